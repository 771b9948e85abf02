"""GCAS's coherent refinement (hil.estimation.refine): the likelihood it maximises is the direct
correlation with the exact schedule, its errors sit on the Cramér–Rao bound for both HFC-CW
families, with no bias and no dependence on where the speed falls on the Doppler grid.

Statistics: consecutive estimates share M − 1 of their M hops, so their errors are strongly
correlated; the number of independent errors in a trial is about its estimates over M (a few
per trial). The RMSE of N independent errors has a relative standard error of about
1/sqrt(2N); with six 0.8 s trials (~24 independent errors) that is ~15 %, so an RMSE measured
at 1.0x the bound is asserted below 1.5x (over three standard errors of margin), and a bias
below a third of the bound is far inside the noise of the mean (σ/sqrt(24) ≈ 0.2 σ).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import hil.estimation.refine as refine_module
import hil.estimation.refine_accel as refine_accel
from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.estimation.gcas import GcasReceiver
from hil.estimation.refine import CoherentRefiner
from hil.evaluation.trials_ch6 import _crlb_fields, ch6_receiver_trial

from .conftest import (
    FS,
    C,
    att_schedule,
    design_speed_target,
    echo_samples,
    make_gcas,
    run_blocks,
    true_range,
)

R0, V0 = 70.0, 12.0  # the target of the table: 70 m, closing at 12 m/s


def _pooled(family: str, snr_db: float, trials: int, speed: float = V0) -> dict[str, float]:
    """RMSE and bias of every detected boundary over ``trials`` seeded ch6 trials (att, M = 10,
    the default receiver: GCAS with refinement), in units of the window's CRLB."""
    r_sse = r_sum = v_sse = v_sum = 0.0
    n = n_truth = false = 0
    for k in range(trials):
        out = ch6_receiver_trial(
            {"snr_db": snr_db, "family": family, "range_m": [R0, R0],
             "speed_mps": [speed, speed], "max_speed_mps": 30.0},
            np.random.SeedSequence(100 + k),
        )  # fmt: skip
        r_sse += out["range_sse_m2"]
        r_sum += out["range_err_sum_m"]
        v_sse += out["speed_sse"]
        v_sum += out["speed_err_sum"]
        n += out["n_detected"]
        n_truth += out["n_truth"]
        false += out["n_false"]
    bounds = _crlb_fields({"preset": "att", "family": family, "bandwidth_hz": 4400.0,
                           "code_seed": 1, "m_hops": 10}, snr_db, FS, C)  # fmt: skip
    return {
        "pd": n / n_truth,
        "false": false,
        "range_x": math.sqrt(r_sse / n) / bounds["crlb_range_m"],
        "speed_x": math.sqrt(v_sse / n) / bounds["crlb_speed_mps"],
        "range_bias_x": (r_sum / n) / bounds["crlb_range_m"],
        "speed_bias_x": (v_sum / n) / bounds["crlb_speed_mps"],
        "range_rmse_m": math.sqrt(r_sse / n),
        "speed_rmse_mps": math.sqrt(v_sse / n),
        "range_bias_m": r_sum / n,
        "speed_bias_mps": v_sum / n,
    }


def _check_at_the_bound(got: dict[str, float]) -> None:
    assert got["pd"] == 1.0 and got["false"] == 0
    assert got["range_x"] < 1.5 and got["speed_x"] < 1.5
    assert abs(got["range_bias_x"]) < 0.4 and abs(got["speed_bias_x"]) < 0.4


@pytest.mark.slow
@pytest.mark.parametrize(
    "family", ["random-cyclic", pytest.param("three-state", marks=pytest.mark.slow)]
)  # three-state: 1.4 CPU s, left to --all (its -10..+10 dB sweep is there too)
def test_at_the_bound_at_0_db(family: str) -> None:
    # Measured (6 trials): random-cyclic 0.95x range / 1.1x speed; three-state 1.5x / 1.1x
    # with two trials (its CRLB is the first window's, the code's windows differ).
    got = _pooled(family, 0.0, 6)
    _check_at_the_bound(got)
    # The goals in absolute terms: speed RMSE <= 0.01 m/s from 0 dB up, no bias.
    assert got["speed_rmse_mps"] < 0.01
    assert abs(got["range_bias_m"]) < 1e-3 and abs(got["speed_bias_mps"]) < 5e-3


@pytest.mark.slow
@pytest.mark.parametrize("family", ["random-cyclic", "three-state"])
@pytest.mark.parametrize("snr_db", [-10.0, 10.0])
def test_at_the_bound_from_minus_10_to_plus_10_db(family: str, snr_db: float) -> None:
    # Measured (random-cyclic, 4 trials): 0.91x / 1.02x the range bound at -10 / +10 dB.
    got = _pooled(family, snr_db, 6)
    _check_at_the_bound(got)
    if snr_db >= 0:
        assert got["speed_rmse_mps"] < 0.01
        assert abs(got["range_bias_m"]) < 1e-3 and abs(got["speed_bias_mps"]) < 5e-3


