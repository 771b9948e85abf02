"""The live run's parts on their own, scripted: the tow controller against a sequence of
stage reports, the capture loop against a ring filled by the test (chunks == whole), the
latency probe, and the recorder holding telemetry until the recording exists."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from hil.acquisition.capture import CapturedBlock, CaptureLoop
from hil.acquisition.feed import ReceiverFeed
from hil.acquisition.ring import SampleRing
from hil.devices.stage import ProfileWindow, StageState, StageStatus
from hil.estimation.base import Estimate
from hil.experiments.experiment import DEFAULT_EXPERIMENT, TowPlan, parse_experiment
from hil.experiments.live.latency import LatencyProbe
from hil.experiments.live.plan import StageLimits, check_tow
from hil.experiments.live.tow import StageAlarmDuringRun, TowController, TowPhase
from hil.experiments.run_calibrations import RunCalibrations

# ---- the tow controller


@dataclass
class ScriptedStage:
    """Records the passes asked for; each one's constant-speed window is [t, t + 2] s."""

    t: float = 0.0
    passes: list[tuple[float, float, float]] = field(default_factory=list)

    def run_profile(
        self,
        start: float,
        end: float,
        speed: float,
        run_up: float,
        run_down: float,
        *,
        wait: bool = True,
    ) -> ProfileWindow:
        assert not wait
        self.passes.append((start, end, speed))
        return ProfileWindow(self.t, self.t + 2.0, start, end)


def _report(state: StageState, alarm: int | None = None) -> StageStatus:
    return StageStatus(state, None, -2.0, 0.0, False, alarm, None, None, 0.0)


IDLE, RUN = _report(StageState.IDLE), _report(StageState.RUN)


def test_the_tow_controller_runs_every_pass_then_the_tail() -> None:
    tow = check_tow(
        TowPlan(-2.0, -5.0, 1.5, repeats=2, run_up_m=0.6, run_down_m=0.6),
        StageLimits(-10.0, 0.0, 2.5, 2.0),
    )
    stage = ScriptedStage()
    ctl = TowController(tow, stage, tail_s=0.3)
    ctl.on_report(IDLE, 0.0, capturing=False)  # not recording yet: no pass
    assert (ctl.phase, stage.passes) == (TowPhase.READY, [])
    ctl.on_report(IDLE, 0.2, capturing=True)
    assert ctl.phase is TowPhase.PASS and stage.passes == [(-2.0, -5.0, 1.5)]
    ctl.on_report(RUN, 1.0, capturing=True)
    ctl.on_report(IDLE, 1.5, capturing=True)  # idle inside the window: a stale report
    assert ctl.phase is TowPhase.PASS and len(stage.passes) == 1
    ctl.on_report(IDLE, 2.5, capturing=True)  # past the window: the pass is over
    assert ctl.phase is TowPhase.READY
    stage.t = 3.0
    ctl.on_report(IDLE, 3.0, capturing=True)  # the second pass runs back
    assert stage.passes[-1] == (-5.0, -2.0, 1.5) and ctl.passes_started == 2
    ctl.on_report(IDLE, 5.5, capturing=True)
    assert ctl.phase is TowPhase.TAIL and ctl.tail_until == pytest.approx(5.8)
    ctl.on_report(IDLE, 6.0, capturing=True)  # nothing more is asked of the stage
    assert len(stage.passes) == 2 and ctl.windows == [(0.0, 2.0), (3.0, 5.0)]


def test_a_stage_alarm_during_the_tow_stops_the_run_with_what_to_do() -> None:
    tow = check_tow(
        TowPlan(-2.0, -5.0, 1.5, run_up_m=0.6, run_down_m=0.6), StageLimits(-10, 0, 2.5, 2)
    )
    ctl = TowController(tow, ScriptedStage(), tail_s=0.3)
    ctl.on_report(IDLE, 0.0, capturing=True)
    with pytest.raises(StageAlarmDuringRun) as info:
        ctl.on_report(_report(StageState.ALARM, alarm=1), 0.4, capturing=True)
    assert str(info.value) == (
        "stage alarm 1 during pass 1 of 1; the stage is held: check for an obstacle or a limit"
        " switch, then home it"
    )


# ---- the capture loop


