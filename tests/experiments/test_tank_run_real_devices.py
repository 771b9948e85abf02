"""The tank run over devices given by port, as a lab runs it on hardware: the Board and GRBL
drivers on plain pty paths (no ``sim://``, so no simulated tank, no shared scaled clock, the
real-device branch of the runner), served in this process by the simulated board firmware
(a loopback cable from DAC 0 to ADC 0) and the simulated GRBL controller, both paced by the
wall clock. Faults injected at the start of transmission must come out in the summary and
the recording exactly, and the xruns the board counted before the run must not."""

from __future__ import annotations

import dataclasses
import json
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from hil.acquisition.feed import ReceiverFeed
from hil.errors import ConfigError
from hil.experiments import tank_run
from hil.experiments.experiment import DEFAULT_EXPERIMENT, Experiment, parse_experiment
from hil.experiments.live import devices as live_devices
from hil.experiments.run_scoring import summarize, write_summary
from hil.experiments.sim_tank import tank_stage_config
from hil.experiments.tank_run import LiveView, run_experiment
from hil.recording.reader import RunRecording
from sim_devices.board import FaultPlan, LoopbackWorld, SimulatedBoardOnPty
from sim_devices.stage.on_pty import SimulatedGrblOnPty
from tests.experiments.conftest import near_home

LOST_AT_START = 500  # ADC samples lost to an overrun as the stream starts
LATENCY = 64  # converters and cable, samples
ECHO_DELAY = 2000  # a fixed echo: 2000 samples at 192 kHz, about 7.7 m
POWER_UP_MM = tank_stage_config().power_up_position_mm  # the carriage before any move
#: The pass near home (``PtyDevices.experiment(near=True)``): it starts at -0.7 m and its
#: run-down ends at -2.8 m, mm.
NEAR_PASS_START_MM, NEAR_PASS_END_MM = -700.0, -2800.0


class WiredTank:
    """The board's world wired as for a tank run: DAC output to ADC input 2 by a cable (the
    monitor), and to ADC input 1 as one fixed echo. ``monitor = False`` unplugs the cable.
    Shapes: ``dac_block`` (n, 1) full scale in, (n, 2) out."""

    def __init__(self) -> None:
        self.monitor = True
        self.starts = 0  # STARTs the board accepted (it resets its world on each)
        self._cable = LoopbackWorld(delay_samples=LATENCY, gain=0.5)
        self._echo = LoopbackWorld(delay_samples=LATENCY + ECHO_DELAY, gain=0.05)

    def reset(self) -> None:
        self.starts += 1
        self._cable.reset()
        self._echo.reset()

    def __call__(self, dac_block: np.ndarray, first_sample: int, /) -> np.ndarray:
        cable = self._cable(dac_block, first_sample)[:, :1]
        echo = self._echo(dac_block, first_sample)[:, :1]
        return np.hstack([echo, cable if self.monitor else np.zeros_like(cable)])


