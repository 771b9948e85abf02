"""A still point echo (a wall) far above a moving target (att, M = 10, span 30 m/s, the default
reverberation band): the wall is measured at rest and taken out of the target's fits
(:meth:`~hil.estimation.refine.CoherentRefiner.refine_still`, :mod:`hil.estimation.gcas.
hidden_echoes`), so the target keeps its boundaries and its grating lobe.

Before, the wall's fits from the band's edge toward rest stopped short of it and it was never
taken out: with the wall at 30 m 20 dB above a target at 50 m closing 8 m/s (0 dB), the
target's fit collected 16.5 dB instead of about 37, pd 0.27 with 0.41 false estimates per hop,
each a whole grating lobe (0.68 m) off at the right speed (issue 26, an outside synthesis).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray

from hil.estimation.base import Estimate
from hil.estimation.echo_fits import Coherence
from hil.estimation.gcas.hidden_echoes import HIDDEN_FRACTION
from hil.estimation.refine import CoherentRefiner, EchoTest, Refinement
from sim_devices.acoustics.delay import TwoWayPath
from sim_devices.acoustics.echo import AnalyticEcho
from sim_devices.acoustics.trajectory import Fixed

from .conftest import FS, C, att_schedule, count_hits, echo_samples, make_gcas, run_blocks

SECONDS = 1.5
HOP_S = 0.01
WALL_M = 30.0
#: The scored boundaries: received from the first full window on, to two hops before the end.
SCORED_S = (0.15, SECONDS - 2 * HOP_S)


def _wall(level_db: float, range_m: float = WALL_M) -> np.ndarray:
    """The echo of a wall at rest at ``range_m`` (exact, ``level_db`` above a unit echo)."""
    sonar = Fixed((0.0, 0.0, 0.0))
    path = TwoWayPath.monostatic(sonar, Fixed((range_m, 0.0, 0.0)), C)
    echo = AnalyticEcho(att_schedule(), path, FS, amplitude=10 ** (level_db / 20.0))
    return echo.block(0, int(round(SECONDS * FS)))


def _wall_and_target(wall_db: float, snr_db: float, seed: int) -> list[Estimate]:
    schedule = att_schedule()
    x = _wall(wall_db) + echo_samples(schedule, 50.0, 8.0, SECONDS, snr_db=snr_db, seed=seed)
    return run_blocks(make_gcas(schedule), x)


def _expected() -> int:
    """The target's boundaries received in :data:`SCORED_S` (50 m closing 8 m/s)."""
    t_tx = HOP_S * np.arange(1, int(SECONDS / HOP_S) + 1)
    t_rx = t_tx + 2.0 * (50.0 - 8.0 * t_tx) / (C + 8.0)
    return int(np.count_nonzero((t_rx >= SCORED_S[0]) & (t_rx < SCORED_S[1])))


@pytest.mark.slow
@pytest.mark.parametrize(
    ("wall_db", "snr_db", "pd_min", "false_max"),
    # Issue 26's goal: pd >= 0.95, at most 0.05 false estimates per hop. Measured (seed 5,
    # 1.5 s): pd 1.000 and no false estimate at +13, +16 and +20 dB, 0 and -10 dB (+16 dB at
    # -10 dB before a still echo's new fit replaced its first one two lobes off: pd 0.94 on
    # an outside synthesis).
    [
        (13.0, 0.0, 0.95, 0.05),
        (13.0, -10.0, 0.95, 0.05),
        (16.0, -10.0, 0.95, 0.05),
        (20.0, 0.0, 0.95, 0.05),
        (20.0, -10.0, 0.95, 0.05),
    ],
)
def test_a_target_beside_a_wall_far_above_it_is_kept(
    wall_db: float, snr_db: float, pd_min: float, false_max: float
) -> None:
    est = [
        e for e in _wall_and_target(wall_db, snr_db, seed=5) if SCORED_S[0] <= e.t_s < SCORED_S[1]
    ]
    hits = count_hits(est, 50.0, 8.0)
    n_hops = (SCORED_S[1] - SCORED_S[0]) / HOP_S
    assert hits / _expected() >= pd_min
    assert (len(est) - hits) / n_hops <= false_max