@pytest.mark.slow
def test_no_scalloping_between_doppler_hypotheses() -> None:
    # The detector's error grows midway between two of its Doppler hypotheses; the refined
    # estimate does not depend on the grid. Same noise seeds on and midway (common random
    # numbers), -10 dB per-sample SNR.
    grid = make_gcas(att_schedule()).grid.speeds_mps
    d = int(np.argmin(np.abs(grid - V0)))
    on, mid = float(grid[d]), float(0.5 * (grid[d] + grid[d + 1]))
    got_on = _pooled("random-cyclic", -10.0, 8, speed=on)
    got_mid = _pooled("random-cyclic", -10.0, 8, speed=mid)
    # Measured over 16 trials each: midway/on-grid 1.13 (range), 0.93 (speed), both within
    # 1.25x the bound; the detector alone: 1.35 and 2.3 (0.065 against 0.048 m). The ratio of
    # two RMSEs of ~30 independent errors each has a standard error of ~0.13: asserted
    # below 1.3, and each against the bound. With 48 seeds of independent errors each (docs/
    # results.md, "The refinement near its threshold, and scalloping") the ratio is
    # 0.92-1.01 at 1/4, 1/2 and 3/4 of a cell, both families, -10 and 0 dB.
    assert got_mid["range_rmse_m"] < 1.3 * got_on["range_rmse_m"]
    assert got_mid["speed_rmse_mps"] < 1.3 * got_on["speed_rmse_mps"]
    assert got_on["range_x"] < 1.5 and got_mid["range_x"] < 1.5


def _off_lobe(family: str, snr_db: float, seeds: range) -> tuple[int, int, float]:
    """Estimates (after 0.2 s), those more than 0.3 m off the truth (a grating lobe of att is
    0.66 m on random-cyclic, 0.51 m on three-state, at 25 m/s), and the RMSE of the others
    (m): 70 m closing at 25 m/s, 2 s, the default receiver."""
    schedule = att_schedule(family)
    errors = []
    for seed in seeds:
        x = echo_samples(schedule, 70.0, 25.0, 2.0, snr_db=snr_db, seed=seed)
        est = [e for e in run_blocks(make_gcas(schedule), x) if e.t_s > 0.2]
        errors += [e.range_m - true_range(70.0, 25.0, e.t_tx_s, e.t_s) for e in est]
    err = np.abs(np.array(errors))
    return err.size, int(np.sum(err > 0.3)), float(np.sqrt(np.mean(err[err <= 0.3] ** 2)))


@pytest.mark.slow
@pytest.mark.parametrize(
    ("family", "most_off", "rmse_max"),
    [
        ("random-cyclic", 10, 0.025),
        pytest.param("three-state", 18, 0.012, marks=pytest.mark.slow),
    ],
)
def test_below_the_lobe_threshold_the_lobe_is_decided_on_twice_the_hops(
    family: str, most_off: int, rmse_max: float
) -> None:
    # -20 dB per-sample SNR (E/N0 about 17 dB over M = 10 hops, below the lobe decision's
    # threshold region): the M hops alone put a fit on a neighbouring grating lobe, or on a
    # Doppler sidelobe of the range-Doppler ridge a lobe away, in runs of estimates. Decided
    # with the M hops before them, over the lobes of the detection and of the fit. Measured
    # (seeds 0-3, deterministic): random-cyclic 5 of 309 estimates off (the M hops alone:
    # 21 of 310), three-state 9 of 439 (53 of 445). Asserted at about twice the measured
    # counts, under half the M hops' alone. The others' RMSE: random-cyclic 0.021 m (0.030 m
    # the M hops alone: fits on the range-Doppler ridge within 0.3 m), three-state 0.009 m
    # (0.009 m).
    n, off, rmse = _off_lobe(family, -20.0, range(4))
    assert n >= 300
    assert off <= most_off
    assert rmse < rmse_max


def test_the_lobe_decisions_threshold_region_is_the_schedules() -> None:
    # E/N0 = LOBE_Z² / (1 − ρ), ρ = 1 − 1/(α Δf D) at the fastest time scale: att
    # random-cyclic (Δf 1100 Hz, D 10 ms) 20.4 dB, three-state (1466.7 Hz, 15 ms) 23.2 dB;
    # both about 6 dB below what an echo at -10 dB per-sample SNR collects (27, 28.8 dB).
    got = [
        CoherentRefiner(att_schedule(f), FS, 10, C, 0.5, 30.0).lobe_sure_db
        for f in ("random-cyclic", "three-state")
    ]
    assert got == pytest.approx([20.42, 23.43], abs=0.02)