@dataclass
class PtyDevices:
    """The simulated board and GRBL controller on ptys, and the board's fault plan."""

    board: SimulatedBoardOnPty
    stage: SimulatedGrblOnPty
    faults: FaultPlan
    world: WiredTank
    stage_received: bytearray  # every byte the simulated controller received

    def stage_lines(self) -> list[str]:
        """The lines the controller received, without GRBL's realtime bytes (``?`` status,
        ``!`` feed hold, ``~`` cycle start, 0x18 reset, 0x80 and up), which are no lines."""
        realtime = set(b"?!~\x18") | set(range(0x80, 0x100))
        text = bytes(b for b in self.stage_received if b not in realtime).decode("ascii")
        return [line.strip() for line in text.split("\n") if line.strip()]

    def assert_nothing_moved_or_transmitted(self) -> None:
        """The carriage is where it powered up and got no motion or homing line; the board
        accepted no START, received no DAC sample and sent no ADC sample."""
        status = self.stage.status()
        assert status.physical_mm == pytest.approx(POWER_UP_MM)
        assert status.velocity_mm_s == 0.0 and status.queued_blocks == 0
        moving = [ln for ln in self.stage_lines() if ln.upper().startswith(("G", "$H", "$J"))]
        assert moving == [], moving
        snap = self.board.call(lambda b: b.snapshot())
        assert self.world.starts == 0
        assert (snap.dac_samples_received, snap.adc_samples_sent) == (0, 0)
        assert snap.state.name != "STREAMING"

    def experiment(self, out: Path, calibration: str = "", *, near: bool = False) -> Experiment:
        """The short built-in pass with the devices given by their pty paths, the receiver
        keeping stationary echoes: plain GCAS with the peak readout (the wired echo does not
        move, and there is no empty-tank capture for gcas-bg); ``calibration`` replaces the
        ``[calibration]`` table's keys. ``near``: the same pass moved near home
        (:func:`near_home`: from -0.7 m, its run-up from -0.1 m), for the runs whose tow is
        not what they check: the stage, at its own speed on the wall clock, then streams
        without first positioning the carriage 1.4 m out (1.7 s at the simulated
        stage's 2 m/s², against 0.45 s to -0.1 m)."""
        text = (
            DEFAULT_EXPERIMENT.replace('name = "gcas-bg"', 'name = "gcas"')
            .replace('"sim://board"', f'"{self.board.port_name}"')
            .replace('"sim://stage"', f'"{self.stage.port_name}"')
            .replace("end_m = -5.0", "end_m = -3.5")
            .replace('output_dir = "runs"', f'output_dir = "{out}"')
            .replace(
                'options = { background = "simulated" }',
                'options = { reverb_speed_mps = 0.0, range_readout = "peak" }',
            )
        )
        if near:
            text = near_home(text)
        if calibration:
            head, _, tail = text.partition("[calibration]\n")
            text = head + "[calibration]\n" + calibration + "\n" + tail.split("\n\n", 1)[1]
        exp = parse_experiment(text)
        assert not exp.simulated
        return exp


@pytest.fixture
def devices(monkeypatch: pytest.MonkeyPatch) -> Iterator[PtyDevices]:
    # The simulated devices share this process with the host: a loaded CI machine may stall
    # it for more than the hardware watchdog's 1 s, which would stop the board mid-run.
    monkeypatch.setattr(live_devices, "WATCHDOG_MS", 10_000)
    stage_sim = SimulatedGrblOnPty(tank_stage_config())  # paced by the wall clock
    received = bytearray()
    grbl = stage_sim.grbl
    original_receive = grbl.receive_data

    def spy(data: bytes) -> None:  # records, then the real controller handles it
        received.extend(data)
        original_receive(data)

    grbl.receive_data = spy  # type: ignore[method-assign]
    stage_sim.start()
    faults = FaultPlan(seed=3)
    world = WiredTank()
    board_sim = SimulatedBoardOnPty(world=world, faults=faults).start()
    try:
        yield PtyDevices(board_sim, stage_sim, faults, world, received)
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
    assert summary["loopback_latency_samples"] == LATENCY  # measured on the monitor
    assert summary["calibrations"] == [] and summary["sound_speed_from"] == "experiment file"
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
        devices.experiment(tmp_path, near=True), folder=folder, view=LiveView(enabled=False)
    )
    assert outcome.error.startswith("ConfigError: block = ")
    assert "is not allowed: must be a block the receiver can take" in outcome.error
    assert not outcome.interrupted
    # Transmission is off and the stage is not left running.
    assert devices.board.call(lambda b: b.conn.state.name) != "STREAMING"
    assert devices.stage.status().state.name in ("IDLE", "HOLD")  # held, or already done
    with RunRecording.open(folder / "run.h5") as rec:
        # Up to the refused block, which was recorded before the receiver refused it (at
        # most one block: the loop reads what the board holds, up to a block at a time).
        block = round(tank_run.TIMING_BLOCK_S * 192_000)
        assert outcome.samples > 0 and 0 <= rec.n_samples - outcome.samples <= block


@pytest.mark.slow
def test_without_a_monitor_signal_the_run_stops_and_says_what_to_cable(
    tmp_path: Path, devices: PtyDevices
) -> None:
    devices.world.monitor = False
    outcome = run_experiment(
        devices.experiment(tmp_path, near=True),
        folder=tmp_path / "run",
        view=LiveView(enabled=False),
    )
    assert outcome.error.startswith(
        "RuntimeError: no loopback on the DAC monitor input (ADC input 2, channel 1):"
        " normalised correlation 0.00 < 0.5"
    )
    assert "Connect the transmit drive to ADC input 2" in outcome.error
    assert 'calibration.required = ["latency"]' in outcome.error
    assert outcome.estimates == [] and devices.board.call(lambda b: b.conn.state.name) != (
        "STREAMING"
    )


