"""Device logs at DEBUG: every GRBL line both ways and the stage's state changes, the
board's control frames (never its sample frames) and session states, link losses,
reconnects and timeouts, the transports opened; all through per-module loggers under
``hil``, so they end in a run's ``run.log``."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from hil.devices.board import Board
from hil.devices.board_settings import BoardSettings
from hil.devices.clock import VirtualClock
from hil.devices.grbl import GrblStage
from hil.errors import TransportTimeoutError
from hil.logs import run_log
from sim_devices.board import BoardPort, FaultPlan, LoopbackWorld, MemoryBoardLink, SimulatedBoard
from sim_devices.stage import GrblSimConfig, ManualClock

RATE_HZ = 48_000
URL = "sim://board?via=memory"


def _board_session(faults: FaultPlan | None = None) -> Board:
    """Open, configure, start, stream 50 ms and stop a simulated board on virtual time."""
    clock = VirtualClock(tick_s=0.001)
    sim = SimulatedBoard(clock=clock, world=LoopbackWorld(3), faults=faults)
    link = MemoryBoardLink(BoardPort(sim), timeout=0.0)
    settings = BoardSettings(sample_rate_hz=RATE_HZ, dac_channels=1, adc_channels=2)
    board = Board(link, settings=settings, virtual_time=clock, keepalive_ms=1000).open()
    board.configure()
    first = board.start(lambda k, n: np.zeros(n))
    assert board.wait_for_samples(first + RATE_HZ // 20, timeout_s=1.0)
    if faults is None:
        board.stop()
    return board


def _messages(caplog: pytest.LogCaptureFixture, logger: str) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == logger]


def test_board_control_frames_and_session_states_are_logged_not_its_samples(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with caplog.at_level(logging.DEBUG, logger="hil"):
        _board_session().close()
    lines = _messages(caplog, "hil.devices.board")
    assert all(r.levelno == logging.DEBUG for r in caplog.records if r.name == "hil.devices.board")
    states = [line.split(": state ")[1] for line in lines if ": state " in line]
    assert states == [
        "IDLE -> HELLO_SENT",
        "HELLO_SENT -> VERSION_SENT",
        "VERSION_SENT -> READY",
        "READY -> CONFIGURING",
        "CONFIGURING -> CONFIGURED",
        "CONFIGURED -> STARTING",
        "STARTING -> STREAMING",
        "STREAMING -> STOPPING",
        "STOPPING -> STOPPED",
    ]
    sent = {line.split(" -> ")[1].split()[0] for line in lines if f"board {URL} -> " in line}
    got = {line.split(" <- ")[1].split()[0] for line in lines if f"board {URL} <- " in line}
    assert sent == {"HELLO", "KEEPALIVE", "CONFIGURE", "START", "STOP"}
    assert got == {"VERSION", "CAPABILITIES", "SYNC", "STATUS", "CREDIT", "ACK"}
    assert f"board {URL} -> CONFIGURE {{'sample_rate_hz': 48000, " in "\n".join(lines)
    assert not any("ADC_DATA" in line or "DAC_DATA" in line for line in lines)


def test_a_lost_link_and_a_timeout_are_logged(caplog: pytest.LogCaptureFixture) -> None:
    faults = FaultPlan()
    with caplog.at_level(logging.DEBUG, logger="hil"):
        board = _board_session(faults)
        faults.disconnect()
        assert board.wait_for_samples(10**9, timeout_s=0.5) is False
        clock = VirtualClock(tick_s=0.001)
        silent = SimulatedBoard(clock=clock)
        silent.receive_data = lambda data: None  # type: ignore[method-assign]  # hears nothing
        link = MemoryBoardLink(BoardPort(silent), timeout=0.0)
        with pytest.raises(TransportTimeoutError):
            Board(link, virtual_time=clock, command_timeout_s=2.5).open()
    lines = _messages(caplog, "hil.devices.board")
    assert f"board {URL}: link lost: simulated board unplugged during read" in "\n".join(lines)
    assert lines[-1] == f"board {URL}: timed out after 2.5 s of virtual time waiting for VERSION"


def test_every_grbl_line_both_ways_and_the_stage_states_are_logged(
    caplog: pytest.LogCaptureFixture,
) -> None:
    config = GrblSimConfig(homing=True, power_up_position_mm=-20.0, max_travel_mm=400.0)
    clock = ManualClock(0.0)
    url = "sim://stage?via=memory"
    options = {"config": config}
    with (
        caplog.at_level(logging.DEBUG, logger="hil"),
        GrblStage(url, clock=clock, transport_options=options) as stage,
    ):
        stage.home()
        stage.move_to(-0.05, 0.005)
    lines = _messages(caplog, "hil.devices.grbl")
    assert f"stage {url} -> $$" in lines
    assert f"stage {url} -> $H" in lines
    assert f"stage {url} <- Grbl 1.1h ['$' for help]" in lines
    assert f"stage {url} <- $22=1" in lines  # every line of the $$ dump
    prefix = f"stage {url} -> "
    sent = [line.removeprefix(prefix) for line in lines if line.startswith(prefix)]
    # Every line sent is answered by one ok (the realtime '?' and 0x18 are not lines).
    answered = [t for t in sent if t not in ("?", r"b'\x18'")]
    assert lines.count(f"stage {url} <- ok") == len(answered) == 4
    assert any(line.startswith(f"stage {url} <- <Idle|MPos:") for line in lines)
    states = [line.split(": state ")[1] for line in lines if ": state " in line]
    assert states == ["unknown -> ALARM", "ALARM -> IDLE", "IDLE -> RUN", "RUN -> IDLE"]
    transports = _messages(caplog, "hil.transports.registry")
    assert transports == [f"transport {url} opened (MemoryStageLink)"]


def test_device_logs_end_in_the_run_log(tmp_path: Path) -> None:
    with run_log(tmp_path) as path:
        _board_session().close()
    text = path.read_text(encoding="utf-8")
    assert f"DEBUG   hil.devices.board: board {URL} -> HELLO " in text
    assert f"DEBUG   hil.devices.board: board {URL}: state STOPPING -> STOPPED" in text