class Source:
    """A ring the test fills: what the loop reads of a board."""

    def __init__(self, channels: int = 2) -> None:
        self.ring: SampleRing | None = SampleRing(1 << 16, channels)

    def wait_for_samples(self, end_index: int, /, timeout_s: float) -> bool:
        assert self.ring is not None
        return self.ring.end_index is not None and self.ring.end_index >= end_index

    def read(self, first: int, n: int, /) -> np.ndarray:
        assert self.ring is not None
        return self.ring.read(first, n)


class Summing:
    """A receiver that emits one estimate per 1000 input samples: their sum (range_m) and the
    gaps it was told about (speed_mps)."""

    def __init__(self) -> None:
        self.buf = np.zeros(0)
        self.gaps = 0
        self.seen = 0

    @property
    def next_decision_index(self) -> int:
        return self.seen  # may emit on any block

    def process(self, x: np.ndarray, gap_before: int = 0) -> list[Estimate]:
        self.gaps += gap_before
        self.seen += gap_before + x.shape[0]
        self.buf = np.concatenate([self.buf, np.zeros(gap_before), x])
        out = []
        while self.buf.size >= 1000:
            chunk, self.buf = self.buf[:1000], self.buf[1000:]
            out.append(
                Estimate(0.0, float(chunk.sum()), float(self.gaps), 0, 0.0, 0.0, 0.0, 0.0, 0, "sum")
            )
        return out

    def flush(self) -> list[Estimate]:
        return []


def _fill(source: Source, blocks: list[tuple[int, int]], data: np.ndarray, first: int) -> None:
    assert source.ring is not None
    for a, b in blocks:
        source.ring.write(first + a, data[a:b])


@pytest.mark.parametrize("max_block", [1, 97, 1000, 4096])
def test_the_capture_loop_gives_the_receiver_the_same_as_one_whole_block(max_block: int) -> None:
    rng = np.random.default_rng(7)
    data = rng.integers(-1000, 1000, size=(9000, 2)).astype(np.int16)
    first = 50_000
    source = Source()
    # Arrivals in uneven pieces, with 300 samples lost (zero-filled by the ring).
    _fill(source, [(0, 1234), (1234, 4000), (4300, 9000)], data, first)
    expected = data.copy()
    expected[4000:4300] = 0
    seen: list[CapturedBlock] = []
    feed = ReceiverFeed(Summing(), origin=first, channel=1)  # type: ignore[arg-type]
    loop = CaptureLoop(source, first, max_block, feed=feed, on_block=seen.append)
    got: list[Estimate] = []
    loop.on_fed = lambda b: got.extend(b.estimates)
    while loop.step(0.0, limit=first + 9000) is not None:  # the last block is short
        pass
    assert loop.next_index == first + 9000
    assert all(b.data.shape[0] <= max_block for b in seen)
    np.testing.assert_array_equal(np.concatenate([b.data for b in seen]), expected)
    whole = Summing()
    want = whole.process(expected[:, 1].astype(float))
    assert [e.range_m for e in got] == [e.range_m for e in want] and len(got) == 9


def test_the_capture_loop_waits_for_the_receivers_next_decision() -> None:
    class Deciding(Summing):
        next_decision_index = 700  # type: ignore[assignment]

    source = Source()
    data = np.ones((2000, 2), dtype=np.int16)
    _fill(source, [(0, 600)], data, 0)
    loop = CaptureLoop(source, 0, 1920, feed=ReceiverFeed(Deciding(), origin=0))  # type: ignore[arg-type]
    assert loop.wanted_index() == 700  # the decision comes before one block
    assert loop.step(0.0) is None  # 600 held: nothing worth reading yet
    _fill(source, [(600, 800)], data, 0)
    block = loop.step(0.0)
    assert block is not None and (block.first_index, block.data.shape[0]) == (0, 800)
    assert loop.backlog_max == 800
    every = CaptureLoop(source, 0, 1920, every=100)
    assert every.wanted_index() == 100 and every.wanted_index(limit=50) == 50


def test_a_feed_attached_by_the_observer_takes_the_blocks_after() -> None:
    source = Source()
    _fill(source, [(0, 3000)], np.ones((3000, 2), dtype=np.int16), 0)
    fed: list[int] = []
    loop = CaptureLoop(source, 0, 1000)

    class Recorder(Summing):
        def process(self, x: np.ndarray, gap_before: int = 0) -> list[Estimate]:
            fed.append(x.size)
            return []

    def attach(block: CapturedBlock) -> None:
        if loop.feed is None:
            loop.feed = ReceiverFeed(Recorder(), origin=block.first_index + 1000)  # type: ignore[arg-type]

    loop.on_block = attach
    while loop.step(0.0) is not None:
        pass
    assert fed == [1000, 1000]  # not the block that attached it