def test_the_design_speed_next_to_the_masked_cells_reads_without_bias() -> None:
    # +25 m/s on att: the default reverberation band masks the ghost cells next to it; the
    # detector alone reads it on the tones its hypotheses share (0.33 m/s low on sums of
    # unequal tones), the refinement measures the echo itself.
    raw, est = design_speed_target()
    assert len(est) == len(raw) >= 60
    assert abs(np.mean([e.speed_mps for e in raw]) - 25.0) < 0.05
    dv = np.array([e.speed_mps - 25.0 for e in est])
    dr = np.array([e.range_m - true_range(60.0, 25.0, e.t_tx_s, e.t_s) for e in est])
    assert abs(dv.mean()) < 0.01 and np.sqrt(np.mean(dv**2)) < 0.01
    assert np.sqrt(np.mean(dr**2)) < 0.005


def test_the_likelihood_is_the_direct_correlation_with_the_schedule() -> None:
    # C(t_rx, α) from the moment tables against Σ_n x[n] s*(α (t_n − t_rx) + T_b) summed
    # directly over the M hops' receive windows (edge samples whole, hence the tolerance).
    schedule = att_schedule()
    x = echo_samples(schedule, R0, V0, 0.5, snr_db=-5.0, seed=3)
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(x, 0)
    est = next(e for e in run_blocks(make_gcas(schedule, refine=False), x) if e.t_s > 0.2)
    alpha0 = est.alpha
    cand_t = est.t_s + np.array([-2e-4, -3e-5, 0.0, 4e-5, 1.5e-4])
    cand_a = alpha0 + np.array([-3e-4, 2e-4, 0.0, -1e-4, 4e-4])
    got = refiner.correlation(est.t_s, alpha0, est.hop_index, cand_t, cand_a)
    assert got is not None
    hops = schedule.hops(est.hop_index - 9, 10)
    t_b = float(hops.start_s[-1] + hops.duration_s[-1])
    t_n = np.arange(x.size) / FS
    for c_got, t_rx, a in zip(got, cand_t, cand_a, strict=True):
        direct = 0j
        for i in range(10):
            lo = t_rx + (hops.start_s[i] - t_b) / a
            hi = t_rx + (hops.start_s[i] + hops.duration_s[i] - t_b) / a
            sel = (t_n >= lo) & (t_n < hi)
            phase = hops.phase_rad[i] + 2 * np.pi * hops.freq_hz[i] * (
                a * (t_n[sel] - t_rx) + t_b - hops.start_s[i]
            )
            direct += np.sum(x[sel] * np.exp(-1j * phase))
        assert abs(c_got - direct) < 2e-3 * abs(direct)


@pytest.mark.parametrize("accel", [-8.0, 3.0, 12.0])
def test_the_accelerating_likelihood_is_the_direct_correlation_along_the_curve(
    accel: float,
) -> None:
    # C(t_rx, α, γ) from the moment tables (each hop on the curve's tangent at its centre)
    # against Σ_n x[n] s*(s(t_n)) with the exact quadratic mapping s(t) − T_b = d_c +
    # α (τ − τ_c) + ½ γ (τ − τ_c)², τ = t − t_rx, τ_c = d_c/α, summed directly over the
    # samples each hop's transmit interval maps to.
    schedule = att_schedule()
    x = echo_samples(schedule, R0, V0, 0.5, snr_db=-5.0, seed=3)
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(x, 0)
    est = next(e for e in run_blocks(make_gcas(schedule, refine=False), x) if e.t_s > 0.2)
    gamma = 2.0 * accel / C
    cand_t = est.t_s + np.array([-3e-5, 0.0, 4e-5])
    cand_a = est.alpha + np.array([2e-4, 0.0, -1e-4])
    got = refiner.correlation(est.t_s, est.alpha, est.hop_index, cand_t, cand_a, np.full(3, gamma))
    assert got is not None
    hops = schedule.hops(est.hop_index - 9, 10)
    t_b = float(hops.start_s[-1] + hops.duration_s[-1])
    d_c = 0.5 * (hops.start_s[0] + hops.start_s[-1] + hops.duration_s[-1]) - t_b
    t_n = np.arange(x.size) / FS
    for c_got, t_rx, a in zip(got, cand_t, cand_a, strict=True):
        tau, tau_c = t_n - t_rx, d_c / a
        s_n = d_c + a * (tau - tau_c) + 0.5 * gamma * (tau - tau_c) ** 2  # from T_b
        direct = 0j
        for i in range(10):
            lo = hops.start_s[i] - t_b
            sel = (s_n >= lo) & (s_n < lo + hops.duration_s[i])
            phase = hops.phase_rad[i] + 2 * np.pi * hops.freq_hz[i] * (s_n[sel] - lo)
            direct += np.sum(x[sel] * np.exp(-1j * phase))
        assert abs(c_got - direct) < 3e-3 * abs(direct)