@pytest.mark.slow
def test_required_calibrations_are_applied_in_the_run(tmp_path: Path, devices: PtyDevices) -> None:
    from hil.experiments.calibration.latency import LatencyResult
    from hil.experiments.calibration.sound_speed import SoundSpeedResult
    from hil.experiments.calibration.stage import StageResult
    from hil.experiments.calibration.store import CalibrationStore

    store = CalibrationStore(tmp_path / "cal")
    ids = {
        kind: store.save(kind, result, {"device": "test"}).id
        for kind, result in (
            ("latency", LatencyResult((LATENCY,) * 3, 192_000.0, LATENCY, 64.0, 0.0, 0, 40.0, 0.5)),
            ("sound-speed", SoundSpeedResult(1490.0, 0.3, "time-of-flight")),
            ("stage", StageResult(1.002, 1e-4, 0.001, 5e-5, -3.0, -1, 1490.0)),
        )
    }
    # The monitor cable is out: the calibrated latency places the receiver's sample 0.
    devices.world.monitor = False
    exp = devices.experiment(
        tmp_path,
        f'store = "{tmp_path / "cal"}"\nmax_age_days = 1.0\n'
        'required = ["latency", "sound-speed", "stage"]',
        near=True,
    )
    folder = tmp_path / "run"
    outcome = run_experiment(exp, folder=folder, view=LiveView(enabled=False))
    summary = summarize(outcome)
    assert summary["error"] == ""
    assert summary["calibrations"] == [ids["latency"], ids["sound-speed"], ids["stage"]]
    assert summary["sound_speed_mps"] == 1490.0
    assert summary["sound_speed_from"] == ids["sound-speed"]
    assert summary["loopback_latency_samples"] == LATENCY
    assert outcome.calibrations.stage is not None and outcome.calibrations.stage.scale == 1.002
    # The fixed echo at the calibrated c: (ECHO_DELAY / fs) * c / 2 = 7.760 m.
    ranges = np.array([e.range_m for e in outcome.estimates])
    assert np.median(ranges) == pytest.approx(ECHO_DELAY / 192_000.0 * 1490.0 / 2, abs=0.01)
    with RunRecording.open(folder / "run.h5") as rec:
        assert rec.metadata.calibration_ids == tuple(summary["calibrations"])
        assert rec.origin_sample == outcome.start_index + LATENCY
        # Notes by their text: a board that refused START once on a busy machine (its lead
        # had passed) adds a START_RETRY note.
        notes = [e.text for e in rec.events() if e.kind == "note"]
        assert [t for t in notes if t.startswith("stop: ")] == ["stop: completed"]
        assert [t for t in notes if t.startswith("loopback latency")] == [
            (
                f"loopback latency {LATENCY} samples from calibration {ids['latency']} (the DAC"
                " monitor input carried no loopback: correlation 0.00)"
            )
        ]


# ---- refusals: each before anything moves or transmits


def test_a_tow_refused_for_its_run_up_neither_moves_nor_transmits(
    tmp_path: Path, devices: PtyDevices
) -> None:
    # 2.5 m/s is the stage's max rate ($110), but at its 2 m/s² ($120) the carriage needs
    # 1.5625 m to reach it: the file's 0.6 m run-up is refused from the stage's own $$,
    # before homing, positioning or a single sample out.
    exp = devices.experiment(tmp_path)
    exp = dataclasses.replace(exp, tow=dataclasses.replace(exp.tow, speed_mps=2.5))
    with pytest.raises(ConfigError) as info:
        run_experiment(exp, folder=tmp_path / "run", view=LiveView(enabled=False))
    assert str(info.value).startswith(
        "tow.run_up_m = 0.6 is not allowed: must be >= 1.562 m, the distance to reach"
        " tow.speed_mps = 2.5 m/s at the stage's acceleration 2 m/s² ($120)"
    )
    devices.assert_nothing_moved_or_transmitted()
    assert "$$" in devices.stage_lines()  # the limits came from the stage itself
    assert not (tmp_path / "run" / "run.h5").exists()


