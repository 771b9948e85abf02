"""Replay equals live: a live loop feeds received blocks (random sizes, lost samples) to a
receiver and to a RunWriter at once; replaying the file gives the identical estimates, another
receiver gives its own, and ``hil replay`` prints them and checks them against live."""

from __future__ import annotations

import csv
import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from hil.acquisition.feed import ReceiverFeed
from hil.cli.main import main
from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.estimation.registry import make_receiver
from hil.estimation.tracking import Tracker, mean_hop_s
from hil.recording import (
    ReceiverSetup,
    RunRecording,
    RunWriter,
    build_receiver,
    compare_estimates,
    replay,
)
from hil.signals.schedule import HopSchedule
from sim_devices.acoustics.delay import TwoWayPath
from sim_devices.acoustics.echo import AnalyticEcho
from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed

FS = 100_000.0
R0, V = 40.0, 9.0  # m, m/s closing
ORIGIN = 5_000_000  # board sample index of the schedule's t = 0
N = 45_000  # 0.45 s
LOST = ((0, 257), (15_000, 15_800), (30_000, 30_123))  # receiver samples never received
COMMON: dict[str, Any] = {
    "sound_speed_mps": 1500.0,
    "max_speed_mps": 30.0,
    "max_range_m": 100.0,
    "m_hops": 10,
}


def _received(schedule: HopSchedule) -> np.ndarray:
    """(N, 2) int16 ADC codes: channel 1 the hydrophone (echo + noise), channel 0 other."""
    rng = np.random.default_rng(11)
    sonar = Fixed([0.0, 0.0, 0.0])
    path = TwoWayPath(sonar, ConstantVelocity([R0, 0.0, 0.0], [-V, 0.0, 0.0]), sonar, 1500.0)
    x = AnalyticEcho(schedule, path, FS).block(0, N) + rng.normal(0.0, 0.5, N)
    codes = np.round(0.5 * x / np.max(np.abs(x)) * 2**15).astype(np.int16)
    other = rng.integers(-3000, 3000, N).astype(np.int16)
    return np.stack([other, codes], axis=1)


def _packets(seed: int) -> list[tuple[int, int]]:
    """Received packets as ``[start, stop)`` receiver sample ranges: random sizes, with the
    samples in :data:`LOST` missing."""
    rng = np.random.default_rng(seed)
    keep = np.ones(N, bool)
    for a, b in LOST:
        keep[a:b] = False
    out: list[tuple[int, int]] = []
    p = 0
    while p < N:
        q = min(N, p + int(rng.integers(300, 6000)))
        idx = np.flatnonzero(keep[p:q]) + p
        if idx.size:
            for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
                out.append((int(run[0]), int(run[-1]) + 1))
        p = q
    return out


@pytest.fixture(scope="module")
def live_run(
    tmp_path_factory: pytest.TempPathFactory, schedule: HopSchedule, schedule_doc: dict[str, Any]
) -> tuple[Path, list[Estimate], np.ndarray]:
    """The "live" loop: every packet goes to the receiver and to the recording."""
    raw = _received(schedule)
    path = tmp_path_factory.mktemp("replay") / "run.h5"
    setup = ReceiverSetup("gcas", COMMON, channel=1, scale=2.0**-15)
    feed = ReceiverFeed(
        build_receiver(setup, schedule, FS), origin=ORIGIN, channel=1, scale=2.0**-15
    )
    live: list[Estimate] = []
    with RunWriter.create(
        path,
        fs_hz=FS,
        n_channels=2,
        dtype="int16",
        schedule_document=schedule_doc,
        receiver=setup,
        origin_sample=ORIGIN,
        chunk_frames=8192,
    ) as writer:
        for a, b in _packets(seed=3):
            writer.append_samples(ORIGIN + a, raw[a:b])
            estimates = feed.feed(ORIGIN + a, raw[a:b])
            writer.append_estimates(estimates)
            live.extend(estimates)
        tail = feed.finish()
        writer.append_estimates(tail)
        live.extend(tail)
    return path, live, raw