def test_rates_of_another_shape_are_refused() -> None:
    schedule = att_schedule()
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(echo_samples(schedule, R0, V0, 0.3, snr_db=0.0, seed=1), 0)
    with pytest.raises(ConfigError, match="rates"):
        refiner.correlation(0.25, 1.016, 20, np.zeros(3), np.ones(3), np.zeros(2))


@given(
    t_b=st.floats(0.1, 10.0),
    alpha_b=st.floats(0.96, 1.04),
    accel=st.floats(-20.0, 20.0),
    d_c=st.floats(-0.15, -0.02),  # M = 4 to 30 hops of 10 ms
)
def test_the_curves_centre_and_boundary_are_one_curve(
    t_b: float, alpha_b: float, accel: float, d_c: float
) -> None:
    # The search's start at the hops' centre maps back onto the boundary it came from, and
    # the known echo's hop lines (boundary-anchored) meet the same curve: the centre hop's
    # line through (t_c + τ_c, T_b + d_c) has the centre's time scale.
    gamma = 2.0 * accel / C
    t_c, alpha_c = refine_accel.to_centre(t_b, alpha_b, gamma, d_c)
    t_back, a_back = refine_accel.to_boundary(t_c, alpha_c, gamma, d_c)
    assert abs(t_back - t_b) < 1e-12 and abs(a_back - alpha_b) < 1e-9
    t_i, a_i = refine_accel.hops_on_curve(t_b, alpha_b, gamma, np.array([d_c]))
    # Each side takes one Newton step from its own anchor (error O(γ² u³)): within 5 ns, a
    # thousandth of a radian of a 30 kHz tone.
    assert abs(a_i[0] - alpha_c) < 1e-8
    assert abs(t_i[0] + d_c / a_i[0] - (t_c + d_c / alpha_c)) < 5e-9


def test_chunks_equal_whole() -> None:
    schedule = att_schedule()
    x = echo_samples(schedule, 50.0, -9.0, 0.6, snr_db=-5.0, seed=9)
    whole = run_blocks(make_gcas(schedule), x, x.size)
    chunks = run_blocks(make_gcas(schedule), x, 3_917)
    assert len(whole) >= 40 and repr(whole) == repr(chunks)
    assert all(math.isfinite(e.crlb_range_m) and e.crlb_range_m > 0 for e in whole)


def test_every_estimate_carries_its_own_bound() -> None:
    # The bound follows the echo's own E/N0: 10 dB more SNR, sqrt(10) smaller bounds.
    schedule = att_schedule()
    lo = run_blocks(make_gcas(schedule), echo_samples(schedule, R0, V0, 0.6, snr_db=-5.0, seed=2))
    hi = run_blocks(make_gcas(schedule), echo_samples(schedule, R0, V0, 0.6, snr_db=5.0, seed=2))
    ratio = np.median([e.crlb_range_m for e in lo]) / np.median([e.crlb_range_m for e in hi])
    assert 2.8 < ratio < 3.5
    speed = np.median([e.crlb_speed_mps for e in hi])
    assert 0.0 < speed < 0.002


def test_refinement_off_keeps_the_detectors_readout() -> None:
    schedule = att_schedule()
    x = echo_samples(schedule, R0, V0, 0.5, snr_db=0.0, seed=4)
    off = run_blocks(make_gcas(schedule, refine=False), x)
    on = run_blocks(make_gcas(schedule), x)
    assert [e.hop_index for e in off] == [e.hop_index for e in on]
    assert all(math.isnan(e.crlb_range_m) for e in off)
    err = [abs(e.range_m - true_range(R0, V0, e.t_tx_s, e.t_s)) for e in (off, on)[1]]
    err_off = [abs(e.range_m - true_range(R0, V0, e.t_tx_s, e.t_s)) for e in off]
    assert np.sqrt(np.mean(np.square(err))) < 0.3 * np.sqrt(np.mean(np.square(err_off)))


def test_after_a_gap_every_estimate_is_refined_on_samples_after_it() -> None:
    schedule = att_schedule()
    x = echo_samples(schedule, R0, V0, 0.8, snr_db=0.0, seed=5)
    rx = make_gcas(schedule)
    cut, gap = 30_000, 700
    out: list[Estimate] = rx.process(x[:cut]) + rx.process(x[cut + gap :], gap_before=gap)
    out += rx.flush()
    after = [e for e in out if e.t_s > (cut + gap) / FS]
    assert len(after) >= 30 and all(math.isfinite(e.crlb_range_m) for e in after)
    err = [e.range_m - true_range(R0, V0, e.t_tx_s, e.t_s) for e in after]
    assert np.sqrt(np.mean(np.square(err))) < 0.005
    # The refiner itself: a detection whose hops reach back before the gap is not refined.
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.reset(cut + gap)
    refiner.push(x[cut + gap :], cut + gap)
    first = after[0]
    assert refiner.refine(first.t_s, first.alpha, first.hop_index) is not None
    assert refiner.refine(first.t_s - 0.05, first.alpha, first.hop_index - 5) is None


