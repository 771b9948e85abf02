"""Round trips of every record a run recording holds, segment/gap bookkeeping, the
time-based flush, and refused input on both sides."""

from __future__ import annotations

import json
import math
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.recording import (
    FORMAT_VERSION,
    ReceiverSetup,
    RunEvent,
    RunRecording,
    RunWriter,
    StageTelemetry,
)
from hil.signals.schedule import HopSchedule

FS = 100_000.0


def _writer(path: Path, doc: dict[str, Any], **kw: Any) -> RunWriter:
    args: dict[str, Any] = {"fs_hz": FS, "n_channels": 2, "dtype": "int16", **kw}
    return RunWriter.create(path, schedule_document=doc, **args)


def test_every_record_kind_round_trips(
    tmp_path: Path, schedule_doc: dict[str, Any], schedule: HopSchedule
) -> None:
    path = tmp_path / "run.h5"
    setup = ReceiverSetup("gcas", {"m_hops": 8, "n_doppler": 32}, channel=2, scale=2.0**-31)
    rng = np.random.default_rng(1)
    a = rng.integers(-(2**31), 2**31, size=(700, 3), dtype=np.int32)
    b = rng.integers(-(2**31), 2**31, size=(300, 3), dtype=np.int32)
    telemetry = [
        StageTelemetry(12.5, 1_000_123, 0.25, -0.5, "Run", 0.021),
        StageTelemetry(12.6, 1_010_123, 0.20, -0.5, "Hold:0", math.inf),  # undated reply
    ]
    estimates = [
        Estimate(0.11, 39.2, 9.0, 5, 177.8, 27.9, 1.012, 0.06, 5, "gcas"),
        Estimate(0.12, 39.1, 9.1, 6, 150.0, math.nan, 1.012, 0.07, 6, "gcas"),
        Estimate(0.013, 40.1, 9.1, -5, 0.98, 56.2, 1.012, -0.04, 12, "stft"),
    ]
    toml = 'name = "tow 3"\n[stage]\nspeed_mps = 0.5  # ü\n'
    with RunWriter.create(
        path,
        fs_hz=FS,
        n_channels=3,
        dtype=np.int32,
        schedule_document=schedule_doc,
        receiver=setup,
        experiment_toml=toml,
        calibration_ids=["hydrophone-2024-07", "tx-gain-3"],
        protocol_schema_hash=0xDEADBEEF,
        origin_sample=999_000,
    ) as w:
        w.append_samples(1_000_000, a)
        w.append_samples(1_000_750, b)  # 50 samples lost
        w.append_sync(1_000_000, 12.25)
        w.append_sync(1_001_000, 12.26)
        for t in telemetry:
            w.append_telemetry(t)
        w.append_event(RunEvent("xrun", 1_000_500, 0, "host late"))
        w.append_estimates(estimates)
        w.append_event(RunEvent("overrun", 1_000_900, 3, "ADC overrun"))

    with RunRecording.open(path) as rec:
        m = rec.metadata
        assert (m.fs_hz, m.n_channels, m.sample_dtype) == (FS, 3, "int32")
        assert m.experiment_toml == toml
        assert m.calibration_ids == ("hydrophone-2024-07", "tx-gain-3")
        assert m.receiver == setup
        assert m.origin_sample == rec.origin_sample == 999_000
        assert m.versions["protocol_schema_hash"] == 0xDEADBEEF
        assert m.versions["h5py"] == h5py.version.version
        assert m.versions["hdf5"] == h5py.version.hdf5_version
        assert set(m.versions) >= {"hil", "numpy", "python"}
        assert rec.schedule_document() == json.loads(json.dumps(schedule_doc))
        assert rec.schedule().period_dict() == schedule.period_dict()

        blocks = rec.samples()
        assert [x.first_index for x in blocks] == [1_000_000, 1_000_750]
        np.testing.assert_array_equal(blocks[0].data, a)
        np.testing.assert_array_equal(blocks[1].data, b)
        assert blocks[0].data.dtype == np.int32
        assert rec.gaps() == [(1_000_700, 50)]
        assert rec.n_samples == 1000

        pairs = rec.sync_pairs()
        assert pairs.sample_index.tolist() == [1_000_000, 1_001_000]
        assert pairs.host_time_s.tolist() == [12.25, 12.26]
        assert rec.telemetry() == telemetry
        assert rec.events() == [
            RunEvent("gap", 1_000_700, 50, "samples 1000700 .. 1000749 missing"),
            RunEvent("xrun", 1_000_500, 0, "host late"),
            RunEvent("overrun", 1_000_900, 3, "ADC overrun"),
        ]
        got = rec.estimates()
        assert got[0] == estimates[0] and got[2] == estimates[2]
        assert math.isnan(got[1].snr_db) and got[1].range_m == 39.1
        assert rec.estimates("stft") == [estimates[2]]
        assert [e.receiver for e in rec.estimates("gcas")] == ["gcas", "gcas"]

    with h5py.File(path, "r") as f:  # the period arrays, for tools that do not parse JSON
        np.testing.assert_array_equal(f["schedule/period/code"][:], schedule.code)
        np.testing.assert_array_equal(f["schedule/period/freq_hz"][:], schedule.freq_hz)
        assert f.attrs["format_version"] == FORMAT_VERSION
        assert f["samples"].chunks == (65536, 3)
        assert f["samples"].maxshape == (None, 3)


