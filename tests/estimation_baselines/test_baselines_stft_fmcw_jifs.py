"""STFT, FMCW and JIFS receivers on exact moving-target echoes; streaming and bad inputs."""

from __future__ import annotations

import itertools
import math
import re
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.estimation.fmcw import FmcwReceiver
from hil.estimation.jifs import JifsReceiver
from hil.estimation.registry import make_receiver
from hil.estimation.stft import StftReceiver
from hil.signals.presets import check_design, get_preset
from hil.signals.waveforms import WaveformSpec, build_schedule

C = 1500.0
FS = 100_000.0
HFC = check_design(get_preset("att").spec("random-cyclic"))
FS_FM = 200_000.0
SAW = build_schedule(
    WaveformSpec(family="fmcw-saw", center_hz=50e3, bandwidth_hz=10e3, sweep_s=0.1)
)
TRI = build_schedule(
    WaveformSpec(family="fmcw-tri", center_hz=50e3, bandwidth_hz=10e3, sweep_s=0.1)
)
COMMON: dict[str, Any] = {
    "sound_speed_mps": C,
    "max_speed_mps": 15.0,
    "max_range_m": 100.0,
    "m_hops": 5,
}
FM_COMMON: dict[str, Any] = {**COMMON, "max_range_m": 30.0}


def run(rx: Any, x: np.ndarray) -> list[Any]:
    rx.reset()
    return list(rx.process(x)) + list(rx.flush())


def chunked(rx: Any, x: np.ndarray, cuts: list[int]) -> list[Any]:
    rx.reset()
    edges = np.cumsum([0, *cuts])
    out = []
    for a, b in itertools.pairwise(edges):
        out += rx.process(x[a:b])
    return out + rx.process(x[edges[-1] :]) + rx.flush()


def rmse(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(v**2)))


# ---------------------------------------------------------------- STFT
@pytest.mark.parametrize("n_s", [10, 50])
@pytest.mark.parametrize("speed", [10.0, -7.3])
def test_stft_reaches_its_time_grid_floor(kit: Any, n_s: int, speed: float) -> None:
    scene = kit.Scene(40.0, speed)
    rx = StftReceiver.from_options(HFC, FS, **COMMON, n_s=n_s)
    est = run(rx, kit.echo(HFC, FS, scene, 0.5, snr_db=40.0, seed=2))
    assert len(est) >= 45  # every hop but the first few (the code window must fill)
    floor = (C / 2) * (n_s / FS) / math.sqrt(12)
    err = scene.range_errors(est)
    assert 0.8 * floor < rmse(err) < 1.25 * floor
    assert rmse(scene.speed_errors(est)) < 0.05
    assert [e.hop_index for e in est] == sorted(e.hop_index for e in est)


def test_stft_errors_shrink_with_snr(kit: Any) -> None:
    scene = kit.Scene(25.0, 6.0)
    rx = StftReceiver.from_options(HFC, FS, **COMMON, n_s=10)
    low = run(rx, kit.echo(HFC, FS, scene, 0.5, snr_db=-3.0, seed=4))
    high = run(rx, kit.echo(HFC, FS, scene, 0.5, snr_db=20.0, seed=4))
    assert rmse(scene.range_errors(high)) < 0.5 * rmse(scene.range_errors(low))


def test_stft_segment_reading_and_chunks(kit: Any) -> None:
    rx = StftReceiver.from_options(HFC, FS, **COMMON, n_s=256, ns_reading="segment", step=20)
    assert (rx.segment, rx.step) == (256, 20)
    x = kit.echo(HFC, FS, kit.Scene(20.0, 4.0), 0.15, snr_db=10.0, seed=1)
    whole = run(rx, x)
    assert len(whole) >= 8

    @settings(max_examples=10, deadline=None)
    @given(st.lists(st.integers(1, 4000), min_size=1, max_size=6))
    def check(cuts: list[int]) -> None:
        assert chunked(rx, x, cuts) == whole

    check()


# ---------------------------------------------------------------- FMCW
def test_fmcw_sawtooth_doppler_bias_example(kit: Any) -> None:
    """SPEC: 10 m/s, B = 10 kHz, T = 0.1 s, 50 kHz → about 5 m bias on an up-sweep."""
    for speed, bias in ((10.0, -5.0), (-10.0, 5.0), (0.0, 0.0)):
        scene = kit.Scene(20.0, speed)
        rx = FmcwReceiver.from_options(SAW, FS_FM, **FM_COMMON)
        est = run(rx, kit.echo(SAW, FS_FM, scene, 0.6, snr_db=10.0, seed=3))
        assert len(est) == 4
        assert np.all(np.abs(scene.range_errors(est) - bias) < 0.1)
        assert np.all(np.abs(scene.speed_errors(est)) < 0.3)  # from the beat edges


def test_fmcw_triangle_removes_the_bias(kit: Any) -> None:
    for speed in (10.0, -10.0):
        scene = kit.Scene(15.0 if speed < 0 else 20.0, speed)
        rx = FmcwReceiver.from_options(TRI, FS_FM, **FM_COMMON)
        est = run(rx, kit.echo(TRI, FS_FM, scene, 1.1, snr_db=10.0, seed=3))
        assert len(est) >= 3  # of the pairs (2,3), (4,5), (6,7), (8,9)
        assert np.all(np.abs(scene.range_errors(est)) < 0.1)
        # Classical pair formula: the range walk between the legs scales v by 1 − B/(2 f0).
        assert np.all(np.abs(scene.speed_errors(est) + 0.1 * speed) < 0.25)