@functools.cache
def _target_and_its_13th_estimate() -> tuple[np.ndarray, Estimate]:
    """The target (R0 closing at V0, 0 dB, seed 6) over 0.6 s and the default receiver's 13th
    estimate of it, made once per process for the tests below that start from it; the input
    is read only (a test that changes it changes a copy)."""
    schedule = att_schedule()
    x = echo_samples(schedule, R0, V0, 0.6, snr_db=0.0, seed=6)
    x.flags.writeable = False
    return x, run_blocks(make_gcas(schedule), x)[12]


def _beside_an_echo_whose_ghost_it_may_be(
    scale: float, ghost_strength: float = 0.0
) -> tuple[CoherentRefiner, Estimate]:
    """A refiner that has measured one echo one tone spacing's speed beyond a target, where
    its comb would put the target's detection (returned, the 13th) as its ghost, at
    ``scale`` times the target's fitted amplitude, its ghosts read so far at a detector
    statistic of ``ghost_strength``."""
    schedule = att_schedule()
    x, first = _target_and_its_13th_estimate()
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(x, 0)
    fit = refiner.refine(first.t_s, first.alpha, first.hop_index)
    assert fit is not None and fit.is_echo(refiner.echo_test)
    refiner.reset(0)
    refiner.push(x, 0)
    v_ghost = V0 - refiner._ghost_speed
    a_ghost = (C + v_ghost) / (C - v_ghost)
    drift = 0.5 * (10 - 1) * (a_ghost / first.alpha - 1.0)  # hops
    t_ghost = first.t_s - drift * refiner.hop_len_s / a_ghost
    refiner._echoes = [
        refine_module.EchoFit(
            first.hop_index, t_ghost, a_ghost, scale * fit.amplitude,
            ghost_strength=(ghost_strength,) * schedule.period_hops,
        )
    ]  # fmt: skip
    return refiner, first


@pytest.mark.parametrize(("scale", "ghost"), [(0.2, False), (1.25, False), (5.0, True)])
def test_a_detection_is_the_ghost_of_a_measured_echo_only_where_it_is_much_weaker(
    scale: float, ghost: bool
) -> None:
    # Read with the measured echo taken out, the detection keeps its own level: five times
    # the target's amplitude, that is a fifth of the echo (below GHOST_LEFT), given up as its
    # ghost; 1.25 times, 0.8 of it, a second echo there, fitted; a fifth of it, the measured
    # echo is the ghost (a weak ghost fit that passed the echo test first) and the detection
    # is kept.
    refiner, first = _beside_an_echo_whose_ghost_it_may_be(scale)
    assert refiner.ghost_of_known(first.t_s, first.alpha, first.hop_index, strength=4.0) is ghost
    # Read as its ghost, the detector statistic is kept on its codeword: later detections
    # there up to GHOST_STRENGTH_MARGIN times it are refused unread, stronger ones are read
    # again.
    read = refiner._echoes[0].ghost_strength
    assert sorted(read) == [0.0] * (len(read) - 1) + [4.0 if ghost else 0.0]


def test_a_ghost_read_once_refuses_the_next_as_weak_unread_and_reads_a_stronger_one() -> None:
    # The echo's ghosts read so far reached a statistic of 4; the detection itself reads 0.8
    # of the echo (a second echo there): at 5.9 (within 1.5 times 4) it is refused unread,
    # at 6.1 it is read, and kept.
    refiner, first = _beside_an_echo_whose_ghost_it_may_be(1.25, ghost_strength=4.0)
    assert refiner.ghost_of_known(first.t_s, first.alpha, first.hop_index, strength=5.9)
    assert not refiner.ghost_of_known(first.t_s, first.alpha, first.hop_index, strength=6.1)
    # Without a statistic (a caller that has none) it is always read.
    assert not refiner.ghost_of_known(first.t_s, first.alpha, first.hop_index)