def _wall_in_noise() -> tuple[NDArray[np.float64], CoherentRefiner, EchoTest]:
    """A wall alone at :data:`WALL_M`, 20 dB, in noise at 0 dB per-sample SNR of a unit echo
    (seed 3): the input, a refiner of att (M = 10) it was pushed into, and the hidden-echo
    test a still fit takes."""
    x = _wall(20.0) + np.random.default_rng(3).normal(0.0, 1.0 / np.sqrt(2.0), int(SECONDS * FS))
    refiner = CoherentRefiner(att_schedule(), FS, 10, C, 0.5, 30.0)
    refiner.push(x, 0)
    test = EchoTest(HIDDEN_FRACTION, HIDDEN_FRACTION, refiner.echo_test.min_e_over_n0_db)
    return x, refiner, test


def test_a_still_echo_is_measured_at_rest() -> None:
    # A wall alone, 20 dB, in noise at 0 dB per-sample SNR of a unit echo: fitted from a
    # boundary a quarter hop off (as the band's edge detection puts it) at time scale 1,
    # on its own grating lobe, with the wall's amplitude, and kept as one echo.
    _, refiner, test = _wall_in_noise()
    hop = 60
    t_true = (hop + 1) * HOP_S + 2.0 * WALL_M / C
    fit = refiner.refine_still(t_true + 0.25 * HOP_S, hop, test)
    assert fit is not None and fit.found and fit.is_echo(test)
    assert fit.alpha == 1.0
    assert abs(fit.t_s - t_true) < 2e-6  # within 1.5 mm of range; a grating lobe is 909 µs
    assert abs(fit.amplitude) == pytest.approx(10.0, rel=0.02)
    # Remembered as a still echo: taken out of a detection's fit 40 hops later.
    later = t_true + 40 * HOP_S
    assert [round(v, 9) for v, _ in refiner.known_echoes(later)] == [0.0]


@pytest.mark.parametrize("offset_s", [-6.0e-3, -5.0e-3, 0.5e-3, 5.0e-3, 6.0e-3])
def test_a_still_fit_started_between_two_grating_lobes_finds_the_echo(offset_s: float) -> None:
    # A wall 10 dB above a unit echo, 0 dB per-sample SNR, hop 10: from starts 0.5, 5 and
    # 6 ms off its boundary (0.55, 5.5 and 6.6 grating lobes of 909 us: between two lobes)
    # the search from rest stopped on the saddle and the still fit failed (found False,
    # coherence 0.10-0.45 of one echo's); started half a lobe either side, it is found.
    schedule = att_schedule()
    x = _wall(10.0) + np.random.default_rng(5).normal(0.0, 1.0 / np.sqrt(2.0), int(SECONDS * FS))
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(x, 0)
    hop = 10
    t_true = (hop + 1) * HOP_S + 2.0 * WALL_M / C
    test = EchoTest(HIDDEN_FRACTION, HIDDEN_FRACTION, refiner.echo_test.min_e_over_n0_db)
    fit = refiner.refine_still(t_true + offset_s, hop, test)
    assert fit is not None and fit.found and fit.is_echo(test)
    assert abs(fit.t_s - t_true) < 2e-6


def test_a_still_echo_s_new_fit_replaces_its_earlier_one_a_few_lobes_off() -> None:
    # The wall moves two grating lobes (1.36 m) at 0.75 s: each fit is at its own range, and
    # the later one replaces the earlier (a first fit that many lobes off, kept beside the
    # right one, was taken out of a target's fits as a second wall).
    schedule = att_schedule()
    lobe_m = 2 * C / (2.0 * 1100.0)
    cut = int(0.75 * FS)
    x = np.concatenate([_wall(20.0)[:cut], _wall(20.0, WALL_M + lobe_m)[cut:]])
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(x, 0)
    test = EchoTest(HIDDEN_FRACTION, HIDDEN_FRACTION, refiner.echo_test.min_e_over_n0_db)
    fits = []
    for hop, range_m in [(60, WALL_M), (90, WALL_M + lobe_m)]:
        t_true = (hop + 1) * HOP_S + 2.0 * range_m / C
        fit = refiner.refine_still(t_true, hop, test)
        assert fit is not None and fit.is_echo(test)
        assert abs(fit.t_s - t_true) < 2e-6
        fits.append(fit)
    assert refiner.known_echoes(fits[1].t_s + 2 * HOP_S) == [(0.0, abs(fits[1].amplitude))]


def test_no_still_fit_before_the_first_m_transmitted_hops() -> None:
    refiner = CoherentRefiner(att_schedule(), FS, 10, C, 0.5, 30.0)
    refiner.push(_wall(20.0), 0)
    test = EchoTest(HIDDEN_FRACTION, HIDDEN_FRACTION, refiner.echo_test.min_e_over_n0_db)
    assert refiner.refine_still(8 * HOP_S + 2.0 * WALL_M / C, 7, test) is None


