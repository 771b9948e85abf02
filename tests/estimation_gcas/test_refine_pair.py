"""Two echoes of one time scale in one detection's hops (hil.estimation.refine_pair): the
two-echo least squares, its fit of two echoes close in range, one echo kept as one."""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math

import numpy as np
import pytest

from hil.estimation import refine_pair
from hil.estimation.base import Estimate
from hil.estimation.refine import CoherentRefiner, Refinement

from .conftest import FS, C, att_schedule, block_edges, echo_samples, make_gcas, run_blocks

V = 10.0  # m/s, both echoes (closing)
SPAN = 0.5  # the receiver's refinement speed span, m/s
SECONDS = 0.3


@functools.cache
def _detection(r0: float) -> Estimate:
    """The receiver's 13th estimate of a lone noiseless echo at ``r0`` (m): a detection's
    boundary, time scale and hop."""
    return run_blocks(make_gcas(att_schedule()), echo_samples(att_schedule(), r0, V, SECONDS))[12]


def _refined(x: np.ndarray, t_s: float, alpha: float, hop: int) -> Refinement:
    refiner = CoherentRefiner(att_schedule(), FS, 10, C, SPAN, 30.0)
    refiner.push(x, 0)
    fit = refiner.refine(t_s, alpha, hop, pairs=True, new_pairs=True)
    assert fit is not None
    return fit


@pytest.mark.parametrize("gap_m", [0.3, 0.7, 1.0])
def test_two_noiseless_echoes_of_one_speed_are_both_measured_to_a_centimetre(gap_m: float) -> None:
    # Each echo alone gives its own boundary (the truth, noiseless); together at one
    # detection's boundary the one-echo fit is refused (0.3, 1.0 m: the tones' phases
    # disagree) or sits on one of them (0.7 m, a grating lobe: its hops are one echo's),
    # and the two-echo fit reads both. Measured: 0.04-0.49 mm off, speeds within 0.3 mm/s.
    first = _detection(50.0)
    schedule = att_schedule()
    near = echo_samples(schedule, 50.0, V, SECONDS)
    far = echo_samples(schedule, 50.0 + gap_m, V, SECONDS)
    shift = 2.0 * gap_m / (C + V)  # s, the farther echo's boundary later
    truth = [
        _refined(near, first.t_s, first.alpha, first.hop_index).t_s,
        _refined(far, first.t_s + shift, first.alpha, first.hop_index).t_s,
    ]
    assert truth[1] - truth[0] == pytest.approx(shift, abs=2e-6)
    # The one-echo fit of the two is where a detection of them would start: at the nearer.
    refiner = CoherentRefiner(schedule, FS, 10, C, SPAN, 30.0)
    refiner.push(near + far, 0)
    both = refiner.refine(first.t_s, first.alpha, first.hop_index, pairs=False)
    assert both is not None and both.second is None
    if gap_m != 0.7:
        assert not both.is_echo(refiner.echo_test)
        fit = refiner.refine(first.t_s, first.alpha, first.hop_index, pairs=True, new_pairs=True)
    else:
        # A grating lobe apart the one-echo fit passes: the pair is looked for where a
        # measured echo's next boundary is a resolution cell from it (the fit jumped).
        # (Its previous fit: the echo it is not on, a hop earlier.)
        assert both.is_echo(refiner.echo_test)
        kept = refiner._echoes[0]
        off = max(truth, key=lambda t: abs(t - both.t_s))
        earlier = off - schedule.hop_s / kept.alpha
        refiner._echoes = [dataclasses.replace(kept, hop_index=kept.hop_index - 1, t_s=earlier)]
        fit = refiner.refine(first.t_s, first.alpha, first.hop_index, pairs=True, new_pairs=True)
    assert fit is not None and fit.second is not None
    got = sorted([fit.t_s, fit.second.t_s])
    for t, want in zip(got, truth, strict=True):
        assert abs(t - want) * C / 2 < 0.01  # m
    for r in (fit, fit.second):
        assert r.speed_mps(C) == pytest.approx(V, abs=0.01)
        assert r.is_echo(refiner.echo_test)
    # Both remembered, as a pair: the next boundary starts from them.
    assert sorted(e.t_s for e in refiner._echoes if e.pair) == got


def test_one_echo_keeps_the_one_echo_model() -> None:
    # One echo in noise (0 dB per-sample SNR): its fit passes as one echo and no pair is
    # looked for; asked for two anyway, the second explains no more of the hops than chance
    # and the one-echo model is kept.
    first = _detection(50.0)
    x = echo_samples(att_schedule(), 50.0, V, SECONDS, snr_db=0.0, seed=3)
    refiner = CoherentRefiner(att_schedule(), FS, 10, C, SPAN, 30.0)
    refiner.push(x, 0)
    fit = refiner.refine(first.t_s, first.alpha, first.hop_index, pairs=True, new_pairs=True)
    assert fit is not None and fit.is_echo(refiner.echo_test) and fit.second is None
    word = refiner._codeword(first.hop_index)
    hops = np.arange(first.hop_index - 9, first.hop_index + 1, dtype=np.int64)
    lobe = 1.0 / (fit.alpha * refiner.spacing_hz)
    known = np.zeros((5, 0), dtype=np.complex128)
    pair = refine_pair.fit_pair(
        refiner, fit, word, hops, first.hop_index, lobe, known, refiner.echo_test
    )
    assert pair is None


