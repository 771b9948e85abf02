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

from hil.estimation import refine
from hil.estimation.base import Estimate
from hil.estimation.gcas import GcasReceiver
from sim_devices.acoustics.delay import TwoWayPath
from sim_devices.acoustics.echo import AnalyticEcho
from sim_devices.acoustics.trajectory import Fixed, Live
from sim_devices.acoustics.truth import HopTruth, hop_truth

from .conftest import FS, C, att_schedule, run_blocks

SECONDS = 1.0
HOPS = SECONDS / 0.01


def _scene(
    v0_mps: float, accel_mps2: float, snr_db: float, seed: int
) -> tuple[list[Estimate], dict[int, HopTruth]]:
    """A target from 40 m closing at ``v0_mps`` (m/s) and speeding up at ``accel_mps2``
    (m/s², negative: braking), per-sample SNR ``snr_db`` of white noise (seeded), 1 s: the
    estimates and the truth per hop boundary."""
    schedule = att_schedule()

    def position(t: np.ndarray) -> np.ndarray:
        x = 40.0 - v0_mps * t - 0.5 * accel_mps2 * t**2
        return np.stack([x, 0 * t, 0 * t], axis=-1)

    def velocity(t: np.ndarray) -> np.ndarray:
        return np.stack([-(v0_mps + accel_mps2 * t), 0 * t, 0 * t], axis=-1)

    target = Live(position, velocity, max_speed_mps=30.0)
    path = TwoWayPath.monostatic(Fixed((0.0, 0.0, 0.0)), target, C)
    n = int(SECONDS * FS)
    x = AnalyticEcho(schedule, path, FS).block(0, n)
    sigma = np.sqrt(0.5 * 10.0 ** (-snr_db / 10.0))
    x = x + np.random.default_rng(seed).normal(0.0, sigma, n)
    rx = GcasReceiver.from_options(
        schedule, FS, sound_speed_mps=C, max_speed_mps=30.0, max_range_m=100.0, m_hops=10
    )
    truth = hop_truth(schedule, Fixed((0.0, 0.0, 0.0)), target, C, n / FS, 0.2)
    return run_blocks(rx, x), {h.hop_index: h for h in truth}


def _score(
    est: list[Estimate], truth: dict[int, HopTruth]
) -> tuple[float, float, float, float]:
    """Detected fraction of the boundaries (received 0.15 s to 0.97 s, faster than 4 m/s:
    outside the band), false estimates per hop (more than 0.5 m or 0.5 m/s from their
    boundary's truth), and the on-target estimates' range and speed RMSE (m, m/s)."""
    dr, dv, hit, false = [], [], set(), 0
    for e in est:
        h = truth.get(e.hop_index + 1)
        if h is None or abs(e.range_m - h.range_m) >= 0.5:
            false += 1
        elif abs(e.speed_mps - h.radial_speed_mps) >= 0.5:
            false += 1
        else:
            hit.add(e.hop_index + 1)
            dr.append(e.range_m - h.range_m)
            dv.append(e.speed_mps - h.radial_speed_mps)
    scored = [
        k for k, h in truth.items()
        if 0.15 < h.t_rx_s < SECONDS - 0.03 and abs(h.radial_speed_mps) > 4.0
    ]  # fmt: skip
    pd = sum(k in hit for k in scored) / len(scored)
    rms = (float(np.sqrt(np.mean(np.square(d)))) if d else np.inf for d in (dr, dv))
    return pd, false / HOPS, *rms