def test_a_ghost_read_on_another_codeword_does_not_refuse_a_detection_unread() -> None:
    # A ghost's codeword recurs; a second echo at the ghost's speed arrives on codewords of
    # its own. Ghosts read at a statistic of 4 on every other hop offset from the echo's: the
    # detection (0.8 of the echo, a second echo) at 3.0 is read, and kept.
    refiner, first = _beside_an_echo_whose_ghost_it_may_be(1.25)
    echo = refiner._echoes[0]
    period = refiner.hop_len_s / echo.alpha
    own = (first.hop_index - echo.hop_index - round((first.t_s - echo.t_s) / period)) % len(
        echo.ghost_strength
    )
    others = tuple(0.0 if i == own else 4.0 for i in range(len(echo.ghost_strength)))
    refiner._echoes = [dataclasses.replace(echo, ghost_strength=others)]
    assert not refiner.ghost_of_known(first.t_s, first.alpha, first.hop_index, strength=3.0)
    # On its own codeword the same statistic is refused unread.
    refiner._echoes = [dataclasses.replace(echo, ghost_strength=(4.0,) * len(others))]
    assert refiner.ghost_of_known(first.t_s, first.alpha, first.hop_index, strength=3.0)


def test_an_echo_measured_at_a_ghosts_speed_is_followed_through_the_ghosts_hops() -> None:
    # The target's own fit one hop earlier is kept: its next boundary, where the measured
    # echo's ghost peaks and weaker than its ghosts read so far, is that echo's, not a ghost.
    refiner, first = _beside_an_echo_whose_ghost_it_may_be(5.0, ghost_strength=4.0)
    earlier = first.t_s - refiner.hop_len_s / first.alpha
    own = refine_module.EchoFit(first.hop_index - 1, earlier, first.alpha, 1.0)
    assert refiner.ghost_of_known(first.t_s, first.alpha, first.hop_index, strength=3.0)
    refiner._echoes = [*refiner._echoes, own]
    assert not refiner.ghost_of_known(first.t_s, first.alpha, first.hop_index, strength=3.0)


def test_an_echo_measured_lately_is_due_at_its_next_boundary_once() -> None:
    # A target fitted at one boundary: its next boundary is due once the stream has passed
    # it, once, and never beyond KNOWN_HOPS hops of the fit; an echo none of whose fits
    # reached the follow gate (FOLLOW_MARGIN_DB over the echo test's E/N0: 15 dB on GCAS) or
    # at rest is not followed, one whose earlier fit reached it is (held) whatever its latest.
    refiner, first = _beside_an_echo_whose_ghost_it_may_be(1.0)
    refiner._echoes = []
    fit = refiner.refine(first.t_s, first.alpha, first.hop_index)
    assert fit is not None and fit.is_echo(refiner.echo_test)
    period = refiner.hop_len_s / fit.alpha
    assert refiner.due(fit.t_s + 0.5 * period) == []
    [(hop, t_next, alpha, latest_db)] = refiner.due(fit.t_s + 1.5 * period)
    assert latest_db == fit.e_over_n0_db
    assert hop == first.hop_index + 1 and alpha == fit.alpha
    assert t_next == pytest.approx(fit.t_s + period, abs=1e-12)
    assert refiner.due(fit.t_s + 1.5 * period) == []
    assert [d[0] for d in refiner.due(fit.t_s + 10 * period)] == [first.hop_index + 2]
    assert [d[0] for d in refiner.due(fit.t_s + 10 * period)] == [first.hop_index + 3]
    assert refiner.due(fit.t_s + 10 * period) == []
    assert refiner.m_hops >= refine_module.FOLLOW_MIN_HOPS
    assert refiner.follow_db == 15.0 < refiner.lobe_sure_db
    echo = refiner._echoes[0]
    assert echo.held
    for other in (
        dataclasses.replace(echo, followed=-1, e_over_n0_db=refiner.follow_db - 0.1, held=False),
        dataclasses.replace(echo, followed=-1, alpha=1.0),
    ):
        refiner._echoes = [other]
        assert refiner.due(fit.t_s + 10 * period) == []
    refiner._echoes = [dataclasses.replace(echo, followed=-1, e_over_n0_db=12.5)]
    assert [d[0] for d in refiner.due(fit.t_s + 10 * period)] == [first.hop_index + 1]


def test_an_echo_held_once_stays_held_through_weaker_fits() -> None:
    # A fit of 15 dB or more holds its echo (EchoFit.held); the echo's next fits replace it
    # and carry that on however weak, while an echo first fitted below the gate is not held.
    refiner, first = _beside_an_echo_whose_ghost_it_may_be(1.0)
    refiner._echoes = []
    fit = refiner.refine(first.t_s, first.alpha, first.hop_index)
    assert fit is not None and fit.e_over_n0_db >= refiner.follow_db
    period = refiner.hop_len_s / fit.alpha
    [echo] = refiner._echoes
    assert echo.held
    weak = dataclasses.replace(fit, t_s=fit.t_s + period, e_over_n0_db=13.0)
    refiner._remember(weak, first.hop_index + 1, None)
    [echo] = refiner._echoes
    assert echo.held and echo.e_over_n0_db == 13.0 and echo.hop_index == first.hop_index + 1
    refiner._echoes = []
    refiner._remember(weak, first.hop_index + 1, None)
    [echo] = refiner._echoes
    assert not echo.held
    # The same through a pair's fits (_remember_all, refine_pair): each carries its own
    # echo's hold, and a new echo of the pair is held only from 15 dB.
    refiner._echoes = []
    refiner.refine(first.t_s, first.alpha, first.hop_index)
    other = dataclasses.replace(weak, t_s=weak.t_s + 0.01)
    refiner._remember_all([weak, other], first.hop_index + 1, True, True)
    held = {round(e.t_s, 6): e.held for e in refiner._echoes}
    assert held == {round(weak.t_s, 6): True, round(other.t_s, 6): False}
    assert [d[0] for d in refiner.due(weak.t_s + 1.5 * period)] == [first.hop_index + 2]


