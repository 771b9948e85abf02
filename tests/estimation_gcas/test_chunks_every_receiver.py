"""Chunks == whole, bit for bit, for every receiver of the registry in volume reverberation.

Each receiver is fed one scene whole, in 997- and 10 000-sample blocks and at 20 seeded random
cuts; the estimates (dataclass ==), refusals and notices must be the same. The scene is long
enough (3 s at 100 kHz; FMCW 3 s at 200 kHz; the matched-filter bank, 8 CPU s a pass over 3 s,
reads its first half second) that a whole-input temporary passes the 256 KiB past which NumPy
reuses a temporary in place (its in-place complex loops round differently), so any result
that depends on the block size or on which NumPy loop runs shows here: a target
closing from 50 m at 10 m/s, braking at 5 m/s² (FMCW: from 25 m at 3 m/s, its
largest range 30 m), 10 dB per-sample SNR, with volume
reverberation at 0 dB SRR from 1 m to 100 m (0.3 scatterers/m³, a diffuse patch) as in
test_scenes' motion scenes.
"""

from __future__ import annotations

import functools
import itertools
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil.estimation.base import CountsRefusals, Estimate, SaysNotices
from hil.estimation.registry import RECEIVERS, make_receiver
from hil.estimation.tracking import TrackedReceiver, Tracker, mean_hop_s
from hil.signals.schedule import HopSchedule
from hil.signals.waveforms import WaveformSpec, build_schedule
from sim_devices.acoustics.delay import TwoWayPath
from sim_devices.acoustics.echo import AnalyticEcho
from sim_devices.acoustics.trajectory import Fixed, Live

from .conftest import FS, C, att_schedule, block_edges

SECONDS = 3.0
#: FMCW's sweep (10 kHz about 50 kHz, 0.1 s) needs 200 kHz sampling.
FS_FM = 200_000.0
BLOCKS = (997, 10_000)
RANDOM_SEEDS = (0,)
#: Receivers fed a prefix of their scene, s: the matched-filter bank costs 2.8 CPU s per second
#: of input (four passes over 3 s: 33 s); half a second still holds 45 estimates, nearly three
#: code periods and 50 000 samples (a whole-input temporary of 400 kB real, 800 kB complex:
#: past NumPy's 256 KiB).
PREFIX_S = {"mfbank": 0.5}


def _schedule(name: str) -> tuple[HopSchedule, float]:
    """The transmit schedule and sample rate (Hz) ``name`` receives."""
    if name == "fmcw":
        spec = WaveformSpec(family="fmcw-saw", center_hz=50e3, bandwidth_hz=10e3, sweep_s=0.1)
        return build_schedule(spec), FS_FM
    return att_schedule(), FS


def _scene(name: str) -> tuple[np.ndarray, np.ndarray]:
    """The input for receiver ``name`` (shape ``(SECONDS·fs,)``, or its first
    ``PREFIX_S[name]·fs`` samples) and its empty-water background (the reverberation averaged
    over the whole code periods after its first, shape ``(P,)``)."""
    x, background = _scene_of("fmcw" if name == "fmcw" else "att")
    if name in PREFIX_S:
        x = x[: int(PREFIX_S[name] * _schedule(name)[1])]
    return x, background