def test_fmcw_errors_shrink_with_snr_and_chunks(kit: Any) -> None:
    scene = kit.Scene(15.0, 3.0)
    rx = FmcwReceiver.from_options(SAW, FS_FM, **FM_COMMON)
    errs = []
    for snr in (-15.0, 15.0):
        est = run(rx, kit.echo(SAW, FS_FM, scene, 0.6, snr_db=snr, seed=8))
        errs.append(rmse(scene.speed_errors(est)))
    assert errs[1] < 0.5 * errs[0]
    x = kit.echo(SAW, FS_FM, scene, 0.35, snr_db=5.0, seed=1)
    whole = run(rx, x)
    assert len(whole) == 2

    @settings(max_examples=10, deadline=None)
    @given(st.lists(st.integers(1, 30_000), min_size=1, max_size=5))
    def check(cuts: list[int]) -> None:
        assert chunked(rx, x, cuts) == whole

    check()


# ---------------------------------------------------------------- JIFS
@pytest.mark.parametrize("speed", [9.0, -7.3])
def test_jifs_recovers_range_and_speed(kit: Any, speed: float) -> None:
    scene = kit.Scene(40.0, speed)
    rx = JifsReceiver.from_options(HFC, FS, **COMMON)
    est = run(rx, kit.echo(HFC, FS, scene, 0.5, snr_db=20.0, seed=1))
    assert len(est) >= 25
    assert rmse(scene.range_errors(est)) < 0.08
    assert rmse(scene.speed_errors(est)) < 0.1
    assert all(e.codeword == e.hop_index % HFC.period_hops for e in est)


def test_jifs_errors_shrink_with_snr_and_chunks(kit: Any) -> None:
    scene = kit.Scene(30.0, -4.0)
    rx = JifsReceiver.from_options(HFC, FS, **COMMON)
    lo = run(rx, kit.echo(HFC, FS, scene, 0.5, snr_db=0.0, seed=6))
    hi = run(rx, kit.echo(HFC, FS, scene, 0.5, snr_db=30.0, seed=6))
    assert rmse(scene.range_errors(hi)) < 0.7 * rmse(scene.range_errors(lo))
    x = kit.echo(HFC, FS, scene, 0.15, snr_db=15.0, seed=2)
    whole = run(rx, x)
    assert len(whole) >= 5

    @settings(max_examples=100, deadline=None)
    @given(st.lists(st.integers(1, 4000), min_size=1, max_size=6))
    def check(cuts: list[int]) -> None:
        assert chunked(rx, x, cuts) == whole

    check()


def test_jifs_keeps_a_fall_whose_rise_is_not_yet_ready(kit: Any) -> None:
    """Regression: a cut that leaves a fall ready but its rise partner (2.4 baseband samples
    later) not yet ready used to drop the fall, losing the pair and the next hop indices."""
    rx = JifsReceiver.from_options(HFC, FS, **COMMON)
    x = kit.echo(HFC, FS, kit.Scene(30.0, -4.0), 0.15, snr_db=15.0, seed=2)
    whole = run(rx, x)
    assert len(whole) == 13
    assert [e.hop_index for e in whole] == list(range(-3, 10))
    for cuts in ([1259, 4000], [1, 1, 1257, 4000], [1, 1258, 4000], [1, 1, 5257], [1257, 4000]):
        assert chunked(rx, x, cuts) == whole, cuts


# ---------------------------------------------------------------- configuration
@pytest.mark.parametrize(
    ("name", "schedule", "extra", "text"),
    [
        ("fmcw", HFC, {}, "schedule.family = 'random-cyclic' is not allowed: must be one of"),
        ("stft", SAW, {}, "schedule.family = 'fmcw-saw' is not allowed"),
        ("jifs", TRI, {}, "schedule.family = 'fmcw-tri' is not allowed"),
        ("stft", HFC, {"ns_reading": "frames"}, "ns_reading = 'frames' is not allowed"),
        ("stft", HFC, {"n_s": 0}, "n_s = 0 is not allowed: must be an integer >= 1"),
        ("jifs", HFC, {"rise_ratio": 1.5}, "rise_ratio = 1.5 is not allowed: must be 0 < value"),
        ("jifs", HFC, {"typo": 1}, "receiver.options.typo = 1 is not allowed"),
        ("fmcw", SAW, {"speed_mode": "x"}, "speed_mode = 'x' is not allowed"),
    ],
)
def test_bad_configuration(name: str, schedule: Any, extra: dict[str, Any], text: str) -> None:
    opts = FM_COMMON if schedule is not HFC else COMMON
    with pytest.raises(ConfigError, match=re.escape(text)):
        make_receiver(name, schedule, FS_FM, **opts, **extra)


def test_fmcw_range_must_leave_room_for_the_beat() -> None:
    with pytest.raises(ConfigError, match=re.escape("max_range_m = 60.0 is not allowed")):
        FmcwReceiver(SAW, FS_FM, sound_speed_mps=C, max_speed_mps=5.0, max_range_m=60.0)


@pytest.mark.parametrize("cls", [StftReceiver, JifsReceiver])
def test_nan_input_is_refused(cls: Any) -> None:
    rx = cls.from_options(HFC, FS, **COMMON)
    with pytest.raises(ConfigError, match=re.escape("block = 'NaN/inf at sample 1'")):
        rx.process(np.array([0.0, np.inf]))


def test_fmcw_nan_and_gap_accounting() -> None:
    rx = FmcwReceiver.from_options(SAW, FS_FM, **FM_COMMON)
    with pytest.raises(ConfigError, match=re.escape("block = 'NaN/inf at sample 0'")):
        rx.process(np.array([np.nan]))
    rx.process(np.zeros(10))
    rx.process(np.zeros(10), gap_before=5)
    assert rx.samples_seen == 25