def test_an_echo_that_ended_is_not_followed_on_its_earlier_hops() -> None:
    # The echo stops half a hop after a boundary it was measured at: the next boundary's
    # window still holds it on its first M - 1 hops, and fitted there it is one echo; followed
    # (no detection brought it) it is measured only where the window's last hop holds it.
    schedule = att_schedule()
    measured, first = _target_and_its_13th_estimate()
    x = measured.copy()
    noise = np.random.default_rng(7).normal(0.0, np.sqrt(0.5), x.shape)
    end = int((first.t_s + 0.5 * schedule.hop_s) * FS)
    x[end:] = noise[end:]
    t_next = first.t_s + schedule.hop_s / first.alpha
    for followed, measured in ((False, True), (True, False)):
        refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
        refiner.push(x, 0)
        fit = refiner.refine(t_next, first.alpha, first.hop_index + 1, followed=followed)
        assert (fit is not None and fit.is_echo(refiner.echo_test)) is measured


def test_a_followed_boundary_is_measured_on_its_own_lobe_only() -> None:
    # Followed from a point a grating lobe off the echo's next boundary, the fit moves onto
    # the echo's lobe, further than the main lobe 1/B: not that echo's continuation, and
    # not remembered; from the boundary itself it is measured.
    schedule = att_schedule()
    x, first = _target_and_its_13th_estimate()
    t_next = first.t_s + schedule.hop_s / first.alpha
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(x, 0)
    lobe = 1.0 / (first.alpha * refiner.spacing_hz)
    free = refiner.refine(t_next + lobe, first.alpha, first.hop_index + 1)
    assert free is not None and abs(free.t_s - (t_next + lobe)) > refiner.main_lobe_s
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(x, 0)
    off = refiner.refine(t_next + lobe, first.alpha, first.hop_index + 1, followed=True)
    assert off is None and refiner._echoes == []
    on = refiner.refine(t_next, first.alpha, first.hop_index + 1, followed=True)
    assert on is not None and on.is_echo(refiner.echo_test)


def test_refine_must_be_a_bool() -> None:
    with pytest.raises(ConfigError, match=r"refine = 'yes' is not allowed: must be true or false"):
        GcasReceiver(
            att_schedule(), FS, sound_speed_mps=C, max_speed_mps=30.0, max_range_m=100.0,
            m_hops=10, refine="yes",  # type: ignore[arg-type]
        )  # fmt: skip


def test_the_refiner_refuses_a_speed_span_that_is_not_a_speed() -> None:
    msg = r"speed_span_mps = nan is not allowed: must be a finite speed > 0 m/s"
    with pytest.raises(ConfigError, match=msg):
        CoherentRefiner(att_schedule(), FS, 10, C, float("nan"), 30.0)


def test_candidates_of_two_shapes_are_refused() -> None:
    schedule = att_schedule()
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(echo_samples(schedule, R0, V0, 0.3, snr_db=0.0, seed=1), 0)
    with pytest.raises(ConfigError, match="alphas"):
        refiner.correlation(0.25, 1.016, 20, np.zeros(3), np.ones(2))