@functools.lru_cache(maxsize=2)
def _scene_of(name: str) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_scene` of receiver ``name`` whole, made once per schedule: every receiver but
    FMCW hears the same ``att`` scene."""
    from sim_devices.acoustics.beam import OmniBeam, TwoWayAmplitudeTable
    from sim_devices.acoustics.reverberation import ReverberationSettings, VolumeReverberation

    schedule, fs = _schedule(name)

    r0, v0, acc = (25.0, 3.0, 0.0) if name == "fmcw" else (50.0, 10.0, 5.0)

    def position(t: np.ndarray) -> np.ndarray:
        return np.stack([r0 - v0 * t + 0.5 * acc * t**2, 0 * t, 0 * t], axis=-1)

    def velocity(t: np.ndarray) -> np.ndarray:
        return np.stack([-v0 + acc * t, 0 * t, 0 * t], axis=-1)

    target = Live(position, velocity, max_speed_mps=20.0)
    n = int(SECONDS * fs)
    x = AnalyticEcho(schedule, TwoWayPath.monostatic(Fixed((0.0, 0.0, 0.0)), target, C), fs)
    x = x.block(0, n) + np.random.default_rng(4).normal(0.0, np.sqrt(0.5) / 10**0.5, n)
    settings = ReverberationSettings(
        density_per_m3=0.3, scattering_strength_db=-70.0, max_range_m=100.0,
        min_range_m=1.0, seed=104,
    )  # fmt: skip
    rev = VolumeReverberation(
        schedule, fs, source_amplitude_upa=1.0, reference_hz=50e3 if name == "fmcw" else 30e3,
        sonar_position_m=(0.0, 0.0, 0.0), sonar_velocity_mps=(0.0, 0.0, 0.0),
        beam=TwoWayAmplitudeTable(OmniBeam(), OmniBeam()), beam_axis=(1.0, 0.0, 0.0),
        sound_speed_mps=C, settings=settings,
    )  # fmt: skip
    reverb = np.sqrt(0.5 / rev.expected_power(0.0)) * rev.generate(n)
    period = schedule.period_samples(fs)
    assert period is not None
    background = reverb[period : n - n % period].reshape(-1, period).mean(axis=0)
    return x + reverb, background


def _run(name: str, edges: list[int], tracked: bool = False, **extra: Any) -> dict[str, Any]:
    """Receiver ``name``'s (options ``extra``; behind a :class:`Tracker` where ``tracked``)
    estimates, refusals and notices with its scene fed in the blocks between ``edges``."""
    schedule, fs = _schedule(name)
    max_range_m = 30.0 if name == "fmcw" else 100.0
    rx = make_receiver(
        name, schedule, fs, sound_speed_mps=C, max_speed_mps=15.0, max_range_m=max_range_m,
        m_hops=5, **extra,
    )  # fmt: skip
    if tracked:
        rx = TrackedReceiver(rx, Tracker(mean_hop_s(schedule)))
    x = _scene(name)[0]
    est: list[Estimate] = []
    for a, b in itertools.pairwise(edges):
        est += rx.process(x[a:b])
    est += rx.flush()
    return {
        "estimates": est,
        "refusals": rx.refusals() if isinstance(rx, CountsRefusals) else None,
        "notices": list(rx.notices()) if isinstance(rx, SaysNotices) else None,
    }


#: Every receiver of the registry, GCAS and its clutter canceller read at the first arrival
#: (gcas-bg reads there by default), and GCAS so read behind the tracker (its track ids).
CASES = [
    *((name, "", False) for name in RECEIVERS),
    ("gcas", "first-arrival", False),
    ("gcas-mti", "first-arrival", False),
    ("gcas", "first-arrival", True),
]


#: The whole test is left to ``--all``: the matched-filter bank takes 7.3 CPU s over its 0.5 s
#: prefix (whole and three cut lists, scene included; 12.7 over 1 s, both at load 12), the
#: STFT, FMCW and JIFS baselines 2.8, 1.4 and 1.0 CPU s and the GCAS cases 0.5-1.8 CPU s each
#: (measured, numba's cache warm); the fast tier keeps chunks == whole tests of GCAS
#: (test_gcas_receiver) and of the STFT, FMCW and JIFS baselines
#: (test_baselines_stft_fmcw_jifs).
@pytest.mark.slow
@pytest.mark.parametrize(("name", "range_readout", "tracked"), CASES)
def test_every_receiver_gives_the_same_estimates_in_any_blocks(
    name: str, range_readout: str, tracked: bool, tmp_path: Path
) -> None:
    extra: dict[str, Any] = {"range_readout": range_readout} if range_readout else {}
    x, background = _scene(name)
    if name == "gcas-bg":
        np.save(tmp_path / "background.npy", background)
        extra["background"] = str(tmp_path / "background.npy")
    whole = _run(name, [0, x.shape[0]], tracked, **extra)
    for cut in (*BLOCKS, *(f"random-{s}" for s in RANDOM_SEEDS)):
        parts = _run(name, block_edges(x.shape[0], cut), tracked, **extra)
        for key, value in whole.items():
            assert parts[key] == value, (key, cut)
    assert len(whole["estimates"]) >= 10
    assert not tracked or any(e.track_id >= 0 for e in whole["estimates"])
