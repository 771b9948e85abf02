"""GCAS on targets accelerating or braking at 15 and 25 m/s² (att, M = 10, `max_speed_mps`
30 as `hil estimate`'s default), and the seeding of the curved fit from the detections' own
speed trend (hil.estimation.refine, accelerating echoes; issue 26).

Before the seed an echo accelerating at 15 m/s² or faster was refused at every boundary
("not one echo"): its constant-speed fits keep 0.4-0.6 of one echo's run coherence, below
the curved fit's gate, and where tried the rate grid about such a fit climbed to -7..+1.5
m/s², never to the echo's rate.
"""

from __future__ import annotations

import numpy as np
import pytest

from hil.estimation import refine_accel
from hil.estimation.base import Estimate
from sim_devices.acoustics.trajectory import Live
from sim_devices.acoustics.truth import HopTruth

from .conftest import C, att_schedule, make_gcas, on_boundary, run_blocks, trajectory_echo

SECONDS = 1.0
HOPS = SECONDS / 0.01


def _scene(
    v0_mps: float, accel_mps2: float, snr_db: float, seed: int, family: str = "random-cyclic"
) -> tuple[list[Estimate], dict[int, HopTruth]]:
    """A target from 40 m closing at ``v0_mps`` (m/s) and speeding up at ``accel_mps2``
    (m/s², negative: braking), per-sample SNR ``snr_db`` of white noise (seeded), 1 s, on
    att's ``family``: the estimates and the truth per hop boundary."""
    schedule = att_schedule(family)

    def position(t: np.ndarray) -> np.ndarray:
        x = 40.0 - v0_mps * t - 0.5 * accel_mps2 * t**2
        return np.stack([x, 0 * t, 0 * t], axis=-1)

    def velocity(t: np.ndarray) -> np.ndarray:
        return np.stack([-(v0_mps + accel_mps2 * t), 0 * t, 0 * t], axis=-1)

    target = Live(position, velocity, max_speed_mps=30.0)
    x, truth = trajectory_echo(schedule, target, SECONDS, snr_db, seed)
    return run_blocks(make_gcas(schedule), x), {h.hop_index: h for h in truth}


def _score(
    est: list[Estimate], truth: dict[int, HopTruth], hops: float = HOPS
) -> tuple[float, float, float, float]:
    """Detected fraction of the boundaries (received 0.15 s to 0.97 s, faster than 4 m/s:
    outside the band), false estimates per hop (more than 0.5 m or 0.5 m/s from their
    boundary's truth), and the on-target estimates' range and speed RMSE (m, m/s)."""
    dr, dv, hit, false = [], [], set(), 0
    for e in est:
        h = on_boundary(e, truth)
        if h is None:
            false += 1
        else:
            hit.add(h.hop_index)
            dr.append(e.range_m - h.range_m)
            dv.append(e.speed_mps - h.radial_speed_mps)
    scored = [
        k for k, h in truth.items()
        if 0.15 < h.t_rx_s < SECONDS - 0.03 and abs(h.radial_speed_mps) > 4.0
    ]  # fmt: skip
    pd = sum(k in hit for k in scored) / len(scored)
    rms = (float(np.sqrt(np.mean(np.square(d)))) if d else np.inf for d in (dr, dv))
    return pd, false / hops, *rms


# Measured (seed 1): pd 1.0 and no false estimate in all eight; range / speed RMSE 1.0 / 5.9,
# 1.1 / 5.5, 1.3 / 8.3, 1.0 / 5.4 mm, mm/s at 0 dB (the order below) and 2.9 / 18, 3.6 / 17,
# 4.0 / 26, 3.5 / 42 at -10 dB. Before the seed: pd 0 in all eight (0.02 false per hop at
# +25 m/s², 0 dB). Braking from 28 m/s, 2 m/s inside the span: the first detections' speeds
# scatter most there, and their slopes read -10 to -49 m/s² at -25.
@pytest.mark.parametrize(
    ("v0", "accel", "snr_db", "max_speed_rms"),
    [
        (5.0, 15.0, 0.0, 0.01), (3.0, 25.0, 0.0, 0.01), (28.0, -15.0, 0.0, 0.015),
        (28.0, -25.0, 0.0, 0.01),
        pytest.param(5.0, 15.0, -10.0, 0.03, marks=pytest.mark.slow),
        pytest.param(3.0, 25.0, -10.0, 0.03, marks=pytest.mark.slow),
        pytest.param(28.0, -15.0, -10.0, 0.04, marks=pytest.mark.slow),
        pytest.param(28.0, -25.0, -10.0, 0.06, marks=pytest.mark.slow),
    ],
)  # fmt: skip
def test_a_target_accelerating_at_15_or_25_mps2_is_measured(
    v0: float, accel: float, snr_db: float, max_speed_rms: float
) -> None:
    pd, false, range_rms, speed_rms = _score(*_scene(v0, accel, snr_db, seed=1))
    assert pd >= 0.97 and false <= 0.01
    assert range_rms < (0.002 if snr_db == 0.0 else 0.006) and speed_rms < max_speed_rms