def test_a_tow_beyond_the_stage_soft_limits_neither_moves_nor_transmits(
    tmp_path: Path, devices: PtyDevices
) -> None:
    # The file's tank is 12 m long; the stage's travel ($130) is 10 m: -9.6 - 0.6 is past it.
    exp = devices.experiment(tmp_path)
    tow = dataclasses.replace(exp.tow, start_m=-8.0, end_m=-9.6)
    with pytest.raises(ConfigError) as info:
        run_experiment(dataclasses.replace(exp, tow=tow), folder=tmp_path / "run")
    assert str(info.value) == (
        "tow.end_m + tow.run_down_m = -10.2 is not allowed: must be within the stage's soft"
        " limits [-10, 0] m; move the tow inside the stage's travel ($130)"
    )
    devices.assert_nothing_moved_or_transmitted()


def test_out_naming_an_existing_run_is_refused_and_left_untouched(
    tmp_path: Path, devices: PtyDevices
) -> None:
    folder = tmp_path / "earlier-run"
    folder.mkdir()
    (folder / "summary.json").write_text('{"earlier": true}\n')
    with pytest.raises(ConfigError) as info:
        run_experiment(devices.experiment(tmp_path), folder=folder)
    assert str(info.value) == (
        f"--out = '{folder}' is not allowed: must be a new or empty folder; it holds a run"
        " already, which is never overwritten; choose another folder"
    )
    assert [p.name for p in folder.iterdir()] == ["summary.json"]
    assert (folder / "summary.json").read_text() == '{"earlier": true}\n'
    devices.assert_nothing_moved_or_transmitted()
    assert devices.stage_received == b""  # the stage was not even opened