def test_two_echoes_within_a_resolution_cell_are_reported_as_one() -> None:
    # 0.1 m apart (0.13 ms, below the main lobe 1/B = 0.30 ms): one estimate.
    first = _detection(50.0)
    schedule = att_schedule()
    x = echo_samples(schedule, 50.0, V, SECONDS, snr_db=10.0, seed=3)
    x = x + echo_samples(schedule, 50.1, V, SECONDS)
    fit = _refined(x, first.t_s, first.alpha, first.hop_index)
    assert fit.second is None


def test_the_pairs_least_squares_is_the_direct_regression() -> None:
    # Two complex models (random hops' worth of samples) and a real input: the energy the
    # pair explains, 2 c^H A^-1 c, is what least squares of Re(b1 s1 + b2 s2) on the input
    # explains (the conjugate terms average out over many cycles: within 1e-3).
    rng = np.random.default_rng(1)
    n = 20000
    t = np.arange(n) / FS
    s1 = np.exp(2j * np.pi * (3000.0 * t + rng.uniform()))
    s2 = np.exp(2j * np.pi * (3000.0 * (t - 2e-4) + rng.uniform())) * (t > 0.02)
    x = np.real((0.8 + 0.3j) * s1 + (0.5 - 0.6j) * s2) + rng.normal(0.0, 0.5, n)
    c = np.array([np.sum(x * np.conj(s1)), np.sum(x * np.conj(s2))])
    cross = complex(np.sum(s2 * np.conj(s1)))
    model = np.array([np.sum(np.abs(s1) ** 2), np.sum(np.abs(s2) ** 2)])
    design = np.stack([s1.real, -s1.imag, s2.real, -s2.imag], axis=1)
    coef, *_ = np.linalg.lstsq(design, x, rcond=None)
    direct = float(np.sum((design @ coef) ** 2))
    # pair_gain with no one-echo share, a unit scatter over M - 2 and two samples a hop is
    # the explained energy itself.
    got = refine_pair.pair_gain(c, cross, model, 0.0, 8.0, 2.0, 10)
    assert got == pytest.approx(direct, rel=1e-3)


def test_the_gain_limit_is_the_f_tail_at_the_pairs_chance() -> None:
    # (1 + g/(M - 2))^-(M - 2) = chance / cells at the limit.
    g = refine_pair.gain_limit(10, 18.0)
    assert (1 + g / 8) ** -8 == pytest.approx(refine_pair.PAIR_CHANCE / 18.0, rel=1e-12)
    assert math.isclose(refine_pair.gain_limit(10, 1.0, 1e-3), 8 * (1000 ** (1 / 8) - 1))


@functools.cache
def _close_pair_whole() -> tuple[np.ndarray, tuple[Estimate, ...], dict[str, int]]:
    """Two echoes 0.3 m apart at 10 m/s, 0 dB, 0.6 s, and the receiver's estimates and
    refusals over it in one block, computed once per process: both cuts compare against the
    same run (the array and the frozen estimates are read only, the counts copied)."""
    schedule = att_schedule()
    x = echo_samples(schedule, 50.0, V, 0.6, snr_db=0.0, seed=4)
    x = x + echo_samples(schedule, 50.3, V, 0.6)
    x.setflags(write=False)
    whole = make_gcas(schedule)
    want = whole.process(x) + whole.flush()
    return x, tuple(want), dict(whole.refusals())


@pytest.mark.parametrize("cut", [997, "random-5"])
def test_a_close_pair_chunks_equal_whole(cut: int | str) -> None:
    # Two echoes 0.3 m apart at 10 m/s, 0 dB, 0.6 s: the receiver's estimates (both echoes'
    # at each boundary) are the same whole and in blocks, bit for bit.
    schedule = att_schedule()
    x, cached, whole_refusals = _close_pair_whole()
    want = list(cached)
    rx = make_gcas(schedule)
    edges = block_edges(x.shape[0], cut)
    got: list[Estimate] = []
    for a, b in itertools.pairwise(edges):
        got += rx.process(x[a:b])
    got += rx.flush()
    assert got == want
    # Measured: 88 estimates, both echoes at each of 44 boundaries.
    assert sum(abs(e.speed_mps - V) < 0.5 for e in want) == 88
    assert rx.refusals() == whole_refusals


def test_interference_is_what_two_echoes_explain_together_over_alone() -> None:
    # Models that do not overlap: 1. Two equal echoes on models of correlation 0.9 (a
    # grating lobe apart), in phase 1.9, in opposite phase 0.1 (they cancel but for the
    # hops' edges): c = A b / 2 for the amplitudes b, A the Gram matrix.
    model = np.array([100.0, 100.0])
    for cross, b, want in (
        (0.0, (1.0, 1.0j), 1.0),
        (90.0, (1.0, 1.0), 1.9),
        (90.0, (1.0, -1.0), 0.1),
    ):
        a = np.array([[model[0], cross], [cross, model[1]]], dtype=np.complex128)
        c = 0.5 * a @ np.array(b, dtype=np.complex128)
        assert refine_pair.interference(c, complex(cross), model) == pytest.approx(want)