# ---- the latency probe and the recorder


def _probe_with_loopback(latency: int) -> LatencyProbe:
    """A probe fed the first 100 ms of a run whose DAC monitor is the drive ``latency``
    samples late (a board: 64; an audio interface at 192 kHz, 4096-frame blocks: 8256)."""
    from hil.signals.synthesis import BlockSynthesizer

    exp = parse_experiment(DEFAULT_EXPERIMENT)
    fs = exp.waveform.fs_hz
    sent = BlockSynthesizer(exp.schedule, fs, amplitude=0.5).render(0, 40_000)
    monitor = np.concatenate([np.zeros(latency), sent])[:40_000]
    codes = np.stack([np.zeros(40_000), monitor * 16384], axis=1).astype(np.int16)
    probe = LatencyProbe(exp.schedule, fs, 0.5, 1000, 1.0 / 32768.0, RunCalibrations())
    assert not probe.add(1000, codes[:10_000])
    assert probe.add(11_000, codes[10_000:19_200])  # 19200 samples = 100 ms at 192 kHz
    return probe


@pytest.mark.parametrize("latency", [64, 4160, 8256, 14_000])
def test_the_latency_probe_measures_the_loopback_on_the_first_100_ms(latency: int) -> None:
    lat, note = _probe_with_loopback(latency).measure()
    assert (lat, note) == (latency, f"loopback latency {latency} samples")


def test_a_loopback_longer_than_the_probe_measures_is_refused() -> None:
    with pytest.raises(RuntimeError) as err:
        _probe_with_loopback(14_500).measure()
    assert str(err.value) == (
        "loopback latency of 14400 samples or more: beyond the 14400 samples (0.075 s) the"
        " run's latency probe measures; lower the audio interface's blocksize or latency"
        " setting"
    )


def _late_heard_probe(latency: int) -> tuple[LatencyProbe, list[bool], int]:
    """A probe fed a digital path whose monitor, the drive ``latency`` samples late, carries
    exact zeros for its first 0.3 s (a JACK graph connected late), block by block until it is
    ready: the probe, what each ``add`` said, the block length."""
    from hil.signals.synthesis import BlockSynthesizer

    exp = parse_experiment(DEFAULT_EXPERIMENT)
    fs = exp.waveform.fs_hz
    n = int(0.5 * fs)
    sent = BlockSynthesizer(exp.schedule, fs, amplitude=0.5).render(0, n)
    monitor = np.concatenate([np.zeros(latency), sent])[:n]
    monitor[: int(0.3 * fs)] = 0.0
    codes = np.stack([np.zeros(n), monitor * 16384], axis=1).astype(np.int16)
    probe = LatencyProbe(exp.schedule, fs, 0.5, 0, 1.0 / 32768.0, RunCalibrations())
    block = 4800
    ready = []
    for i in range(0, n, block):
        ready.append(probe.add(i, codes[i : i + block]))
        if ready[-1]:
            break
    return probe, ready, block


def test_a_monitor_silent_at_first_is_waited_for_and_then_measured() -> None:
    """Gathered until the drive is heard and a probe's length past it: the latency is the
    converter's, as on a monitor connected from the start."""
    from hil.experiments.live.latency import PROBE_MAX_S, PROBE_S

    probe, ready, block = _late_heard_probe(64)
    fs = parse_experiment(DEFAULT_EXPERIMENT).waveform.fs_hz
    # Silent up to 0.3 s, then PROBE_S of capture from the first block heard.
    assert ready.index(True) * block == int(0.3 * fs) + int(PROBE_S * fs) - block
    assert PROBE_S < 0.3 < PROBE_MAX_S
    assert probe.measure() == (64, "loopback latency 64 samples")


def test_a_late_heard_loopback_longer_than_the_probe_measures_is_refused() -> None:
    probe, _, _ = _late_heard_probe(14_500)
    with pytest.raises(RuntimeError) as err:
        probe.measure()
    assert str(err.value) == (
        "loopback latency of 14400 samples or more: beyond the 14400 samples (0.075 s) the"
        " run's latency probe measures; lower the audio interface's blocksize or latency"
        " setting"
    )