@pytest.mark.parametrize("dtype", ["int16", "int32", "float32"])
def test_samples_keep_the_captured_dtype(
    tmp_path: Path, schedule_doc: dict[str, Any], dtype: str
) -> None:
    x = (np.arange(40, dtype=np.float64).reshape(20, 2) * 1.5 - 7).astype(dtype)
    with _writer(tmp_path / "d.h5", schedule_doc, dtype=dtype, chunk_frames=8) as w:
        w.append_samples(5, x[:13])
        w.append_samples(18, x[13:])
    with RunRecording.open(tmp_path / "d.h5") as rec:
        (blk,) = rec.samples()
        assert blk.first_index == 5 and blk.data.dtype == np.dtype(dtype)
        np.testing.assert_array_equal(blk.data, x)


blocks_strategy = st.lists(
    st.tuples(st.integers(0, 300), st.integers(0, 200)),  # (samples lost before, samples)
    min_size=1,
    max_size=12,
)


@pytest.mark.slow
@settings(max_examples=40, deadline=None)
@given(
    blocks=blocks_strategy,
    first=st.integers(0, 2**40),
    window=st.tuples(st.integers(-50, 3000), st.integers(0, 3000)),
    max_frames=st.integers(1, 500),
)
def test_gaps_and_indices_come_back_exactly(
    blocks: list[tuple[int, int]],
    first: int,
    window: tuple[int, int],
    max_frames: int,
    schedule_doc: dict[str, Any],
) -> None:
    rng = np.random.default_rng(len(blocks) * 1000 + first % 997)
    written: dict[int, np.ndarray] = {}
    index = first
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "p.h5"
        with _writer(path, schedule_doc, dtype="int32", chunk_frames=64) as w:
            for lost, n in blocks:
                index += lost
                x = rng.integers(-1000, 1000, size=(n, 2), dtype=np.int32)
                w.append_samples(index, x)
                written.update({index + i: x[i] for i in range(n)})
                index += n
        keys = sorted(written)
        # Expected segments: runs of consecutive board indices.
        starts = [k for k in keys if k - 1 not in written]
        stops = [k + 1 for k in keys if k + 1 not in written]
        with RunRecording.open(path) as rec:
            seg = rec.segments()
            assert seg.sample_index.tolist() == starts
            assert seg.stop_index.tolist() == stops
            assert rec.gaps() == [(s, t - s) for s, t in zip(stops[:-1], starts[1:], strict=True)]
            gap_events = [(e.sample_index, e.length) for e in rec.events() if e.kind == "gap"]
            assert gap_events == rec.gaps()
            assert rec.n_samples == len(keys)
            assert rec.origin_sample == (starts[0] if starts else 0)

            lo, hi = first + window[0], first + window[0] + window[1]
            got = rec.samples(lo, hi)
            want = [k for k in keys if lo <= k < hi]
            got_index = [blk.first_index + i for blk in got for i in range(len(blk.data))]
            assert got_index == want
            for blk in got:
                assert len(blk.data) > 0
                for i, row in enumerate(blk.data):
                    np.testing.assert_array_equal(row, written[blk.first_index + i])
            # Blocks of bounded size: the same samples, never across a gap.
            pieces = list(rec.iter_blocks(max_frames))
            assert all(0 < len(p.data) <= max_frames for p in pieces)
            assert [p.first_index + i for p in pieces for i in range(len(p.data))] == keys
            assert all(p.stop_index - 1 in written for p in pieces)


