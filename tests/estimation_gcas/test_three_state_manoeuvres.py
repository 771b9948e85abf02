"""GCAS on att three-state (15 ms hops, M = 10) targets that brake to rest or reverse through
it (issue 26 item 3): outside the still band their boundaries are measured, and an echo that
moves on through rest is measured again as it leaves the band.

On 15 ms hops the window's curvature at one acceleration is 2.25 times random-cyclic's: at
8 m/s² the constant-speed fit of a reversing echo is no point of its curve. Where no track of
detections shows the acceleration (an echo just detected, or just out of the band, whose
detections there were refused) the window's own halves seed the curved fit; and the
detections of an echo leaving the band sit on the band's edge for half a window (the detector
reads the window's mean speed), where they are measured from the curve the echo went in on.
Without both (the same scenes through ``hil.evaluation.trials_scene``, 1.6 s, two seeds, 0
and -10 dB): braking pd 0.93, reversing 0.73.
"""

from __future__ import annotations

import numpy as np
import pytest

from hil.estimation import refine
from hil.estimation.base import Estimate
from hil.estimation.gcas import GcasReceiver
from hil.estimation.reverb_band import doppler_resolution_mps
from sim_devices.acoustics.trajectory import Live
from sim_devices.acoustics.truth import HopTruth

from .conftest import FS, C, att_schedule, make_gcas, on_boundary, run_blocks, trajectory_echo

SECONDS = 1.6


def _scene(
    r0_m: float, v0_mps: float, accel_mps2: float, stops: bool, snr_db: float, seed: int
) -> tuple[list[Estimate], list[HopTruth], GcasReceiver]:
    """A target from ``r0_m`` closing at ``v0_mps`` (m/s), its closing speed changing at
    ``accel_mps2`` (m/s²) until it comes to rest where ``stops`` (else on through rest),
    per-sample SNR ``snr_db`` of white noise (seeded), 1.6 s of att three-state: the
    estimates, the truth per hop boundary and the receiver."""
    schedule = att_schedule("three-state")
    rest = -v0_mps / accel_mps2 if stops else np.inf

    def position(t: np.ndarray) -> np.ndarray:
        t = np.minimum(t, rest)
        x = r0_m - v0_mps * t - 0.5 * accel_mps2 * t**2
        return np.stack([x, 0 * t, 0 * t], axis=-1)

    def velocity(t: np.ndarray) -> np.ndarray:
        v = np.where(t < rest, v0_mps + accel_mps2 * np.minimum(t, rest), 0.0)
        return np.stack([-v, 0 * t, 0 * t], axis=-1)

    target = Live(position, velocity, max_speed_mps=abs(v0_mps) + abs(accel_mps2) * SECONDS)
    x, truth = trajectory_echo(schedule, target, SECONDS, snr_db, seed)
    rx = make_gcas(schedule)
    return run_blocks(rx, x), truth, rx


def _score(
    est: list[Estimate], truth: list[HopTruth], rx: GcasReceiver
) -> tuple[float, int, float]:
    """Detected fraction of the boundaries received from 0.15 s to two hops before the end
    whose speed is at least one hop's Doppler resolution beyond the reverberation band
    (hil.evaluation.trials_scene's rule), the number of those boundaries, and the false
    estimates per hop (more than 0.5 m or 0.5 m/s from their boundary's truth)."""
    schedule = att_schedule("three-state")
    least = rx.reverb_speed_mps + doppler_resolution_mps(schedule.tones_hz, schedule.hop_s, C)
    by = {h.hop_index: h for h in truth}
    hit, false = set(), 0
    for e in est:
        h = on_boundary(e, by)
        if h is None:
            false += 1
        else:
            hit.add(h.hop_index)
    scored = [
        h.hop_index for h in truth
        if 0.15 <= h.t_rx_s < SECONDS - 2 * schedule.hop_s and abs(h.radial_speed_mps) >= least
    ]  # fmt: skip
    pd = sum(k in hit for k in scored) / len(scored)
    return pd, len(scored), false / (SECONDS / schedule.hop_s)


BRAKING = (40.0, 10.0, -10.0, True)
REVERSING = (50.0, 8.0, -8.0, False)


# Measured (seeds 1, 2, 3): braking 40, 40, 40 of 41 at 0 dB and 40, 40, 39 at -10 dB;
# reversing 50, 50, 50 of 51 at 0 dB and 49, 50, 50 at -10 dB (before: braking 38, reversing
# 37 at seed 1, 0 dB). The boundary missed is the first, whose window began before the
# echo did; braking's one false estimate at 0 dB (0.009 per hop, at hop 7: 34 m against
# 38.6) was there before.
@pytest.mark.parametrize(
    ("target", "snr_db", "seed"),
    [
        (BRAKING, 0.0, 1), (REVERSING, 0.0, 1),
        pytest.param(BRAKING, -10.0, 2, marks=pytest.mark.slow),
        pytest.param(REVERSING, -10.0, 2, marks=pytest.mark.slow),
    ],
)  # fmt: skip
def test_a_three_state_target_braking_or_reversing_is_detected_outside_the_band(
    target: tuple[float, float, float, bool], snr_db: float, seed: int
) -> None:
    pd, expected, false = _score(*_scene(*target, snr_db, seed))
    assert expected >= 40
    assert pd >= 0.95 and false <= 0.011


@pytest.mark.slow
def test_a_reversing_echo_leaving_the_band_is_measured_from_its_edge_detections(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Its first boundaries out of the band (2.63 m/s on three-state) come while the window's
    # mean speed is still inside: the detector sees them on the band's edge, refused there
    # as a rule. Without the curve it went in on they are lost.
    with_curve = _score(*_scene(*REVERSING, 0.0, 1))[0]
    monkeypatch.setattr(refine.CoherentRefiner, "band_exit", lambda *args: None)
    without = _score(*_scene(*REVERSING, 0.0, 1))[0]
    assert with_curve >= 0.95 and without <= 0.9


def test_a_curve_carried_on_is_the_target_s_own_boundary_time_and_speed() -> None:
    # A fit of the boundary ending hop 10 at 50 m, closing at 2 m/s and braking at 8 m/s²
    # (time scale changing at rate γ = a (α + 1)² / (2c)): 40 hops later the curve's
    # boundary is where the target's constant deceleration puts it.
    schedule = att_schedule("three-state")
    rf = refine.CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    v0, a = 2.0, -8.0
    alpha0 = (C + v0) / (C - v0)
    gamma = a * (alpha0 + 1.0) ** 2 / (2.0 * C)
    t0 = 0.2
    curve = rf._on_curve(10, t0, alpha0, gamma, 50)
    assert curve is not None
    t1, alpha1 = curve
    tau = 40 * schedule.hop_s  # transmit time between the two boundaries, s
    v1 = C * (alpha1 - 1.0) / (alpha1 + 1.0)
    # The rate is the fit's, taken at its speed: 40 hops on, 0.02 m/s of the 4.8 m/s change
    # (3e-3) is the time scale's curvature in speed; the boundary's time is within 10 µs
    # (7.5 mm of range; a grating lobe is 0.68 ms).
    assert v1 == pytest.approx(v0 + a * tau, abs=0.03)
    assert t1 - t0 == pytest.approx(tau * (1.0 - (v0 + 0.5 * a * tau) * 2.0 / C), abs=1e-5)
    assert rf._on_curve(10, t0, alpha0, gamma, 10) is None