def test_a_monitor_silent_throughout_is_no_loopback_after_the_longest_probe() -> None:
    from hil.experiments.live.latency import PROBE_MAX_S

    exp = parse_experiment(DEFAULT_EXPERIMENT)
    fs = exp.waveform.fs_hz
    probe = LatencyProbe(exp.schedule, fs, 0.5, 0, 1.0 / 32768.0, RunCalibrations())
    block = 4800
    silent = np.zeros((block, 2), dtype=np.int16)
    ready = [probe.add(i * block, silent) for i in range(int(PROBE_MAX_S * fs) // block + 1)]
    assert ready.index(True) + 1 == int(PROBE_MAX_S * fs) // block
    with pytest.raises(RuntimeError, match="no loopback on the DAC monitor input"):
        probe.measure()


def test_the_recorder_holds_telemetry_until_the_recording_exists(tmp_path: Path) -> None:
    from hil.experiments.live.recorder import RunRecorder
    from hil.recording.reader import RunRecording
    from hil.recording.records import RunEvent, StageTelemetry
    from hil.signals.schedule_file import schedule_document

    exp = parse_experiment(DEFAULT_EXPERIMENT)
    fs = exp.waveform.fs_hz
    doc = schedule_document(exp.schedule, fs, 0.0, sound_speed_mps=exp.sound_speed_mps)
    options = {"fs_hz": fs, "n_channels": 2, "dtype": "int16", "schedule_document": doc}
    recorder = RunRecorder(tmp_path / "run.h5", options)
    recorder.telemetry(StageTelemetry(1.0, -1, -1.4, 0.0, "Idle"))
    recorder.samples(0, np.zeros((10, 2), np.int16))  # before the origin is known: dropped
    assert not recorder.open_ and not (tmp_path / "run.h5").exists()
    recorder.open(1064, RunEvent("note", 1000, 64, "loopback latency 64 samples"))
    recorder.telemetry(StageTelemetry(1.2, 100, -1.5, 0.5, "Run"))
    recorder.samples(1000, np.ones((100, 2), np.int16))
    recorder.sync(lambda pairs: pairs.extend([(1000, 0.5), (2000, 0.51)]))
    recorder.events([("note", 1100, 0, "stop: completed")])
    recorder.close()
    with RunRecording.open(tmp_path / "run.h5") as rec:
        assert [t.position_m for t in rec.telemetry()] == [-1.4, -1.5]
        assert rec.origin_sample == 1064 and rec.n_samples == 100
        assert [e.text for e in rec.events()] == ["loopback latency 64 samples", "stop: completed"]
        assert rec.sync_pairs().sample_index.tolist() == [1000, 2000]


# ---- the run's heap


def test_the_run_freezes_its_heap_before_any_device_opens_and_thaws_it_after(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The full collection before the freeze holds the GIL (about 0.1 s of CPU, seconds on a
    loaded machine): it runs before a device opens, where no board's watchdog waits on the
    keepalives it would hold up; the run hands the objects back when it ends."""
    import gc

    from hil.errors import ConfigError
    from hil.experiments.live.devices import RunDevices
    from hil.experiments.tank_run import LiveView, run_experiment

    frozen_at_open: list[int] = []

    def refuse(self: RunDevices, *args: object, **kwargs: object) -> None:
        frozen_at_open.append(gc.get_freeze_count())
        raise ConfigError("devices", "refused by the test", "devices this test opens")

    monkeypatch.setattr(RunDevices, "open", refuse)
    text = DEFAULT_EXPERIMENT.replace('name = "gcas-bg"', 'name = "gcas-mti"').replace(
        'options = { background = "simulated" }\n', ""
    )
    assert gc.get_freeze_count() == 0
    with pytest.raises(ConfigError, match="refused by the test"):
        run_experiment(
            parse_experiment(text), folder=tmp_path / "run", view=LiveView(enabled=False)
        )
    # Frozen at the first device's opening: the set-up's objects (numba, SciPy, the
    # receiver's tables: over 100 000 of them); none left frozen after the run.
    assert frozen_at_open and frozen_at_open[0] > 50_000
    assert gc.get_freeze_count() == 0