@pytest.mark.slow
@pytest.mark.parametrize("snr_db", [-10.0, 0.0])
def test_a_long_window_searched_through_fewer_hops_finds_the_full_searchs_maxima(
    snr_db: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    # M = 29: a detection without a warm start searches the last SUB_HOPS hops, then all M
    # hops narrowly around that maximum. The full search over all M hops (SUB_HOPS >= M)
    # must find the same echoes at the same maxima: the same hops, ranges within 1 mm and
    # speeds within 5 mm/s (a quadratic fit started from another grid point).
    import hil.estimation.refine as refine

    schedule = att_schedule()
    x = echo_samples(schedule, R0, V0, 0.8, snr_db=snr_db, seed=11)
    fewer = run_blocks(make_gcas(schedule, m_hops=29), x)
    monkeypatch.setattr(refine, "SUB_HOPS", 1000)
    full = run_blocks(make_gcas(schedule, m_hops=29), x)
    assert len(fewer) >= 40
    assert [e.hop_index for e in fewer] == [e.hop_index for e in full]
    assert max(abs(a.range_m - b.range_m) for a, b in zip(fewer, full, strict=True)) < 1e-3
    assert max(abs(a.speed_mps - b.speed_mps) for a, b in zip(fewer, full, strict=True)) < 5e-3
    err = [e.range_m - true_range(R0, V0, e.t_tx_s, e.t_s) for e in fewer]
    assert np.sqrt(np.mean(np.square(err))) < (0.02 if snr_db < 0 else 0.005)


def test_a_window_older_than_the_history_is_refused_not_read_wrapped() -> None:
    # A detection reaches the refiner up to the search's decision lag after its samples were
    # pushed; allow_lag keeps that much more history. Past it, the hops' windows are refused.
    schedule, block = att_schedule(), 1000
    x = echo_samples(schedule, R0, V0, 2.0, snr_db=-5.0, seed=3)
    est = next(e for e in run_blocks(make_gcas(schedule, refine=False), x) if e.t_s > 0.2)
    args = (est.t_s, est.alpha, est.hop_index, np.array([est.t_s]), np.array([est.alpha]))
    stop = int((est.t_s + 0.01) * FS)

    def pushed(samples: int, lag: int = 0) -> CoherentRefiner:
        refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
        if lag:
            refiner.allow_lag(lag)
        for i in range(0, samples, block):
            refiner.push(x[i : min(i + block, samples)], i)
        return refiner

    want = pushed(stop).correlation(*args)
    assert want is not None
    late = pushed(x.size)
    # A ring holds at most 4 histories and a block: the boundary's hops have left it.
    assert x.size - 4 * late.history - block > int(est.t_s * FS)
    assert late.correlation(*args) is None
    kept = pushed(x.size, lag=x.size - stop)
    assert kept.history == late.history + x.size - stop
    got = kept.correlation(*args)
    assert got is not None and np.array_equal(got, want)


def test_a_negative_decision_lag_is_refused_with_its_field() -> None:
    refiner = CoherentRefiner(att_schedule(), FS, 10, C, 0.5, 30.0)
    with pytest.raises(ConfigError, match=r"samples = -1 .*>= 0 \(input samples of decision lag\)"):
        refiner.allow_lag(-1)


def test_an_echo_that_begins_within_the_window_is_not_fitted_as_accelerating() -> None:
    # An echo that begins within a detection's window (its first hops hold noise) loses
    # coherence as an accelerating one does, but it is one-sided (refine.PARTIAL_LEVEL): the
    # accelerating fit is not tried. The same detections on the whole echo are not one-sided.
    schedule = att_schedule()
    clean = echo_samples(schedule, R0, V0, 0.7)
    noise = np.random.default_rng(4).normal(0.0, np.sqrt(0.5), clean.shape)  # 0 dB
    t_cut = 0.45
    cut = clean.copy()
    cut[: int(t_cut * FS)] = 0.0
    whole = run_blocks(make_gcas(schedule, refine=False), clean + noise)
    span = 10 * schedule.hop_s
    # Windows with 3 to 7 of their 10 hops before the echo begins.
    straddling = [e for e in whole if 0.3 * span <= t_cut - (e.t_s - span) <= 0.7 * span]
    assert len(straddling) >= 3
    for x, one_sided in ((cut + noise, True), (clean + noise, False)):
        refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
        refiner.push(x, 0)
        for e in straddling:
            fit = refiner.refine(e.t_s, e.alpha, e.hop_index)
            assert fit is not None and fit.found and fit.accel_mps2 == 0.0
            word = refiner._codeword(e.hop_index)
            hop_ids = np.arange(e.hop_index - 9, e.hop_index + 1, dtype=np.int64)
            known = refine_module._NO_KNOWN
            assert refiner._one_sided(fit, word, hop_ids, known) is one_sided


@pytest.mark.parametrize(
    ("m_hops", "gate"), [(5, "lobe"), (7, "lobe"), (8, "margin"), (29, "margin")]
)
def test_short_windows_follow_only_from_the_lobe_decisions_threshold_region(
    m_hops: int, gate: str
) -> None:
    # Over fewer than FOLLOW_MIN_HOPS hops a speed sidelobe's or a ghost's fit collects what
    # the echo's own fits do: an echo is followed from the lobe decision's 20.4 dB there, from
    # 3 dB over the echo test's 12 dB from M = 8.
    refiner = CoherentRefiner(att_schedule(), FS, m_hops, C, 0.5, 30.0)
    assert refiner.lobe_sure_db == pytest.approx(20.42, abs=0.01)
    want = refiner.lobe_sure_db if gate == "lobe" else 12.0 + refine_module.FOLLOW_MARGIN_DB
    assert refiner.follow_db == want