class FakeClock:
    """A clock the test moves by hand (s)."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@settings(max_examples=25, deadline=None)
@given(steps=st.lists(st.floats(0.0, 0.7), min_size=1, max_size=40))
def test_time_based_flush_keeps_every_append_within_a_second_of_a_flush(
    steps: list[float], schedule_doc: dict[str, Any]
) -> None:
    clock = FakeClock()
    with tempfile.TemporaryDirectory() as folder:
        w = _writer(Path(folder) / "f.h5", schedule_doc, clock=clock)
        with w:
            flushes, flushed_rows = 0, 0
            for i, dt in enumerate(steps):
                clock.now += dt
                due = clock.now - w.last_flush_s >= 1.0
                w.append_sync(i, clock.now)
                flushes += due
                assert w.flush_count == flushes
                assert clock.now - w.last_flush_s < 1.0
                # Flushed rows are in the file; the rest wait for the next flush.
                flushed_rows = i + 1 if due else flushed_rows
                assert w._file["sync/sample_index"].shape[0] == flushed_rows
        with RunRecording.open(Path(folder) / "f.h5") as rec:
            assert rec.sync_pairs().sample_index.tolist() == list(range(len(steps)))


def test_rows_wait_for_the_flush(tmp_path: Path, schedule_doc: dict[str, Any]) -> None:
    clock = FakeClock()
    with _writer(tmp_path / "w.h5", schedule_doc, clock=clock) as w:
        w.append_event(RunEvent("note", 0, 0, "a"))
        clock.now = 0.999
        w.append_event(RunEvent("note", 1, 0, "b"))
        assert (w.flush_count, w._file["events/kind"].shape[0]) == (0, 0)
        clock.now = 1.0
        w.append_event(RunEvent("note", 2, 0, "c"))
        assert (w.flush_count, w._file["events/kind"].shape[0]) == (1, 3)


def test_samples_wait_for_the_flush_or_a_full_chunk(
    tmp_path: Path, schedule_doc: dict[str, Any]
) -> None:
    clock = FakeClock()
    block = np.arange(10, dtype=np.int16).reshape(5, 2)
    with _writer(tmp_path / "s.h5", schedule_doc, clock=clock, chunk_frames=8) as w:
        w.append_samples(100, block)
        block[:] = -1  # the caller reuses its buffer: the waiting copy keeps the samples
        assert w._file["samples"].shape[0] == 0
        w.append_samples(105, np.full((5, 2), 7, dtype=np.int16))  # 10 rows >= one chunk
        assert w._file["samples"].shape[0] == 10
        w.append_samples(112, np.full((3, 2), 9, dtype=np.int16))  # a gap: a new segment
        assert (w._file["samples"].shape[0], w.next_sample_index) == (10, 115)
        w.flush()
        assert w._file["samples"].shape[0] == 13
        assert w._file["flushes/sample_rows"][-1] == 13
    with RunRecording.open(tmp_path / "s.h5") as rec:
        first, second = rec.samples()
        assert (first.first_index, second.first_index) == (100, 112)
        expected = np.concatenate([np.arange(10).reshape(5, 2), np.full((5, 2), 7)])
        assert np.array_equal(first.data, expected)
        assert np.array_equal(second.data, np.full((3, 2), 9))
        assert rec.segments().row.tolist() == [0, 10]


# ---------------------------------------------------------------------- refused input
@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"dtype": "float64"}, "dtype = 'float64' is not allowed: must be one of int16, int32"),
        ({"n_channels": 0}, "n_channels = 0 is not allowed: must be >= 1"),
        ({"fs_hz": 48_000.0}, "fs_hz = 48000.0 is not allowed: must be the schedule's sample"),
        ({"flush_interval_s": 2.0}, "flush_interval_s = 2.0 is not allowed: must be 0 < interval"),
        ({"chunk_frames": 0}, "chunk_frames = 0 is not allowed"),
        (
            {"receiver": ReceiverSetup("gcas", channel=2)},
            "receiver.channel = 2 is not allowed: must be 0..1",
        ),
        (
            {"schedule_document": {"format": "x"}},
            "schedule_document.format = 'x' is not allowed: must be \"cas-hil-schedule\"",
        ),
    ],
)
def test_bad_writer_settings_are_refused_before_the_file_exists(
    tmp_path: Path, schedule_doc: dict[str, Any], kw: dict[str, Any], message: str
) -> None:
    path = tmp_path / "bad.h5"
    args: dict[str, Any] = {"schedule_document": schedule_doc, **kw}
    doc = args.pop("schedule_document")
    with pytest.raises(ConfigError, match=r"^" + message.replace("(", r"\(")) as err:
        _writer(path, doc, **args)
    assert message in str(err.value)
    assert not path.exists()


def test_an_existing_recording_is_never_overwritten(
    tmp_path: Path, schedule_doc: dict[str, Any]
) -> None:
    path = tmp_path / "run.h5"
    _writer(path, schedule_doc).close()
    with pytest.raises(ConfigError, match=r"path = .* must be a new file; recordings are never"):
        _writer(path, schedule_doc)


def test_bad_appends_are_refused(tmp_path: Path, schedule_doc: dict[str, Any]) -> None:
    with _writer(tmp_path / "a.h5", schedule_doc) as w:
        w.append_samples(100, np.zeros((10, 2), np.int16))
        with pytest.raises(ConfigError, match=r"samples.first_index = 105 .* must be >= 110"):
            w.append_samples(105, np.zeros((10, 2), np.int16))
        with pytest.raises(ConfigError, match=r"samples.shape = \(10, 3\) .* \(n, 2\)"):
            w.append_samples(110, np.zeros((10, 3), np.int16))
        with pytest.raises(ConfigError, match=r"samples.dtype = 'int32' .* must be int16"):
            w.append_samples(110, np.zeros((10, 2), np.int32))
    with pytest.raises(ConfigError, match=r"event.kind = 'bang' .* one of gap, xrun, alarm"):
        RunEvent("bang", 0)
    with pytest.raises(ConfigError, match=r"receiver.settings.on_map = .* must be a JSON value"):
        ReceiverSetup("gcas", {"on_map": print})
    with pytest.raises(ConfigError, match=r"receiver.scale = 0.0"):
        ReceiverSetup("gcas", scale=0.0)


def test_the_run_end_maps_every_telemetry_row_once(
    tmp_path: Path, schedule_doc: dict[str, Any]
) -> None:
    # Rows appended live with the clock fit of the moment (one still waiting for a flush)
    # get the run's final mapping; the other columns stay as they were.
    path = tmp_path / "run.h5"
    live = [StageTelemetry(1.0 + 0.2 * i, 1000 * i - 1, 0.1 * i, -0.5, "Run", 0.01 * i)
            for i in range(3)]  # fmt: skip
    with _writer(path, schedule_doc) as w:
        w.append_telemetry(live[0])
        w.flush()
        for t in live[1:]:
            w.append_telemetry(t)
        with pytest.raises(ConfigError) as err:
            w.map_telemetry_times([5, 6])
        assert str(err.value) == (
            "telemetry sample_index = '2 values' is not allowed: must be one per recorded stage"
            " report (3); map every report the recording holds, in the order recorded"
        )
        w.map_telemetry_times([100_000, 120_000, 140_001])
    with RunRecording.open(path) as rec:
        assert rec.telemetry() == [
            replace(t, sample_index=i) for t, i in zip(live, (100_000, 120_000, 140_001),
                                                       strict=True)
        ]  # fmt: skip


def test_files_that_are_not_recordings_are_refused(
    tmp_path: Path, schedule_doc: dict[str, Any]
) -> None:
    text = tmp_path / "notes.txt"
    text.write_text("not hdf5")
    with pytest.raises(
        ConfigError, match=r"recording = .*notes.txt.* must be an HDF5 run recording"
    ):
        RunRecording.open(text)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = [1, 2]
    with pytest.raises(ConfigError, match=r'recording.format = None .* must be "cas-hil-run"'):
        RunRecording.open(other)
    with pytest.raises(ConfigError, match=r"recording = .*missing.h5.* an existing run recording"):
        RunRecording.open(tmp_path / "missing.h5")
    future = tmp_path / "future.h5"
    _writer(future, schedule_doc).close()
    with h5py.File(future, "r+") as f:
        f.attrs["format_version"] = 99
    with pytest.raises(
        ConfigError,
        match=r"recording.format_version = 99 .* must be one of 1, 2 \(the versions this hil",
    ):
        RunRecording.open(future)