def test_a_still_echo_s_ghosts_lie_a_whole_tone_spacing_from_rest() -> None:
    # att: one tone spacing is 27.5 m/s, a Doppler cell of one hop 2.5 m/s; a still echo's
    # ghosts' main lobes lie within two cells of whole spacings from rest (the beyond-span
    # check's rule).
    refiner = CoherentRefiner(att_schedule(), FS, 10, C, 0.5, 30.0)
    ghosts = [22.6, 27.5, 32.4, -25.0, -29.9, 55.0]
    away = [0.0, 2.0, -4.9, 8.0, -8.0, 20.0, -22.4, 32.6, 40.0]
    assert all(refiner.ghost_of_rest(v) for v in ghosts)
    assert not any(refiner.ghost_of_rest(v) for v in away)


def test_a_weak_fit_where_a_measured_still_echo_leaks_is_its_leak() -> None:
    # A wall measured at rest at hop 60 (20 dB, 0 dB per-sample SNR of a unit echo): a fit
    # within two Doppler cells of one of its ghosts (27.5 m/s) or of rest that collects less
    # than the follow gate (12 + 3 dB) is refused as what the wall's leak brought; one that
    # reaches the gate, one away from its leaks, and any before the wall is measured are not.
    x, refiner, test = _wall_in_noise()
    hop = 60
    t_wall = (hop + 1) * HOP_S + 2.0 * WALL_M / C
    wall = refiner.refine_still(t_wall, hop, test)
    assert wall is not None and wall.is_echo(test)
    assert refiner.follow_db == pytest.approx(15.0)

    def fit(speed: float, e_over_n0_db: float, hops_later: float = 10.3) -> Refinement:
        alpha = (C + speed) / (C - speed)
        return replace(
            wall, t_s=t_wall + hops_later * HOP_S, alpha=alpha, e_over_n0_db=e_over_n0_db
        )

    assert refiner.weak_in_still_leak(fit(-29.0, 13.0))
    assert refiner.weak_in_still_leak(fit(25.0, 14.9))
    assert refiner.weak_in_still_leak(fit(4.0, 12.5))
    assert not refiner.weak_in_still_leak(fit(27.0, 15.0))  # the follow gate reached
    assert not refiner.weak_in_still_leak(fit(12.0, 13.0))  # away from its leaks
    assert not refiner.weak_in_still_leak(fit(27.0, 13.0, hops_later=70.0))  # wall's fit let go

    # Above the gate but coherent over runs of hops only (0.75 of one echo over all hops,
    # 0.9 over runs): the echo test's run branch is for a drifting speed, not for a leak.
    def runs_only(speed: float) -> Refinement:
        return replace(
            fit(speed, 16.0), coherence=Coherence(0.75, 1.0), run_coherence=Coherence(0.9, 1.0)
        )

    assert runs_only(-26.0).is_echo(refiner.echo_test)
    assert refiner.weak_in_still_leak(runs_only(-26.0))
    assert refiner.weak_in_still_leak(runs_only(1.0))
    assert not refiner.weak_in_still_leak(runs_only(12.0))  # away from its leaks
    assert not refiner.weak_in_still_leak(replace(runs_only(-26.0), coherence=Coherence(0.8, 1.0)))
    fresh = CoherentRefiner(att_schedule(), FS, 10, C, 0.5, 30.0)
    fresh.push(x, 0)
    assert not fresh.weak_in_still_leak(fit(27.0, 13.0))  # no still echo measured


def _moving_expected(range_m: float, speed_mps: float) -> int:
    """A target's boundaries received in :data:`SCORED_S` (from ``range_m`` m closing at
    ``speed_mps`` m/s)."""
    t_tx = HOP_S * np.arange(1, int(SECONDS / HOP_S) + 1)
    t_rx = t_tx + 2.0 * (range_m - speed_mps * t_tx) / (C + speed_mps)
    return int(np.count_nonzero((t_rx >= SCORED_S[0]) & (t_rx < SCORED_S[1])))