@pytest.mark.parametrize("name", ["../../x", "/tmp/x", "a/b", "..", ".hidden", "a\\b"])
def test_a_run_name_cannot_leave_output_dir(tmp_path: Path, devices: PtyDevices, name: str) -> None:
    exp = devices.experiment(tmp_path / "runs")
    with pytest.raises(ConfigError) as info:
        run_experiment(dataclasses.replace(exp, name=name))
    assert str(info.value).startswith(f"run.name = {name!r} is not allowed: must be a plain")
    assert "must stay inside run.output_dir" in str(info.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing created anywhere
    devices.assert_nothing_moved_or_transmitted()
    assert devices.stage_received == b""
    # The file itself is refused on reading, with the same message.
    text = DEFAULT_EXPERIMENT.replace('name = "sim-towed-pass"', f"name = {json.dumps(name)}")
    with pytest.raises(ConfigError, match=r"run\.name = .* is not allowed: must be a plain"):
        parse_experiment(text)


# ---- faults: a device lost mid-pass stops the run, named


def _on_the_pass(devices: PtyDevices, act: Callable[[], None]) -> threading.Thread:
    """A thread that runs ``act`` once the simulated carriage is on the pass near home
    (moving, past the pass's start at -0.7 m: its run-up starts at -0.1 m), as the controller
    reports it."""
    done = threading.Event()

    def watch() -> None:
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline and not done.wait(0.02):
            status = devices.stage.status()
            if status.velocity_mm_s != 0.0 and status.physical_mm < NEAR_PASS_START_MM:
                act()
                return

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


def _slow(exp: Experiment) -> Experiment:
    """The pass at 0.5 m/s: 2.1 m of the near pass and its run-down take 4.2 s."""
    return dataclasses.replace(exp, tow=dataclasses.replace(exp.tow, speed_mps=0.5))


@pytest.mark.slow
def test_a_board_lost_mid_pass_stops_the_run_naming_it(tmp_path: Path, devices: PtyDevices) -> None:
    port = devices.board.port_name
    killer = _on_the_pass(devices, devices.board.close)  # its pty gone, as a killed process
    folder = tmp_path / "run"
    outcome = run_experiment(
        _slow(devices.experiment(tmp_path, near=True)),
        folder=folder,
        view=LiveView(enabled=False),
    )
    killer.join(10)
    assert outcome.error.startswith(f"DeviceLostError: board {port} lost: its link dropped at")
    assert "check its USB cable and power" in outcome.error
    assert not outcome.interrupted
    # Stopped within its grace, not at the end of the pass or run.max_duration_s: the stage
    # was held short of the pass's end (-2.8 m) and is at rest.
    status = devices.stage.status()
    assert status.velocity_mm_s == 0.0 and status.physical_mm > NEAR_PASS_END_MM + 250.0
    with RunRecording.open(folder / "run.h5") as rec:
        stop = rec.events()[-1]
    assert (stop.kind, stop.text) == ("alarm", f"stop: error: {outcome.error}")


@pytest.mark.slow
def test_a_stage_lost_mid_pass_stops_the_run_naming_it(tmp_path: Path, devices: PtyDevices) -> None:
    port = devices.stage.port_name
    killer = _on_the_pass(devices, devices.stage.close)
    folder = tmp_path / "run"
    outcome = run_experiment(
        _slow(devices.experiment(tmp_path, near=True)),
        folder=folder,
        view=LiveView(enabled=False),
    )
    killer.join(10)
    assert outcome.error.startswith(f"DeviceLostError: stage {port} lost: ")
    assert "check the controller's USB cable and power" in outcome.error
    # Transmission is off: the board is not left streaming.
    assert devices.board.call(lambda b: b.conn.state.name) != "STREAMING"
    with RunRecording.open(folder / "run.h5") as rec:
        assert rec.events()[-1].text == f"stop: error: {outcome.error}"


# ---- the Python API


@pytest.mark.slow
def test_the_python_api_yields_the_runs_estimates_status_and_summary(
    tmp_path: Path, devices: PtyDevices
) -> None:
    from hil.estimation.base import Estimate
    from hil.experiments import api

    items = list(api.iterate(devices.experiment(tmp_path, near=True), folder=tmp_path / "run"))
    finished = items[-1]
    assert isinstance(finished, api.Finished)
    estimates = [i for i in items if isinstance(i, Estimate)]
    statuses = [i.text for i in items if isinstance(i, api.Status)]
    # Every estimate of the run, in order, as it came; the status line as the CLI shows it.
    assert estimates == finished.outcome.estimates and len(estimates) > 50
    assert any(s.startswith("t ") and "estimates | dropped" in s for s in statuses)
    assert finished.summary["error"] == "" and finished.summary["estimates"] == len(estimates)
    assert json.loads((tmp_path / "run" / "summary.json").read_text()) == finished.summary
    # The recording reads back as arrays.
    with RunRecording.open(tmp_path / "run" / "run.h5") as rec:
        table = rec.table("estimates")
    np.testing.assert_array_equal(table["range_m"], [e.range_m for e in estimates])
    # hil report's rebuild replays the receiver for its GCAS map: the same cells (times) as
    # far as both kept them (each keeps its first CodewordMaps.MAX_POINTS points), and the
    # same power in nearly all: GCAS's map callback, unlike its estimates, depends on where
    # the input was cut into calls (live: as samples arrived; replay: 65536-frame blocks).
    from hil.experiments.run_from_recording import outcome_from_recording

    rebuilt = outcome_from_recording(tmp_path / "run" / "run.h5")
    live_t, again_t = (np.concatenate(o.map_times) for o in (finished.outcome, rebuilt))
    live_p, again_p = (np.concatenate(o.map_power) for o in (finished.outcome, rebuilt))
    n = min(live_t.size, again_t.size)
    assert n > 10_000
    np.testing.assert_array_equal(again_t[:n], live_t[:n])
    assert np.mean(again_p[:n] == live_p[:n]) > 0.9
    assert rebuilt.estimates == finished.outcome.estimates


@pytest.mark.slow
def test_leaving_the_python_api_loop_early_stops_the_run_safely(
    tmp_path: Path, devices: PtyDevices
) -> None:
    from hil.estimation.base import Estimate
    from hil.experiments import api

    seen = 0
    near = _slow(devices.experiment(tmp_path, near=True))
    for item in api.iterate(near, folder=tmp_path / "run"):
        seen += isinstance(item, Estimate)
        if seen == 5:
            break  # closes the iterator: the run stops as on Ctrl-C, and is waited for
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["interrupted"] is True
    assert summary["error"] == "interrupted (stopped by the caller)"
    assert devices.board.call(lambda b: b.conn.state.name) != "STREAMING"
    status = devices.stage.status()
    assert status.velocity_mm_s == 0.0 and status.physical_mm > NEAR_PASS_END_MM + 250.0
    with RunRecording.open(tmp_path / "run" / "run.h5") as rec:
        assert rec.events()[-1].text == "stop: interrupted (stopped by the caller)"
