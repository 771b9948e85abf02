"""The accelerating fit of :class:`~hil.estimation.refine.CoherentRefiner`: one echo whose
time scale changes at a rate ``γ`` (1/s) over a detection's ``M`` hops.

Over the ``M`` hops an echo whose speed changes drifts in phase against one time scale (a
quadratic phase, ``π f γ u²`` at ``u`` from the window's centre, 2.5 rad at the ends for 8 m/s²
on ``att`` at M = 10), and the constant-speed fit reads the mean speed of the window, half a
window before the boundary. Where a fit's coherence shows that drift (:data:`ACCEL_TRY`), the
time scale is let change at a rate ``γ`` (1/s) about the hops' centre
(:func:`~hil.estimation.refine_kernels.candidate_sums`: each hop heard on the curve's tangent at
its own centre), fitted from a grid of rates and kept where the likelihood rises by
:data:`ACCEL_GAIN` (a generalised likelihood ratio test of one more parameter): the estimate is
then the boundary's own time and speed, with the acceleration (:attr:`Refinement. accel_mps2`),
and the next detections of that echo start from the curve. Over more than
:data:`~hil.estimation.refine.SUB_HOPS` hops the rates' curves pass through a constant-speed fit
of the last of them (the curvature grows as ``M²``: at M = 29 and 4 m/s² it is 10 rad at the
ends, and the fit of all M hops at one speed is nowhere near the echo). Below about 1.5 m/s² at
M = 10 on ``att`` (about 6 m/s² at M = 5) the drift stays within the coherence of one echo and
the speed lags by ``a M T_h / 2`` (at most 0.075 m/s). Above about 12 m/s² at M = 10 the
constant-speed fit is no point of the curve (its runs of hops lose their coherence too) and the
rate grid about it does not reach the echo's rate: there the acceleration the detections
themselves show (:func:`speed_trend`, :data:`ACCEL_SEED_HOPS`) seeds the curved fit, and once
one fit is curved the next detections start from it. On ``att`` at M = 10, 0 dB, a target from 2
m/s closing keeps 0.955 of its boundaries at 35 m/s² and 0.88 at 40 (the detector spreads it
over 16 Doppler cells of the window, and the seed, clipped at :data:`ACCEL_SEED_MAX_MPS2`,
scatters more); about 3 g is the limit.

The fit reads its refiner through :class:`AccelFitHost` (the members it uses, by their public
names), as the two-echo fit does (:class:`~hil.estimation.refine_pair.PairFitHost`).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from hil.estimation.codewords import Codeword
from hil.estimation.detection import parabolic_offset
from hil.estimation.echo_fits import EchoTest, Refinement
from hil.estimation.fit_steps import (
    FIT_PASSES,
    SPEED_POINTS,
    TIME_POINTS,
    echo_quality,
    maximise_recentred,
)
from hil.estimation.refine_kernels import FOUND

#: Accelerating echoes (:func:`with_acceleration`): a fit whose coherence
#: over all hops is below ACCEL_TRY of one echo's at its SNR while over runs of consecutive
#: hops it keeps ACCEL_RUN_MIN of it (an echo whose phase drifts slowly: measured 0.85-0.87
#: at 8 m/s² and 0.55-0.72 at 12 m/s² on att, M = 10; of 830 tries over nine scenes of an
#: independent synthesiser, braking at 5-15 m/s², reversing, still and moving echoes, at 0
#: and -10 dB, the 73 whose curved fit passed the echo test kept 0.71-0.97 before it, while
#: the ghosts of a still echo at 40 m, fitted at 0 dB, keep 0.50-0.85, median 0.55: tried
#: from 0.5, no try below 0.71 passed, and beside a target at 70 m closing at 12 m/s the
#: tries took 0.98 s of the receiver's 2.6 s of CPU for 2 s of input; over more than
#: SUB_HOPS hops the curvature at the window's ends grows as ``M²`` and a braking echo's
#: runs keep less, so there the tries start from ACCEL_RUN_MIN_LONG: at M = 29 and 4 m/s²
#: 40 of 71 boundaries are kept from 0.5, 13 from 0.65), and that collects ACCEL_MARGIN_DB more
#: than an echo must (fits of noise collect 12-16 dB and, given a third parameter, fit it;
#: an echo's curvature needs that margin for its gain to pass ACCEL_GAIN), is fitted again
#: with a changing time scale: accelerations up to MAX_ACCEL_MPS2 (m/s²) on a grid that moves
#: the phase at the window's ends by an eighth of a cycle a step (at most ACCEL_POINTS
#: points: longer windows cover less), then from the ACCEL_STARTS best of its local maxima
#: ACCEL_ROUNDS rounds of the delay–speed fit and a parabola in the rate. The acceleration is
#: kept where it raises the likelihood ``ln Λ = |C|²/(σ² E_s)`` by more than ACCEL_GAIN
#: (twice that gain is χ² with one degree of freedom for an echo of constant speed: 13.8 is
#: a chance of 2e-4).
ACCEL_TRY = 0.98
ACCEL_RUN_MIN = 0.65
ACCEL_RUN_MIN_LONG = 0.5
ACCEL_MARGIN_DB = 6.0
MAX_ACCEL_MPS2 = 20.0
ACCEL_POINTS = 41
ACCEL_ROUNDS = 2
ACCEL_STARTS = 3
ACCEL_GAIN = 6.9
#: Faster accelerations (the rate grid about a constant-speed fit finds none: at 15 m/s² on
#: att, M = 10, the quadratic phase is 4.7 rad at the window's ends, the constant-speed fit's
#: delay and speed are no point of the curve and its run coherence falls to 0.4-0.6): the
#: acceleration the detections themselves show seeds the fit. The detections of the last
#: ACCEL_SEED_HOPS hops on this echo's track (delay within ACCEL_SEED_LOBES grating lobes of
#: this one moved on at its speed; speed within what ACCEL_SEED_MAX_MPS2 reaches plus the
#: speed span) give the speed's least-squares slope (m/s²) and its standard error when there
#: are at least ACCEL_SEED_POINTS of them; where the slope is at least ACCEL_SEED_MIN_MPS2
#: (below, the rate grid about the constant-speed fit finds the echo: 12 m/s² is), the
#: curved fit is tried from a run coherence of ACCEL_RUN_SEEDED and starts also from the
#: grid rates within twice the standard error of the seed's (at least ACCEL_SEED_STEPS
#: either side, at most ACCEL_SEED_MAX_STEPS: at -10 dB and near the span's edge the
#: detections' speeds scatter, braking at 25 m/s² from 28 m/s the first slopes read -10 to
#: -49 m/s²), a delay–speed search at each and the best kept, which the gain and echo tests
#: then judge as any other try.
ACCEL_SEED_HOPS = 8
ACCEL_SEED_LOBES = 1.5
ACCEL_SEED_POINTS = 4
ACCEL_SEED_MIN_MPS2 = 8.0
#: The hop length (s) at which ACCEL_SEED_MIN_MPS2 was measured (att random-cyclic, M = 10):
#: at one M the phase an acceleration puts at the window's ends grows as ``a T_h²``, so a
#: schedule of longer hops is seeded from ``ACCEL_SEED_MIN_MPS2 (ACCEL_SEED_HOP_S / T_h)²``
#: (att three-state, 15 ms: 3.6 m/s²; there braking at 10 m/s² and reversing at 8 m/s² were
#: missed on 7-15 % and 41-49 % of their boundaries seeded from 8 m/s² only, 7 % and 27 %
#: seeded from 3.6).
ACCEL_SEED_HOP_S = 0.01
ACCEL_SEED_MAX_MPS2 = 40.0
ACCEL_RUN_SEEDED = 0.3
ACCEL_SEED_STEPS = 2
ACCEL_SEED_MAX_STEPS = 6
#: Where no track of detections shows the acceleration (an echo just detected, or just out
#: of the reverberation band, whose detections there were refused), the window's halves
#: show it (:func:`halves_seed`) where each holds at least
#: HALVES_MIN_HOPS hops.
HALVES_MIN_HOPS = 4


class AccelFitHost(Protocol):
    """What the accelerating fit reads of its refiner (:class:`~hil.estimation.refine.
    CoherentRefiner`)."""

    c: float
    fs_hz: float
    m_hops: int
    hop_len_s: float
    speed_span_mps: float
    sub_hops: int
    sub_speed_points: int
    n_tones: int
    echo_test: EchoTest
    #: The M hops' Doppler resolution, m/s.
    v_res: float
    #: The grid of time-scale rates the curved fit starts from, 1/s, shape ``(G,)``.
    gammas: NDArray[np.float64]
    #: The latest detections ``(hop index, boundary time s, speed m/s)``, oldest first.
    detections: deque[tuple[int, float, float]]

    @property
    def slot_tables(self) -> tuple[NDArray[Any], ...]: ...

    def sub_word(self, hop_index: int) -> Codeword: ...

    def half_word(self, hop_index: int, first: bool) -> Codeword: ...

    def hop_slots(
        self, hop_ids: NDArray[np.int64], word: Codeword, t_s: float, alpha: float
    ) -> NDArray[np.int64] | None: ...

    def candidate_powers(
        self, args: tuple[Any, ...], known: NDArray[np.complex128], t: NDArray[np.float64],
        alpha: NDArray[np.float64], gamma: NDArray[np.float64],
    ) -> NDArray[np.float64]: ...  # fmt: skip

    def search_near(
        self, word: Codeword, hop_ids: NDArray[np.int64], t_s: float, v: float, lobe: float,
        known: NDArray[np.complex128], grid: tuple[Any, ...],
    ) -> tuple[float, float, int, tuple[Any, ...]] | None: ...  # fmt: skip

    def refinement_at(
        self, args: tuple[Any, ...], known: NDArray[np.complex128], word: Codeword, t: float,
        alpha: float, gamma: float, curved: bool,
    ) -> Refinement: ...  # fmt: skip


def accel_seed(
    host: AccelFitHost, hop_index: int, t_s: float, speed: float, lobe: float
) -> tuple[float, float] | None:
    """The acceleration and its standard error (m/s²) the detections of this echo's
    track show up to this one (:data:`ACCEL_SEED_HOPS`, :func:`speed_trend`), where the
    acceleration is at least :data:`ACCEL_SEED_MIN_MPS2`, scaled to the hop length
    (:data:`ACCEL_SEED_HOP_S`); else None. This detection is the latest recorded
    (:meth:`~hil.estimation.refine.CoherentRefiner.refine`); the earlier ones are the rest."""
    seen = np.array(host.detections, dtype=np.float64).reshape(-1, 3)[:-1]
    trend = speed_trend(
        seen[:, 0], seen[:, 1], seen[:, 2], hop_index, t_s, speed, host.hop_len_s, host.c,
        ACCEL_SEED_LOBES * lobe, host.speed_span_mps,
    )  # fmt: skip
    least = ACCEL_SEED_MIN_MPS2 * (ACCEL_SEED_HOP_S / host.hop_len_s) ** 2
    return trend if trend is not None and abs(trend[0]) >= least else None


def halves_seed(
    host: AccelFitHost, fit: Refinement, word: Codeword, hop_ids: NDArray[np.int64], lobe: float,
    known: NDArray[np.complex128],
) -> tuple[float, float] | None:  # fmt: skip
    """The acceleration and its standard error (m/s²) the window's own halves show
    (:data:`HALVES_MIN_HOPS`): a constant-speed search over the first ``⌊M/2⌋`` hops and
    one over the last ``⌊M/2⌋`` about ``fit`` (each line the curve's tangent at its hops'
    centre), their speeds' difference over the time between those centres; None where
    either finds no maximum inside or is not one echo by the coherence over all its hops
    (:attr:`echo_test`), or where the acceleration is below :data:`ACCEL_SEED_MIN_MPS2`
    scaled to the hop length (:func:`accel_seed`'s bound)."""
    n = host.m_hops // 2
    if n < HALVES_MIN_HOPS:
        return None
    v = fit.speed_mps(host.c)
    # A half's tangent is up to MAX_ACCEL_MPS2 over a quarter window off the whole
    # window's line, and a curved echo's constant-speed fit is no point of the curve:
    # the speed span and that reach, in steps of half a half's Doppler resolution.
    reach = host.speed_span_mps + 0.25 * MAX_ACCEL_MPS2 * host.m_hops * host.hop_len_s
    step = 0.5 * host.v_res * host.m_hops / n
    grid = (0.5 * lobe, reach, TIME_POINTS, 2 * int(math.ceil(reach / step)) + 1)
    speeds = []
    for part, ids in ((host.half_word(int(hop_ids[-1]), True), hop_ids[:n]),
                      (host.half_word(int(hop_ids[-1]), False), hop_ids[-n:])):  # fmt: skip
        searched = host.search_near(part, ids, fit.t_s, v, lobe, known, grid)
        if searched is None or searched[2] != FOUND:
            return None
        t_h, v_h, _, args = searched
        alpha_h = (host.c + v_h) / (host.c - v_h)
        coherence = echo_quality(args, known, part, host.n_tones, t_h, alpha_h)[1]
        if coherence.fraction < host.echo_test.fraction:
            return None
        speeds.append(v_h)
    gap_s = (host.m_hops - n) * host.hop_len_s
    accel = (speeds[1] - speeds[0]) / gap_s
    least = ACCEL_SEED_MIN_MPS2 * (ACCEL_SEED_HOP_S / host.hop_len_s) ** 2
    if abs(accel) < least:
        return None
    # Each half's speed error: the M hops' bound with half the energy and half the span
    # (sqrt(2) x 2), the two halves independent.
    sigma = 0.0 if fit.bound is None else 2.0 * math.sqrt(2.0) * fit.bound.sigma_speed_mps
    return accel, math.sqrt(2.0) * sigma / gap_s


def with_acceleration(
    host: AccelFitHost, fit: Refinement, word: Codeword, hop_ids: NDArray[np.int64], lobe: float,
    known: NDArray[np.complex128], seed: tuple[float, float] | None = None,
) -> Refinement:  # fmt: skip
    """``fit`` (constant speed, its maximum found) fitted again with a changing time scale
    (:data:`ACCEL_TRY`): the rate's grid at the fit's delay and time scale (those of the hops'
    centre: the curvature is even about it; over more than
    :data:`~hil.estimation.refine.SUB_HOPS` hops, each rate's curve through the fit of the last
    of them) on the fit's grating lobe and its two neighbours; from each of the
    :data:`ACCEL_STARTS` best local maxima, the delay–speed fit and a parabola in the rate,
    :data:`ACCEL_ROUNDS` times. The best accelerating fit where it raises the likelihood by
    :data:`ACCEL_GAIN`, else ``fit``; its time and time scale are the boundary's. With ``seed``
    (m/s², the detections' own acceleration and its standard error, :func:`accel_seed`) one more
    start: the best of the delay–speed searches at the grid rates about the seed's
    (:func:`_seeded_start`)."""
    gammas = host.gammas
    n = gammas.shape[0]
    # Each rate's curve through a point of the echo: the fit's own (the hops' centre)
    # or, over more than SUB_HOPS hops (where the curvature, growing as M², leaves the
    # constant-speed fit of all M hops nowhere near the echo), a constant-speed fit of
    # the last SUB_HOPS hops, whose line is the curve's tangent at their centre.
    t_c = np.full(n, fit.t_s)
    a_c = np.full(n, fit.alpha)
    if host.sub_hops < host.m_hops:
        sub = host.sub_word(int(hop_ids[-1]))
        grid = (0.5 * lobe, host.speed_span_mps, TIME_POINTS, host.sub_speed_points)
        v = fit.speed_mps(host.c)
        searched = host.search_near(sub, hop_ids[-host.sub_hops :], fit.t_s, v, lobe, known, grid)
        if searched is None or searched[2] != FOUND:
            return fit
        t_sub, a_sub = searched[0], (host.c + searched[1]) / (host.c - searched[1])
        for i, g in enumerate(gammas):
            a_b = a_sub - float(g) * sub.centre_s / a_sub
            t_c[i], a_c[i] = to_centre(t_sub, a_b, float(g), word.centre_s)
    # The M hops' tables after the fewer hops' search, whose fills may take slots.
    slots = host.hop_slots(hop_ids, word, fit.t_s, fit.alpha)
    if slots is None:
        return fit
    args = (*host.slot_tables, slots, *word.hops, host.fs_hz, host.hop_len_s)
    # Over the M hops the rate's phase (even about the centre) can alias with the
    # delay's and time scale's (odd) at another grating lobe or rate: several starts.
    shifts = lobe * np.array([-1.0, 0.0, 1.0])
    power = host.candidate_powers(
        args, known, (shifts[:, None] + t_c).ravel(), np.tile(a_c, 3), np.tile(gammas, 3)
    ).reshape(3, n)
    inner = power[:, 1:-1]
    peak = (inner > power[:, :-2]) & (inner >= power[:, 2:])
    rows, cols = np.nonzero(peak)
    order = np.argsort(-inner[rows, cols])[:ACCEL_STARTS]
    starts = [
        (float(t_c[c] + shifts[r]), float(a_c[c]), float(gammas[c]))
        for r, c in zip(rows[order], cols[order] + 1, strict=True)
    ]
    if seed is not None:
        seeded = _seeded_start(host, args, known, fit, seed, lobe)
        if seeded is not None:
            starts.append(seeded)
    best: tuple[float, float, float, float] | None = None
    for t0, a0, g0 in starts:
        found = accel_fit(host, args, known, t0, a0, g0, lobe)
        if found is not None and (best is None or found[3] > best[3]):
            best = found
    if best is None:
        return fit
    t, alpha, gamma, p_best = best
    p0 = host.candidate_powers(args, known, np.array([fit.t_s]), np.array([fit.alpha]), np.zeros(1))
    gain = 10.0 ** (fit.e_over_n0_db / 10.0) * (p_best / p0[0] - 1.0) if p0[0] > 0 else 0.0
    if not gain > ACCEL_GAIN:
        return fit
    return host.refinement_at(args, known, word, t, alpha, gamma, True)


def _seeded_start(
    host: AccelFitHost, args: tuple[Any, ...], known: NDArray[np.complex128], fit: Refinement,
    seed: tuple[float, float], lobe: float,
) -> tuple[float, float, float] | None:  # fmt: skip
    """The curved fit's start from the acceleration ``seed`` (m/s², and its standard
    error): at each grid rate (``γ = a (α+1)²/(2c)``) within twice the error of the
    seed's (at least :data:`ACCEL_SEED_STEPS` steps either side, at most
    :data:`ACCEL_SEED_MAX_STEPS`), the delay–speed search about ``fit`` (±½ lobe, ± the
    speed span); the best ``(t, alpha, gamma)`` (the hops' centre's line), None where no
    search finds a maximum inside."""
    step = float(host.gammas[1] - host.gammas[0])
    to_rate = (fit.alpha + 1.0) ** 2 / (2.0 * host.c)
    g_seed = float(np.clip(seed[0], -ACCEL_SEED_MAX_MPS2, ACCEL_SEED_MAX_MPS2)) * to_rate
    reach = 2.0 * seed[1] * to_rate / step
    steps = int(np.clip(math.ceil(reach), ACCEL_SEED_STEPS, ACCEL_SEED_MAX_STEPS))
    v_fit = fit.speed_mps(host.c)
    grid = (0.5 * lobe, host.speed_span_mps, TIME_POINTS, SPEED_POINTS, FIT_PASSES)
    best: tuple[float, float, float] | None = None
    p_best = -1.0
    starts = [(fit.t_s, v_fit, g_seed + k * step) for k in range(-steps, steps + 1)]
    # Then the best one's neighbouring grating lobes: at -10 dB a curved fit's lobe is
    # decided ~1 dB apart as a constant-speed one's (CoherentRefiner.better_lobe).
    for i in range(len(starts) + 2):
        if i == len(starts):
            if best is None:
                break
            v_best = host.c * (best[1] - 1.0) / (best[1] + 1.0)
            starts += [(best[0] + d, v_best, best[2]) for d in (-lobe, lobe)]
        t, v, g = starts[i]
        t, v, outcome = maximise_recentred(args, known, g, host.c, t, v, grid)
        if outcome != FOUND:
            continue
        alpha = (host.c + v) / (host.c - v)
        one = (np.array([t]), np.array([alpha]), np.array([g]))
        p = float(host.candidate_powers(args, known, *one)[0])
        if p > p_best:
            best, p_best = (t, alpha, g), p
    return best


def accel_gain(
    host: AccelFitHost, args: tuple[Any, ...], known: NDArray[np.complex128], word: Codeword,
    t: float, alpha: float, gamma: float,
) -> float:  # fmt: skip
    """What the rate ``gamma`` adds to ``ln Λ = |C|²/(σ² E_s)`` at ``(t, alpha)`` (the
    hops' centre's line), ``σ²`` what the accelerating fit leaves of the windows' energy."""
    en0 = echo_quality(args, known, word, host.n_tones, t, alpha, gamma)[0]
    p = host.candidate_powers(args, known, np.full(2, t), np.full(2, alpha), np.array([0.0, gamma]))
    return en0 * (1.0 - p[0] / p[1]) if p[1] > 0 else 0.0


def accel_fit(
    host: AccelFitHost, args: tuple[Any, ...], known: NDArray[np.complex128], t: float,
    alpha: float, gamma: float, lobe: float,
) -> tuple[float, float, float, float] | None:  # fmt: skip
    """From ``(t, alpha, gamma)`` (s, the centre's time scale, 1/s): the delay–speed fit at
    the rate, then a parabola in the rate over half the grid's step (halving each
    round), :data:`ACCEL_ROUNDS` times; ``(t, alpha, gamma, |C|²)``, None where the fit
    finds no maximum inside."""
    step = float(host.gammas[1] - host.gammas[0])
    v = host.c * (alpha - 1.0) / (alpha + 1.0)
    grid = (0.125 * lobe, 0.25 * host.speed_span_mps, 5, 5, FIT_PASSES)
    p = np.zeros(3)
    for r in range(ACCEL_ROUNDS):
        t, v, outcome = maximise_recentred(args, known, gamma, host.c, t, v, grid)
        if outcome != FOUND:
            return None
        alpha = (host.c + v) / (host.c - v)
        h = 0.5 * step / 2**r
        rates = gamma + h * np.arange(-1.0, 2.0)
        p = host.candidate_powers(args, known, np.full(3, t), np.full(3, alpha), rates)
        gamma += h * parabolic_offset(p[0], p[1], p[2])  # 0 where p has no maximum
    p_end = host.candidate_powers(args, known, np.array([t]), np.array([alpha]), np.array([gamma]))
    return t, alpha, gamma, float(p_end[0])


def speed_trend(
    hops: NDArray[np.float64], times: NDArray[np.float64], speeds: NDArray[np.float64],
    hop_index: int, t_s: float, speed: float, hop_s: float, c: float, lobe_s: float,
    span_mps: float,
) -> tuple[float, float] | None:  # fmt: skip
    """The acceleration (m/s², of the closing speed) that detections show and its standard
    error (m/s²): the least-squares slope of speed against time (``hop_s`` a hop) of the
    detection ``(hop_index, t_s, speed)`` (its boundary, s; m/s) and the earlier ones (shape
    ``(K,)`` each: hop index, boundary time s, speed m/s) up to :data:`ACCEL_SEED_HOPS` hops
    before it on its track, one a hop (the latest): the boundary time within ``lobe_s`` (s)
    of this one's moved back at hops of ``hop_s / α``, the speed within ``span_mps`` (m/s)
    plus what :data:`ACCEL_SEED_MAX_MPS2` changes it by. None where fewer than
    :data:`ACCEL_SEED_POINTS` hops (this one's included) are on the track."""
    k = hop_index - hops
    alpha = (c + speed) / (c - speed)
    a_j = (c + speeds) / (c - speeds)
    on_track = (
        (k >= 1)
        & (k <= ACCEL_SEED_HOPS)
        & (np.abs(t_s - times - k * hop_s * 2.0 / (a_j + alpha)) <= lobe_s)
        & (np.abs(speeds - speed) <= span_mps + ACCEL_SEED_MAX_MPS2 * k * hop_s)
    )
    if int(np.count_nonzero(on_track)) + 1 < ACCEL_SEED_POINTS:
        return None
    # The latest detection of each hop (the receiver brings them in order).
    k_on, v_on = k[on_track], speeds[on_track]
    _, last = np.unique(k_on[::-1], return_index=True)
    idx = k_on.shape[0] - 1 - last
    if idx.shape[0] + 1 < ACCEL_SEED_POINTS:
        return None
    x = np.concatenate(([0.0], -k_on[idx] * hop_s))
    y = np.concatenate(([speed], v_on[idx]))
    x = x - x.mean()
    slope = float(np.dot(x, y - y.mean()) / np.dot(x, x))
    left = y - y.mean() - slope * x
    return slope, float(np.sqrt(np.dot(left, left) / (x.shape[0] - 2) / np.dot(x, x)))


def hops_on_curve(
    t_b: float, alpha_b: float, rate: float, d: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each hop's line ``(t_i, α_i)`` (s; shape of ``d``) on the curve through the boundary
    ``(t_b, alpha_b)`` whose time scale changes at ``rate`` (1/s): the transmit time heard
    ``τ`` after ``t_b`` is ``T_b + α_b τ + ½ rate τ²``; ``d`` the hops' transmit centres
    from ``T_b`` (s). A hop's line passes through its centre's point with the curve's slope
    there (the kernels' per-hop model); with ``rate = 0`` every hop is the boundary's line."""
    if rate == 0.0:
        return np.full(d.shape, t_b), np.full(d.shape, alpha_b)
    tau = d / alpha_b
    tau -= 0.5 * rate * tau * tau / (alpha_b + rate * tau)
    a_i = alpha_b + rate * tau
    return t_b + tau - d / a_i, a_i


def to_boundary(t: float, alpha: float, gamma: float, d_c: float) -> tuple[float, float]:
    """The boundary's receive time (s) and time scale of the kernels' accelerating mapping
    (:func:`~hil.estimation.refine_kernels.candidate_sums`) of parameters ``(t, alpha,
    gamma)``, ``d_c`` (s) the hops' transmit centre from the boundary: where the curve
    reaches ``T_b``, ``u`` after the centre (one Newton step, error ``O(γ²)``)."""
    u = -d_c / alpha
    u -= 0.5 * gamma * u * u / (alpha + gamma * u)
    return t + d_c / alpha + u, alpha + gamma * u


def to_centre(t_b: float, alpha_b: float, gamma: float, d_c: float) -> tuple[float, float]:
    """The inverse of :func:`to_boundary` (two fixed-point steps: a search's start)."""
    alpha = alpha_b + gamma * d_c / alpha_b
    for _ in range(2):
        t_x, a_x = to_boundary(t_b, alpha, gamma, d_c)
        alpha += alpha_b - a_x
    t_x, _ = to_boundary(t_b, alpha, gamma, d_c)
    return t_b + (t_b - t_x), alpha