@pytest.mark.slow
@pytest.mark.parametrize(
    ("wall_db", "speed_mps", "snr_db", "pd_min"),
    # Where the wall leaks: beside its ghost (27.5 m/s: 25, 27, -27 m/s) and beside rest
    # (4-5 m/s). Left in those detections, the wall hid the target (12 trials of 2 s each
    # at 0 and -10 dB, with and without reverberation: pd 0.01-0.03 at 25-27 m/s, 0.27 at
    # 5 m/s beside a wall 16 dB up, 0.86 at 4 m/s beside one 10 dB up). Measured (seed 5,
    # 1.5 s): pd 0.92, 1.00, 1.00, 0.955, 1.00, false 0.0075, 0, 0, 0, 0 per hop; pd 0.89,
    # 1.00, 0.89, 0.92, 1.00 while a still fit started between two grating lobes failed (the
    # wall's first fits). The boundaries missed are the first ones.
    [
        (10.0, 27.0, 0.0, 0.9),
        (10.0, -27.0, -10.0, 0.95),
        (16.0, 25.0, -10.0, 0.95),
        (16.0, 5.0, 0.0, 0.95),
        (10.0, 4.0, -10.0, 0.95),
    ],
)
def test_a_target_where_a_wall_above_it_leaks_is_kept(
    wall_db: float, speed_mps: float, snr_db: float, pd_min: float
) -> None:
    schedule = att_schedule()
    range_m = 90.0 if speed_mps > 20.0 else (35.0 if speed_mps < -20.0 else 50.0)
    x = _wall(wall_db) + echo_samples(schedule, range_m, speed_mps, SECONDS, snr_db=snr_db, seed=5)
    est = [e for e in run_blocks(make_gcas(schedule), x) if SCORED_S[0] <= e.t_s < SCORED_S[1]]
    hits = count_hits(est, range_m, speed_mps)
    n_hops = (SCORED_S[1] - SCORED_S[0]) / HOP_S
    assert hits / _moving_expected(range_m, speed_mps) >= pd_min
    assert (len(est) - hits) / n_hops <= 0.05  # issue 26's goal


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 4])
def test_a_lone_slow_echo_measured_at_rest_adds_few_ghosts(seed: int) -> None:
    # A lone echo at 40 m closing 0.05 m/s (0 dB, 2 s): inside the reverberation band,
    # nothing to report. Its fit at rest is taken out of every detection, its ghosts'
    # included, and what the fit leaves there (the echo turns 1 rad in 8 hops: a fit at
    # rest does not hold it) passes the echo test on 2 and 1 boundaries of these seeds (at
    # +24.7 and 9.2 m/s; -24.9 m/s): 0 where it was left in its leaks' detections, which hid every
    # target there: test_a_target_where_a_wall_above_it_leaks_is_kept). Issue 26's goal:
    # at most 0.05 false estimates per hop.
    schedule = att_schedule()
    x = echo_samples(schedule, 40.0, 0.05, 2.0, snr_db=0.0, seed=seed)
    est = run_blocks(make_gcas(schedule), x)
    assert len(est) / (2.0 / HOP_S) <= 0.015


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 4])
def test_a_lone_slow_echo_at_minus_10_db_gives_no_ghost_where_it_leaks(seed: int) -> None:
    # The same echo at -10 dB: the detections its leaks bring (near rest, at its ghosts one
    # tone spacing out) are fitted with its fit at rest taken out, and those fits read the
    # noise there; 5 and 4 passed the echo test (at +-24-30 m/s, 0.8-89 m) before a fit there
    # had to collect the follow gate (15 dB), none since.
    schedule = att_schedule()
    x = echo_samples(schedule, 40.0, 0.05, 2.0, snr_db=-10.0, seed=seed)
    est = run_blocks(make_gcas(schedule), x)
    assert len(est) / (2.0 / HOP_S) <= 0.005


@pytest.mark.slow
def test_braking_to_rest_in_reverberation_gives_no_ghost_coherent_over_runs_only() -> None:
    # The scenes sweep's `braking` at -10 dB in volume reverberation at 0 dB SRR, its first
    # trial (SeedSequence(2626, spawn_key=(19, 0))): 5 false estimates at -25.7 m/s, 26-67 m,
    # fits of 15.3-17.7 dB beside the target's fit at rest, coherent 0.73-0.80 of one echo
    # over all hops and 0.85-0.90 over runs, and the boundaries they were followed to, while
    # only the follow gate applied where a still echo leaks; none since coherence over all
    # hops is required there. Every boundary of the target kept.
    from hil.evaluation.trials_scene import scene_trial

    params = {"scene": "braking", "snr_db": -10.0, "srr_db": 0.0, "duration_s": 2.0}
    out = scene_trial(params, np.random.SeedSequence(2626, spawn_key=(19, 0)))
    assert out["detected"] == out["expected"] == [48]
    assert out["n_false"] == 0
