"""The time–codeword map the watch server computes from the recorded samples: the true
codeword is the map's strongest where each hop boundary arrives, and a map followed through
a growing recording equals the map of the finished one (chunks == whole)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.recording.records import ReceiverSetup
from hil.recording.writer import RunWriter
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule_file import schedule_document
from hil.watch import WatchData

FS = 100_000.0
C = 1500.0
RANGE_M = 40.0
SPEED_MPS = 9.0
"""The target starts RANGE_M away and closes at SPEED_MPS (GCAS's reverberation band
leaves out targets standing still)."""
N = 150_000
"""1.5 s of samples."""


def _echo() -> np.ndarray:
    """(N, 1) float32: the target's echo with noise at 3 dB SNR (seeded)."""
    from sim_devices.acoustics.delay import TwoWayPath
    from sim_devices.acoustics.echo import AnalyticEcho
    from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed

    schedule = check_design(get_preset("att").spec("random-cyclic"))
    sonar = Fixed([0.0, 0.0, 0.0])
    target = ConstantVelocity([RANGE_M, 0.0, 0.0], [-SPEED_MPS, 0.0, 0.0])
    path = TwoWayPath(sonar, target, sonar, C)
    rng = np.random.default_rng(7)
    x = AnalyticEcho(schedule, path, FS).block(0, N) + rng.normal(0.0, 0.5, N)
    return (0.5 * x / np.max(np.abs(x))).astype(np.float32)[:, None]


def _writer(path: Path, receiver: str = "gcas") -> RunWriter:
    schedule = check_design(get_preset("att").spec("random-cyclic"))
    doc = schedule_document(schedule, FS, 0.0, sound_speed_mps=C)
    return RunWriter.create(
        path,
        fs_hz=FS,
        n_channels=1,
        dtype="float32",
        schedule_document=doc,
        receiver=ReceiverSetup(receiver, {"m_hops": 10}),
        origin_sample=0,
    )


def _snapshot(path: Path, cuts: tuple[int, ...]) -> dict[str, Any]:
    """The map followed while the samples are written in pieces ending at ``cuts``."""
    x = _echo()
    with _writer(path) as w:
        data = WatchData.open(path, live_map=True)
        try:
            assert data.live_map is not None
            start = 0
            for stop in cuts:
                w.append_samples(start, x[start:stop])
                w.flush()
                assert data.live_map.update(max_frames=20_000) == stop - start
                assert data.live_map.update() == 0  # nothing new
                start = stop
            return data.codeword_map()["map"]  # type: ignore[no-any-return]
        finally:
            data.close()


def test_the_true_codeword_is_strongest_where_each_boundary_arrives(tmp_path: Path) -> None:
    m = _snapshot(tmp_path / "run.h5", (N,))
    assert m["error"] == ""
    assert m["computed_to_s"] == pytest.approx(N / FS)
    assert m["column_s"] == pytest.approx(0.005)
    t, db = np.asarray(m["t_s"]), np.asarray(m["db"])
    assert db.shape == (t.size, 17) and db.max() == 0.0 and db.min() >= -30.0
    # Hop k (10 ms) ends at T = 0.01 (k + 1) s; that boundary bounces off the target at
    # t_b = (T + R0/c) / (1 + v/c) and arrives at T + 2 (R0 - v t_b) / c. After the
    # receiver's first M = 10 hops, the column holding each arrival peaks at codeword k.
    k = np.arange(12, 140)
    end = 0.01 * (k + 1)
    bounce = (end + RANGE_M / C) / (1 + SPEED_MPS / C)
    arrival = end + 2 * (RANGE_M - SPEED_MPS * bounce) / C
    inside = arrival < N / FS - m["column_s"]
    col = np.searchsorted(t, arrival[inside], side="right") - 1
    assert np.mean(db[col].argmax(axis=1) == k[inside] % 17) >= 0.95


@pytest.mark.slow
def test_followed_map_equals_the_map_of_the_whole(tmp_path: Path) -> None:
    whole = _snapshot(tmp_path / "a.h5", (N,))
    pieces = _snapshot(tmp_path / "b.h5", (33_333, 90_001, N))
    assert pieces["t_s"] == whole["t_s"] and len(whole["t_s"]) == 301  # from -5 ms
    assert pieces["db"] == whole["db"]


def test_only_gcas_has_a_map(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    with _writer(path, receiver="stft"):
        pass
    with pytest.raises(ConfigError, match=r"^--map = 'stft' is not allowed: must be a recording"):
        WatchData.open(path, live_map=True)
    bare = tmp_path / "bare.h5"
    schedule = check_design(get_preset("att").spec("random-cyclic"))
    doc = schedule_document(schedule, FS, 0.0, sound_speed_mps=C)
    with RunWriter.create(bare, fs_hz=FS, n_channels=1, dtype="int16", schedule_document=doc):
        pass
    with pytest.raises(ConfigError) as err:
        WatchData.open(bare, live_map=True)
    assert str(err.value) == (
        "--map = None is not allowed: must be a recording whose live receiver is gcas, "
        "gcas-mti or gcas-bg (those with a time–codeword map); watch it without --map"
    )


@pytest.mark.slow
def test_a_long_map_is_max_pooled_to_the_columns_sent(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    whole = _snapshot(tmp_path / "a.h5", (N,))
    monkeypatch.setattr("hil.watch.live_map.MAX_SENT_COLUMNS", 100)
    pooled = _snapshot(tmp_path / "b.h5", (N,))
    # 301 columns of 5 ms from -5 ms -> groups of 4 (20 ms) starting at -20 ms.
    assert pooled["column_s"] == pytest.approx(0.02)
    assert pooled["t_s"] == pytest.approx(0.02 * np.arange(-1, 75))
    t, db = np.asarray(whole["t_s"]), np.asarray(whole["db"])
    group = np.floor(np.round(t / 0.005) / 4).astype(int)
    expected = [db[group == g].max(axis=0) for g in range(-1, 75)]
    np.testing.assert_array_equal(pooled["db"], expected)