@pytest.mark.slow
@pytest.mark.parametrize(
    ("seed_hop_s", "detected", "false_per_hop"),
    [(refine_accel.ACCEL_SEED_HOP_S, 55, 0.0), (0.015, 4, 0.015)],
)
def test_a_three_state_target_braking_at_6_mps2_is_seeded_from_its_hop_length(
    seed_hop_s: float, detected: int, false_per_hop: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    # att three-state hops are 15 ms: at M = 10 the window's curvature at one acceleration is
    # 2.25 times random-cyclic's, so its seed threshold is 8 (10 / 15)² = 3.6 m/s². Seeded
    # from 8 m/s² only (ACCEL_SEED_HOP_S at its hop length), a target braking from 20 m/s at
    # 6 m/s² kept 4 of its 56 boundaries (measured 30 Nov; 7.5 m/s²: 0.96, 10: 0.85-0.93).
    # Seeded also from the window's halves (the same threshold): 55 (52 from the track only).
    monkeypatch.setattr(refine_accel, "ACCEL_SEED_HOP_S", seed_hop_s)
    est, truth = _scene(20.0, -6.0, 0.0, seed=1, family="three-state")
    pd, false, range_rms, _ = _score(est, truth, SECONDS / 0.015)
    assert (round(pd * 56), false) == (detected, pytest.approx(false_per_hop, abs=1e-9))
    if detected > 50:
        assert range_rms < 0.003


def _track(accel: float, noise: float, hops: int = 8, seed: int = 3) -> tuple[np.ndarray, ...]:
    """Detections of one echo at hops 0..hops-1 (10 ms, from 40 m, 10 m/s closing and
    ``accel`` m/s²; speed noise ``noise`` m/s RMS, seeded) plus a still echo's at 60 m each hop."""
    rng = np.random.default_rng(seed)
    k = np.arange(hops, dtype=np.float64)
    v = 10.0 + accel * 0.01 * k + rng.normal(0.0, noise, hops)
    t = 2.0 * 40.0 / C + 0.01 * k * (1.0 - 2.0 * 10.0 / C)
    hops_all = np.concatenate((k, k))
    times = np.concatenate((t, 2.0 * 60.0 / C + 0.01 * k))
    speeds = np.concatenate((v, np.zeros(hops)))
    return hops_all, times, speeds


@pytest.mark.parametrize("accel", [-30.0, -15.0, 0.0, 15.0, 30.0])
def test_the_seed_is_the_speed_trend_of_the_echo_s_own_detections(accel: float) -> None:
    hops, times, speeds = _track(accel, 0.0)
    last = hops == 7
    last[8:] = False
    trend = refine_accel.speed_trend(
        hops[~last], times[~last], speeds[~last], 7, float(times[last][0]),
        float(speeds[last][0]), 0.01, C, 0.005, 1.0,
    )  # fmt: skip
    assert trend is not None
    assert trend[0] == pytest.approx(accel, abs=1e-9) and trend[1] == pytest.approx(0.0, abs=1e-9)


def test_the_seed_s_error_grows_with_the_detections_scatter() -> None:
    hops, times, speeds = _track(20.0, 0.1)
    keep = np.ones(hops.shape[0], dtype=bool)
    keep[7] = False
    trend = refine_accel.speed_trend(
        hops[keep], times[keep], speeds[keep], 7, float(times[7]), float(speeds[7]), 0.01, C,
        0.005, 1.0,
    )  # fmt: skip
    assert trend is not None
    # The slope's scatter over 8 hops at 0.1 m/s: 0.1 / sqrt(Σ (t - t̄)²) = 4.4 m/s².
    assert abs(trend[0] - 20.0) < 3.0 * 4.4 and 1.5 < trend[1] < 10.0


def test_no_seed_from_too_few_detections_or_from_another_echo() -> None:
    hops, times, speeds = _track(20.0, 0.0, hops=3)
    # Two earlier detections of the echo and this one: fewer than ACCEL_SEED_POINTS.
    assert (
        refine_accel.speed_trend(hops[:2], times[:2], speeds[:2], 2, float(times[2]),
                           float(speeds[2]), 0.01, C, 0.005, 1.0) is None
    )  # fmt: skip
    # The still echo's detections are not on a track at 40 m and 10 m/s.
    hops, times, speeds = _track(20.0, 0.0)
    still = slice(8, 15)
    assert (
        refine_accel.speed_trend(hops[still], times[still], speeds[still], 7, float(times[7]),
                           float(speeds[7]), 0.01, C, 0.005, 1.0) is None
    )  # fmt: skip