def test_live_estimates_track_the_target_across_gaps(live_run: Any) -> None:
    _, live, _ = live_run
    for e in live:
        assert e.receiver == "gcas"
        assert e.range_m == pytest.approx(R0 - V * (e.t_s + e.t_tx_s) / 2, abs=0.1)
        assert e.speed_mps == pytest.approx(V, abs=0.3)
    # GCAS restarts its M-hop accumulation after each gap (0.15 s, 0.30 s): estimates in
    # every stretch between gaps once M = 10 hops (0.1 s) have been gathered again.
    t = np.array([e.t_s for e in live])
    counts = [int(np.sum((t > a) & (t < b))) for a, b in ((0, 0.15), (0.15, 0.3), (0.3, 0.45))]
    assert min(counts) >= 3, counts


def test_replay_with_live_settings_equals_live_exactly(live_run: Any) -> None:
    path, live, _ = live_run
    with RunRecording.open(path) as rec:
        assert rec.gaps() == [(ORIGIN + a, b - a) for a, b in LOST[1:]]
        assert rec.samples()[0].first_index == ORIGIN + LOST[0][1]
        assert rec.estimates("gcas") == live
        replayed = replay(rec)
        assert replayed == live
        # Block boundaries do not matter (chunk-invariant receivers), gaps do.
        assert replay(rec, block_frames=4999) == live
    assert compare_estimates(live, replayed) == (
        "equal",
        f"all {len(live)} replayed estimates equal the recorded live ones",
    )


def test_replay_with_another_receiver_gives_its_estimates(
    live_run: Any, schedule: HopSchedule
) -> None:
    path, _, raw = live_run
    # Reference: the receiver run by hand on whole contiguous runs, gaps as gap_before.
    receiver = make_receiver("stft", schedule, FS, **COMMON)
    expected: list[Estimate] = []
    previous_stop = 0
    keep = np.ones(N, bool)
    for a, b in LOST:
        keep[a:b] = False
    edges = np.flatnonzero(np.diff(np.concatenate(([0], keep.astype(np.int8), [0]))))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        x = raw[a:b, 1].astype(np.float64) * 2.0**-15
        expected += receiver.process(x, gap_before=int(a) - previous_stop)
        previous_stop = int(b)
    expected += receiver.flush()
    # Replay's estimates leave through the tracker (hil.estimation.tracking), as live ones do.
    expected = Tracker(mean_hop_s(schedule)).update(expected)
    got = replay(path, "stft")
    assert len(got) >= 10 and all(e.receiver == "stft" for e in got)
    assert got == expected
    assert {e.track_id for e in got} >= {0}


def test_replay_setup_errors_name_the_field(live_run: Any) -> None:
    path, _, _ = live_run
    with RunRecording.open(path) as rec:
        with pytest.raises(ConfigError, match="receiver = 'sonar9000' is not allowed: must be one"):
            replay(rec, "sonar9000")
        with pytest.raises(ConfigError, match=r"channel = 2 is not allowed: must be 0..1"):
            replay(rec, channel=2)
        with pytest.raises(ConfigError, match=r"receiver.options.bogus = 1 .* option of the gcas"):
            replay(rec, bogus=1)


def test_compare_estimates_prefix_and_difference() -> None:
    a = Estimate(0.1, 40.0, 9.0, 5, 10.0, float("nan"), 1.012, 0.05, 5, "gcas")
    b = Estimate(0.11, 39.9, 9.0, 6, 10.0, 20.0, 1.012, 0.06, 6, "gcas")
    assert compare_estimates([a, b], [a, b])[0] == "equal"  # NaN SNR equals NaN SNR
    assert compare_estimates([a], [a, b]) == (
        "prefix",
        "1 recorded and 2 replayed estimates, equal as far as both go",
    )
    verdict, text = compare_estimates([a, a], [a, b])
    assert verdict == "differ" and text.startswith("estimate 1 differs: recorded Estimate(t_s=0.1")


