"""The tank run over devices given by port, as a lab runs it on hardware: the Board and GRBL
drivers on plain pty paths (no ``sim://``, so no simulated tank, no shared scaled clock, the
real-device branch of the runner), served in this process by the simulated board firmware
(a loopback cable from DAC 0 to ADC 0) and the simulated GRBL controller, both paced by the
wall clock. Faults injected at the start of transmission must come out in the summary and
the recording exactly, and the xruns the board counted before the run must not."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.experiments import tank_run
from hil.experiments.experiment import DEFAULT_EXPERIMENT, Experiment, parse_experiment
from hil.experiments.sim_tank import STAGE_ACCEL_MM_S2, STAGE_MAX_RATE_MM_MIN, STAGE_TRAVEL_MM
from hil.experiments.tank_run import LiveView, run_experiment, summarize, write_summary
from hil.recording.reader import RunRecording
from hil.recording.replay import ReceiverFeed
from sim_devices.board import FaultPlan, LoopbackWorld, SimulatedBoardOnPty
from sim_devices.stage.controller import GrblSimConfig
from sim_devices.stage.on_pty import SimulatedGrblOnPty

LOST_AT_START = 500  # ADC samples lost to an overrun as the stream starts


@dataclass
class PtyDevices:
    """The simulated board and GRBL controller on ptys, and the board's fault plan."""

    board: SimulatedBoardOnPty
    stage: SimulatedGrblOnPty
    faults: FaultPlan

    def experiment(self, out: Path) -> Experiment:
        """The short built-in pass with the devices given by their pty paths."""
        text = (
            DEFAULT_EXPERIMENT.replace('"sim://board"', f'"{self.board.port_name}"')
            .replace('"sim://stage"', f'"{self.stage.port_name}"')
            .replace("end_m = -5.0", "end_m = -3.5")
            .replace('output_dir = "runs"', f'output_dir = "{out}"')
        )
        exp = parse_experiment(text)
        assert not exp.simulated
        return exp


@pytest.fixture
def devices(monkeypatch: pytest.MonkeyPatch) -> Iterator[PtyDevices]:
    # The simulated devices share this process with the host: a loaded CI machine may stall
    # it for more than the hardware watchdog's 1 s, which would stop the board mid-run.
    monkeypatch.setattr(tank_run, "_WATCHDOG_MS", 10_000)
    stage_sim = SimulatedGrblOnPty(
        GrblSimConfig(
            steps_per_mm=80.0,
            max_rate_mm_min=STAGE_MAX_RATE_MM_MIN,
            acceleration_mm_s2=STAGE_ACCEL_MM_S2,
            max_travel_mm=STAGE_TRAVEL_MM,
            homing=True,
            homing_seek_mm_min=6000.0,
            homing_feed_mm_min=600.0,
            power_up_position_mm=-20.0,
            host_silence_timeout_s=5.0,
        )
    ).start()
    faults = FaultPlan(seed=3)
    board_sim = SimulatedBoardOnPty(
        world=LoopbackWorld(delay_samples=64, gain=0.5), faults=faults
    ).start()
    try:
        yield PtyDevices(board_sim, stage_sim, faults)
    finally:
        board_sim.close()
        stage_sim.close()


@pytest.mark.slow
def test_a_run_over_devices_given_by_port_reports_its_own_xruns_and_a_lost_start(
    tmp_path: Path, devices: PtyDevices
) -> None:
    # The board had xruns before this run (its counters run from power-up) ...
    devices.board.call(lambda b: (setattr(b, "dac_underruns", 5), setattr(b, "adc_overruns", 3)))
    # ... and has one of each as it starts: the first ADC samples are lost, a stretch of the
    # DAC buffer plays silence.
    devices.faults.adc_overrun(LOST_AT_START)
    devices.faults.dac_underrun(1000)
    folder = tmp_path / "run"
    outcome = run_experiment(
        devices.experiment(tmp_path), folder=folder, view=LiveView(enabled=False)
    )
    counters = devices.board.call(lambda b: (b.dac_underruns, b.adc_overruns))

    summary = summarize(outcome)
    write_summary(outcome, summary)
    assert summary["error"] == "" and not summary["interrupted"]
    # Exactly the board's own count since the run started (on a loaded machine the
    # simulated board, paced by the wall clock, may add real xruns to the injected ones).
    assert counters[0] >= 6 and counters[1] >= 4
    assert (summary["dac_underruns"], summary["adc_overruns"]) == (
        counters[0] - 5,
        counters[1] - 3,
    )
    # The lost start is a gap like any other: zero-filled, counted, and an event.
    gaps = [(index, length) for kind, index, length, _ in outcome.events if kind == "gap"]
    assert gaps[0] == (outcome.start_index, LOST_AT_START)
    assert summary["dropped_samples"] == sum(length for _, length in gaps)
    on_disk = json.loads((folder / "summary.json").read_text())
    assert on_disk["dac_underruns"] == summary["dac_underruns"]

    with RunRecording.open(folder / "run.h5") as rec:
        # Recorded from the first transmitted sample on, the lost ones as zeros.
        assert rec.origin_sample == outcome.start_index + summary["loopback_latency_samples"]
        assert rec.segments().sample_index[0] == outcome.start_index
        assert rec.n_samples == outcome.samples
        (lost,) = rec.samples(outcome.start_index, outcome.start_index + LOST_AT_START)
        assert lost.first_index == outcome.start_index and lost.data.shape == (LOST_AT_START, 2)
        assert not lost.data.any()
        kinds = [e.kind for e in rec.events()]
        assert kinds.count("gap") == len(gaps) and kinds.count("underrun") >= 1
        # The stage pass is in the telemetry: run-up from -1.4 m to past the end at -3.5 m.
        positions = [t.position_m for t in rec.telemetry()]
        assert min(positions) == pytest.approx(-4.1, abs=1e-3)
        assert max(positions) == pytest.approx(-1.4, abs=1e-3)


@pytest.mark.slow
def test_a_refusal_once_transmitting_ends_the_run_safely_with_the_reason(
    tmp_path: Path, devices: PtyDevices, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A ConfigError before anything transmits means a bad file or set-up and is raised;
    # once transmitting (here: the receiver refuses its 40th block) it is a failure of the
    # run like any other: transmission off, stage held, the recording closed and readable,
    # the reason in the outcome.
    feed = ReceiverFeed.feed
    calls = 0

    def refusing_feed(self: ReceiverFeed, first: int, block: np.ndarray) -> list[object]:
        nonlocal calls
        calls += 1
        if calls == 40:
            raise ConfigError("block", first, "a block the receiver can take", "test")
        return feed(self, first, block)

    monkeypatch.setattr(ReceiverFeed, "feed", refusing_feed)
    folder = tmp_path / "run"
    outcome = run_experiment(
        devices.experiment(tmp_path), folder=folder, view=LiveView(enabled=False)
    )
    assert outcome.error.startswith("ConfigError: block = ")
    assert "is not allowed: must be a block the receiver can take" in outcome.error
    assert not outcome.interrupted
    # Transmission is off and the stage is not left running.
    assert devices.board.call(lambda b: b.conn.state.name) != "STREAMING"
    assert devices.stage.status().state.name in ("IDLE", "HOLD")  # held, or already done
    with RunRecording.open(folder / "run.h5") as rec:
        # Up to the refused block, which was recorded before the receiver refused it.
        block = round(tank_run._BLOCK_S * 192_000)
        assert outcome.samples > 0 and rec.n_samples - outcome.samples in (0, block)