# ---------------------------------------------------------------------- hil replay
def test_cli_replays_the_live_receiver_and_checks_it(
    live_run: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    path, live, _ = live_run
    assert main(["replay", str(path), "--json"]) == 0
    out, err = capsys.readouterr()
    rows = [json.loads(line) for line in out.splitlines()]
    assert rows == [json.loads(json.dumps(e.to_dict())) for e in live]
    verdict, refused = err.splitlines()
    assert (
        verdict
        == f"replay equals live: all {len(live)} replayed estimates equal the recorded live ones"
    )
    assert refused.startswith("refused: ")


def test_cli_another_receiver_to_csv(
    live_run: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, _, _ = live_run
    out_csv = tmp_path / "stft.csv"
    assert main(["replay", str(path), "--receiver", "stft", "--csv", str(out_csv)]) == 0
    assert capsys.readouterr().out == ""  # no live comparison for another receiver
    with out_csv.open() as fh:
        rows = list(csv.DictReader(fh))
    want = replay(path, "stft")
    assert [float(r["range_m"]) for r in rows] == [e.range_m for e in want]
    assert {r["receiver"] for r in rows} == {"stft"}


def test_cli_reports_a_replay_that_differs_from_live(
    live_run: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, live, _ = live_run
    tampered = tmp_path / "tampered.h5"
    shutil.copy(path, tampered)
    with h5py.File(tampered, "r+") as f:
        f["estimates/range_m"][3] = 1.0
    assert main(["replay", str(tampered)]) == 1
    out = capsys.readouterr().out
    lines = out.splitlines()  # the table (a header, a row per estimate), then the count
    assert lines[1 + len(live)] == f"{len(live)} estimates from {tampered} (gcas)"
    assert "replay DIFFERS from live: estimate 3 differs: recorded Estimate(" in out
    assert "range_m=1.0" in out


@pytest.mark.parametrize(
    ("make", "extra", "message"),
    [
        ("text", [], "RUN (recording) = '{path}' is not allowed: must be an HDF5 run recording"),
        ("version", [], "recording.format_version = 7 is not allowed: must be one of 1, 2 (the"),
        ("copy", ["--receiver", "sonar9000"], "--receiver (receiver) = 'sonar9000' is not"),
        ("copy", ["--option", "bogus=1"], "receiver.options.bogus = 1 is not allowed"),
        ("copy", ["--option", "novalue"], "--option = 'novalue' is not allowed: must be KEY=VALUE"),
        ("copy", ["--channel", "5"], "--channel (channel) = 5 is not allowed: must be 0..1"),
        ("missing", [], "RUN (recording) = '{path}' is not allowed: must be an existing run"),
        ("cut", [], "an HDF5 run recording written by hil; it is truncated: "),
        ("empty", [], "it does not start with the HDF5 signature (0 bytes)"),
    ],
)
def test_cli_bad_input_exits_2(
    live_run: Any,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    make: str,
    extra: list[str],
    message: str,
) -> None:
    path = tmp_path / "in.h5"
    if make == "text":
        path.write_text("not a recording")
    elif make == "cut":  # an interrupted copy: HDF5 would wait for the missing end
        whole = Path(live_run[0]).read_bytes()
        path.write_bytes(whole[: len(whole) * 2 // 3])
    elif make == "empty":
        path.write_bytes(b"")
    elif make in ("version", "copy"):
        shutil.copy(live_run[0], path)
        if make == "version":
            with h5py.File(path, "r+") as f:
                f.attrs["format_version"] = 7
    assert main(["replay", str(path), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hil replay: error: ")
    assert message.format(path=path) in err
    assert len(err.splitlines()) == 1


def test_a_recording_cut_anywhere_is_refused_before_hdf5_opens_it(
    live_run: Any, tmp_path: Path
) -> None:
    from hil.recording.reader import hdf5_damage

    whole = Path(live_run[0]).read_bytes()
    path = tmp_path / "cut.h5"
    path.write_bytes(whole)
    assert hdf5_damage(path) is None
    rng = np.random.default_rng(5)
    for keep in [0, 7, 8, 11, 40, 95, *rng.integers(96, len(whole), 20).tolist()]:
        path.write_bytes(whole[:keep])
        damage = hdf5_damage(path)
        assert damage is not None, keep
        with pytest.raises(ConfigError) as info:
            RunRecording.open(path)
        assert str(info.value).startswith(f"recording = '{path}' is not allowed: must be an HDF5")
        assert damage in str(info.value)
        assert f"({keep} bytes" in damage or f"{keep} bytes, but its last flush wrote" in damage
    # A flipped signature byte is refused as not HDF5.
    path.write_bytes(b"\x00" + whole[1:])
    assert hdf5_damage(path) == f"it does not start with the HDF5 signature ({len(whole)} bytes)"


def test_cli_needs_a_receiver_name_when_none_ran_live(
    tmp_path: Path, schedule_doc: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "norx.h5"
    with RunWriter.create(
        path, fs_hz=FS, n_channels=1, dtype="float32", schedule_document=schedule_doc
    ) as w:
        w.append_samples(0, np.zeros(1000, np.float32))
    assert main(["replay", str(path)]) == 2
    assert capsys.readouterr().err == (
        "hil replay: error: --receiver (receiver) = None is not allowed: must be one of gcas, "
        "gcas-mti, jifs, stft, mfbank, fmcw, gcas-bg, gcas-still; the recording holds no live "
        "receiver: name the one to run\n"
    )


def test_feed_drops_samples_before_its_origin() -> None:
    """Samples captured before the receiver's sample 0 (e.g. while the loopback latency was
    measured) are dropped; the first fed sample is the origin; repeats are still refused."""
    from hil.acquisition.feed import ReceiverFeed
    from hil.errors import ConfigError

    seen: list[tuple[int, int]] = []

    class Recorder:
        name = "recorder"
        fs_hz = 1.0
        next_decision_index = 0  # may emit on any block

        def process(self, x: np.ndarray, *, gap_before: int = 0) -> list:
            seen.append((len(x), gap_before))
            return []

    feed = ReceiverFeed(Recorder(), origin=100)  # type: ignore[arg-type]
    assert feed.feed(0, np.zeros((64, 2))) == []
    feed.feed(64, np.zeros((64, 2)))  # 36 before the origin, 28 after
    feed.feed(128, np.zeros((10, 2)))
    assert seen == [(28, 0), (10, 0)]
    with pytest.raises(ConfigError, match="first_index = 130"):
        feed.feed(130, np.zeros((5, 2)))


class Plain:
    """A receiver that may emit after any sample: its decision index is what it has seen."""

    name, fs_hz = "plain", 1.0

    def __init__(self) -> None:
        self.next_decision_index = 0

    def process(self, x: np.ndarray, *, gap_before: int = 0) -> list:
        self.next_decision_index += gap_before + x.shape[0]
        return []


class Bounded(Plain):
    """A receiver that says before which input sample no estimate can come out."""

    def process(self, x: np.ndarray, *, gap_before: int = 0) -> list:
        return []


def test_receiver_feed_says_how_far_the_stream_must_go_before_an_estimate() -> None:
    from hil.acquisition.feed import ReceiverFeed

    plain = ReceiverFeed(Plain(), origin=100)  # type: ignore[arg-type]
    plain.feed(100, np.zeros((50, 1)))
    assert plain.next_index == plain.next_useful_index == 150
    rx = Bounded()
    bounded = ReceiverFeed(rx, origin=100)  # type: ignore[arg-type]
    bounded.feed(100, np.zeros((50, 1)))
    rx.next_decision_index = 400  # receiver input samples: board index origin + 400
    assert (bounded.next_index, bounded.next_useful_index) == (150, 500)
    rx.next_decision_index = 20  # a bound already passed never points back
    assert bounded.next_useful_index == 150


def test_live_loop_waits_for_the_next_decision_or_one_block() -> None:
    from hil.acquisition.feed import ReceiverFeed

    plain = ReceiverFeed(Plain(), origin=100)  # type: ignore[arg-type]
    plain.feed(100, np.zeros((50, 1)))
    assert plain.wait_index(1920) == 150 + 1920  # no decisions: a whole block
    rx = Bounded()
    bounded = ReceiverFeed(rx, origin=100)  # type: ignore[arg-type]
    bounded.feed(100, np.zeros((50, 1)))
    rx.next_decision_index = 400  # board index 500
    assert bounded.wait_index(1920) == 500  # the decision comes first: wait for it only
    assert bounded.wait_index(350) == 500  # ... also when it ends the block exactly
    assert bounded.wait_index(349) == 499  # beyond the block: one block, then look again
    rx.next_decision_index = 50  # board index 150, already reached: a whole block
    assert bounded.wait_index(8) == 158
    for bad in (0, -5):
        with pytest.raises(ConfigError, match=rf"max_block = {bad} is not allowed: must be >= 1"):
            bounded.wait_index(bad)


def test_live_estimates_carry_track_ids_that_replay_repeats(live_run: Any) -> None:
    path, live, _ = live_run
    # Each stretch between two gaps restarts GCAS's M = 10 hop accumulation: more than the
    # tracker's 5 missed hops, so each stretch is a new track, confirmed on its 3rd estimate.
    assert [e.track_id for e in live] == [-1, -1, 0, 0, -1, -1, 1, -1, -1, 2, 2]
    with RunRecording.open(path) as rec:
        assert rec.has_track_ids
        assert rec.table("estimates")["track_id"].tolist() == [e.track_id for e in live]
        assert replay(rec) == live  # Estimate equality compares the ids


def test_tracker_settings_are_receiver_settings_on_replay(live_run: Any) -> None:
    path, live, _ = live_run
    got = replay(path, track_confirm_hits=2)
    assert [e.track_id for e in got] == [-1, 0, 0, 0, -1, 1, 1, -1, 2, 2, 2]
    assert [replace(e, track_id=-1) for e in got] == [replace(e, track_id=-1) for e in live]
    with pytest.raises(ConfigError, match="track_confirm_hits = 9 is not allowed: must be <="):
        replay(path, track_confirm_hits=9)


def _without_track_ids(source: Path, target: Path) -> None:
    """A copy of ``source`` as recorded before track ids were kept (no ``track_id``)."""
    shutil.copy(source, target)
    with h5py.File(target, "r+") as f:
        del f["estimates/track_id"]
        columns = [str(c) for c in f["estimates"].attrs["columns"] if str(c) != "track_id"]
        f["estimates"].attrs["columns"] = columns


def test_cli_replay_of_a_recording_without_track_ids_equals_live(
    live_run: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, live, _ = live_run
    old = tmp_path / "old.h5"
    _without_track_ids(path, old)
    with RunRecording.open(old) as rec:
        assert not rec.has_track_ids
        assert [e.track_id for e in rec.estimates()] == [-1] * len(live)
        assert compare_estimates(rec.estimates(), live)[0] == "differ"
        assert compare_estimates(rec.estimates(), live, track_ids=False)[0] == "equal"
    assert main(["replay", str(old), "--json"]) == 0
    out, err = capsys.readouterr()
    assert [json.loads(line)["track_id"] for line in out.splitlines()] == [e.track_id for e in live]
    assert err.startswith("replay equals live: all 11 replayed")


def test_cli_replay_lists_the_tracks(live_run: Any, capsys: pytest.CaptureFixture[str]) -> None:
    path, live, _ = live_run
    assert main(["replay", str(path)]) == 0
    lines = capsys.readouterr().out.splitlines()[1 + len(live) :]  # after the table
    assert lines[0] == f"{len(live)} estimates from {path} (gcas)"
    on0 = [e for e in live if e.track_id == 0]
    assert lines[1] == (
        f"track 0: 2 estimates, t {on0[0].t_s:.3f}–{on0[1].t_s:.3f} s, range "
        f"{on0[0].range_m:.3f} → {on0[1].range_m:.3f} m, speed "
        f"{(on0[0].speed_mps + on0[1].speed_mps) / 2:.3f} m/s (median), CRLB "
        f"{1e3 * (on0[0].crlb_range_m + on0[1].crlb_range_m) / 2:.2f} mm / "
        f"{1e3 * (on0[0].crlb_speed_mps + on0[1].crlb_speed_mps) / 2:.2f} mm/s (median)"
    )
    assert lines[2].startswith("track 1: 1 estimates") and lines[3].startswith("track 2: 2 ")
    assert lines[4] == "6 estimates on no confirmed track"
    # Then the verdict, and what GCAS refused instead of reporting (as hil estimate says it).
    assert lines[5].startswith("replay equals live")
    assert lines[6].startswith("refused: ") and "not one echo of the schedule" in lines[6]
