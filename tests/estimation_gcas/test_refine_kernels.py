"""The refinement's compiled loops (hil.estimation.refine_kernels): the hop tables are the
moment prefix sums they stand for, a candidate's sums do not depend on the candidates computed
beside it, and the known hops a search reads per hop include every one its windows can meet.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import hil.estimation.refine_kernels as kernels
from hil.estimation.refine import CoherentRefiner

from .conftest import FS, C, att_schedule, echo_samples


def test_a_slot_holds_the_prefix_sums_of_its_moments() -> None:
    # S[j, p] = Σ_{k<j} x_k e^{−j2π c u_k} (u_k / D)^p with u_k = u0 + k, and E[j] = Σ_{k<j} x_k²,
    # side 0 rows 0..R and side 1 rows span−R..span; the fill's rotation recurrence (renewed
    # every 256 samples) stays within 1e-12 of the direct exponential.
    rng = np.random.default_rng(11)
    x = rng.normal(size=3000)
    span, rows, pos, u0, cycles, hop = 1212, 213, 37, -606.25, 0.0913, 1000.0
    prefix = np.zeros((3, 2, rows, kernels.N_MOMENTS), dtype=np.complex128)
    energy = np.zeros((3, 2, rows))
    kernels._fill_slot(x, pos, 1, u0, span, cycles, hop, prefix, energy)
    u = u0 + np.arange(span)
    y = x[pos : pos + span] * np.exp(-2j * np.pi * cycles * u)
    powers = (u / hop)[:, None] ** np.arange(kernels.N_MOMENTS)
    direct = np.vstack([np.zeros(kernels.N_MOMENTS), np.cumsum(y[:, None] * powers, axis=0)])
    direct_e = np.concatenate([[0.0], np.cumsum(x[pos : pos + span] ** 2)])
    scale = np.max(np.abs(direct), axis=0)
    assert np.max(np.abs(prefix[1, 0] - direct[:rows]) / scale) < 1e-12
    assert np.max(np.abs(prefix[1, 1] - direct[span - rows + 1 :]) / scale) < 1e-12
    assert np.allclose(energy[1, 0], direct_e[:rows], rtol=1e-13, atol=0.0)
    assert np.allclose(energy[1, 1], direct_e[span - rows + 1 :], rtol=1e-13, atol=0.0)
    assert not prefix[0].any() and not prefix[2].any()  # other slots untouched


def _kernel_args(refiner: CoherentRefiner, hop: int, t_s: float, alpha: float) -> tuple:
    word = refiner._codeword(hop)
    hop_ids = np.arange(hop - refiner.m_hops + 1, hop + 1, dtype=np.int64)
    slots = refiner.hop_slots(hop_ids, word, t_s, alpha)
    assert slots is not None
    return (*refiner.slot_tables, slots, *word.hops, refiner.fs_hz, refiner.hop_len_s)


def test_a_candidates_sums_do_not_depend_on_its_neighbours() -> None:
    # Candidates of one time scale share their per-hop constants (made once per run of equal
    # time scales): the same candidate alone, or between others of other time scales and
    # rates, gives the same bits.
    schedule = att_schedule()
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(echo_samples(schedule, 70.0, 12.0, 0.4, snr_db=0.0, seed=4), 0)
    alpha = (C + 12.0) / (C - 12.0)
    hop = 28  # its windows end 0.38 s in, within the input and the kept history
    t_s = float(schedule.hops(hop + 1, 1).start_s[0]) + 2 * 70.0 / C
    args = _kernel_args(refiner, hop, t_s, alpha)
    t = t_s + 1e-5 * np.array([-3.0, -1.0, 0.0, 2.0, 5.0, 1.0])
    a = alpha + np.array([0.0, 0.0, 0.0, 1e-4, 1e-4, 1e-4])  # the last: a rate alone changes
    g = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.004])
    m = refiner.m_hops
    known = np.zeros((5, 0), dtype=np.complex128)

    def sums(tt: np.ndarray, aa: np.ndarray, gg: np.ndarray) -> tuple[np.ndarray, ...]:
        n = tt.shape[0]
        out = (np.empty(n, complex), np.empty(n), np.empty(n), np.empty((n, m), complex))
        kernels.candidate_sums(*args, tt, aa, gg, *out, known)
        return out

    together = sums(t, a, g)
    for c in range(t.shape[0]):
        alone = sums(t[c : c + 1], a[c : c + 1], g[c : c + 1])
        for got, want in zip(alone, together, strict=True):
            assert got[0].tobytes() == want[c].tobytes()
    assert np.all(np.abs(together[0]) > 0)


def test_sums_without_the_input_energy_keep_every_other_bit() -> None:
    # candidate_sums with no input-energy output (shape (0,)) skips its table reads: C, the
    # model's energy and the hops' terms are the bits of the call that reads it, with and
    # without known hops, straight and curved.
    args, alpha, t_s, known = _echo_with_known_hops(seed=5)
    t = t_s + 1e-5 * np.array([-3.0, 0.0, 2.0, 0.0, 1.0])
    a = alpha + np.array([0.0, 0.0, 1e-4, 0.0, 1e-4])
    g = np.array([0.0, 0.0, 0.0, 0.003, -0.002])
    m = args[6].shape[0]
    for rows in (known, np.zeros((5, 0), dtype=np.complex128)):
        for gg in (np.zeros(5), g):
            full = (np.empty(5, complex), np.empty(5), np.empty(5), np.empty((5, m), complex))
            kernels.candidate_sums(*args, t, a, gg, *full, rows)
            part = (np.empty(5, complex), np.empty(5), np.empty(0), np.empty((5, m), complex))
            kernels.candidate_sums(*args, t, a, gg, *part, rows)
            for i in (0, 1, 3):
                assert part[i].tobytes() == full[i].tobytes()
            if not rows.shape[1]:  # the windows' energy was read: an echo in noise
                assert np.all(full[2] > 0.0)


@settings(max_examples=100, deadline=None)
@given(
    t_s=st.floats(0.5, 5.0),
    half_t=st.floats(1e-5, 2e-3),
    a_mid=st.floats(0.97, 1.03),
    half_a=st.floats(0.0, 1e-3),
    starts=st.lists(st.floats(-0.2, 0.05), min_size=1, max_size=30),
    lengths=st.lists(st.floats(1e-4, 0.02), min_size=30, max_size=30),
    probe=st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0)),
)
def test_the_known_hops_a_search_reads_include_every_one_it_can_meet(
    t_s: float, half_t: float, a_mid: float, half_a: float, starts: list[float],
    lengths: list[float], probe: tuple[float, float],
) -> None:  # fmt: skip
    # Any candidate (t, α) within the reach: every known hop whose interval overlaps hop i's
    # window [t + dt_lo/α, t + dt_hi/α] is among hop i's columns, and they are ascending.
    n = len(starts)
    known = np.zeros((5, n), dtype=np.complex128)
    known[2] = t_s + np.array(starts)
    known[3] = known[2] + np.array(lengths[:n])
    dt_hi = -0.01 * np.arange(10.0)[::-1]
    dt_lo = dt_hi - 0.01
    a_lo, a_hi = a_mid - half_a, a_mid + half_a
    near, n_near = kernels._columns_near(
        known, dt_lo, dt_hi, t_s - half_t, t_s + half_t, a_lo, a_hi
    )
    t = t_s - half_t + 2.0 * half_t * probe[0]
    alpha = a_lo + (a_hi - a_lo) * probe[1]
    for i in range(dt_lo.shape[0]):
        lo, hi = t + dt_lo[i] / alpha, t + dt_hi[i] / alpha
        meets = np.nonzero(np.minimum(hi, known[3].real) > np.maximum(lo, known[2].real))[0]
        read = near[i, : n_near[i]]
        assert set(meets.tolist()) <= set(read.tolist())
        assert np.all(np.diff(read) > 0)


def _echo_with_known_hops(seed: int) -> tuple[tuple[Any, ...], float, float, np.ndarray]:
    """A refiner's kernel arguments at a 70 m echo closing at 12 m/s (0 dB, hop 28), its time
    scale, boundary time (s), and 40 made-up known hops (``rng`` seed ``seed``) that start and
    end inside the M hops' windows, across their edges or outside."""
    schedule = att_schedule()
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(echo_samples(schedule, 70.0, 12.0, 0.4, snr_db=0.0, seed=4), 0)
    alpha = (C + 12.0) / (C - 12.0)
    hop = 28
    t_s = float(schedule.hops(hop + 1, 1).start_s[0]) + 2 * 70.0 / C
    rng = np.random.default_rng(seed)
    n_cols = 40
    known = np.zeros((5, n_cols), dtype=np.complex128)
    known[0] = rng.normal(size=n_cols) + 1j * rng.normal(size=n_cols)
    known[1] = rng.choice(schedule.tones_hz, n_cols) * (1.0 + rng.uniform(-0.02, 0.02, n_cols))
    known[2] = t_s + rng.uniform(-0.11, 0.0, n_cols)
    known[3] = known[2].real + rng.uniform(0.001, 0.012, n_cols)
    known[4] = t_s - rng.uniform(0.0, 0.02, n_cols)
    return _kernel_args(refiner, hop, t_s, alpha), alpha, t_s, known


def test_a_search_rows_carried_phasors_give_each_candidates_own_sums() -> None:
    # maximise walks a row of equally spaced times turning each hop's phasor and each known
    # column's integral ends by a fixed factor a step (_row_phasors, _row_edges); a candidate
    # so reached equals the same candidate computed alone (candidate_sums), to rounding, while
    # other echoes' hops start and end inside the windows, across their edges or outside.
    args, alpha, t_s, known = _echo_with_known_hops(7)
    prefix, energy, first, tail, alpha0, centre, slots, k, f, dt_lo, dt_hi, amp2, fs, hop_s = args
    m = slots.shape[0]
    near, n_near = kernels._every_column(m, known)
    step = 1e-4  # the row's times cross the known hops' ends and the windows' edges
    n_t = 9
    for a, gamma in ((alpha + 2e-4, 0.0), (alpha - 1e-4, 0.003)):
        consts, coef = kernels._scratch(slots, prefix)
        d_c_a = kernels._line(alpha0, slots, f, dt_lo, dt_hi, hop_s, a, gamma, consts, coef)
        curved = gamma != 0.0
        t0 = t_s - 0.5 * (n_t - 1) * step
        phasors = np.empty(m, dtype=np.complex128)
        turn = np.empty(m, dtype=np.complex128)
        edges = np.empty((5, m, known.shape[1]), dtype=np.complex128)
        kernels._row_phasors(centre, slots, t0, curved, d_c_a, consts, step, phasors, turn)
        kernels._row_edges(known, near, n_near, t0, curved, d_c_a, consts, step, edges)
        no_key, no_rot = np.empty(0), np.empty(0, dtype=np.complex128)
        row = np.empty(n_t, dtype=np.complex128)
        for j in range(n_t):
            if j:
                kernels._advance(phasors, turn)
                kernels._advance_edges(edges, n_near)
            row[j] = kernels._candidate(
                prefix, energy, first, tail, centre, slots, k, amp2, fs, t0 + j * step,
                curved, d_c_a, consts, coef, no_rot, known, near, n_near, no_key, no_rot,
                phasors, edges, True,
            )[0]  # fmt: skip
        t = t0 + step * np.arange(n_t)
        alone = np.empty(n_t, dtype=np.complex128)
        kernels.candidate_sums(
            *args, t, np.full(n_t, a), np.full(n_t, gamma), alone, np.empty(n_t), np.empty(n_t),
            np.empty((n_t, 0), dtype=np.complex128), known,
        )  # fmt: skip
        # Rounding: a hop's phase is about 1e4 rad (2π f α over the centre's 50 ms), whose
        # last bit is 2e-12 rad, in either path; ten hops' terms.
        assert np.max(np.abs(row - alone)) <= 1e-11 * np.max(np.abs(alone))
        # The known hops move the sums (the comparison reads their integrals).
        bare = np.empty(n_t, dtype=np.complex128)
        kernels.candidate_sums(
            *args, t, np.full(n_t, a), np.full(n_t, gamma), bare, np.empty(n_t), np.empty(n_t),
            np.empty((n_t, 0), dtype=np.complex128), np.zeros((5, 0), dtype=np.complex128),
        )  # fmt: skip
        assert np.min(np.abs(bare - alone)) > 1e-3 * np.max(np.abs(alone))


def test_a_grid_of_rows_gives_each_candidates_own_sums_and_model_energy() -> None:
    # grid_sums (the amplitude read near a detection: times t0 + j·step at several time
    # scales) carries each row's phasors and the known columns' ends as maximise does; every
    # candidate's C equals candidate_sums' to rounding, with and without known hops, and its
    # model energy Σ a_i² N_i (no phasor in it) bit for bit.
    args, alpha, t_s, known = _echo_with_known_hops(5)
    step, n_t = 1.5e-4, 9
    alphas = alpha + np.array([-3e-4, -1e-4, 0.0, 2e-4])
    t0 = t_s - 0.5 * (n_t - 1) * step
    t = np.tile(t0 + step * np.arange(n_t), alphas.size)
    a = np.repeat(alphas, n_t)
    for cols in (known, np.zeros((5, 0), dtype=np.complex128)):
        got_c = np.empty((alphas.size, n_t), dtype=np.complex128)
        got_m = np.empty((alphas.size, n_t))
        kernels.grid_sums(*args, cols, t0, step, alphas, got_c, got_m)
        want_c, want_m = np.empty(t.size, dtype=np.complex128), np.empty(t.size)
        kernels.candidate_sums(
            *args, t, a, np.zeros(t.size), want_c, want_m, np.empty(t.size),
            np.empty((t.size, 0), dtype=np.complex128), cols,
        )  # fmt: skip
        # Rounding as in the search's rows: a hop's phase of ~1e4 rad has a last bit of 2e-12.
        assert np.max(np.abs(got_c.ravel() - want_c)) <= 1e-11 * np.max(np.abs(want_c))
        assert got_m.ravel().tobytes() == want_m.tobytes()


def test_a_grid_with_known_hops_gives_each_candidates_bits_over_every_column() -> None:
    # candidate_sums on a grid of constant time scale reads only the known columns its
    # windows can meet and shares each column's rotation down a column of equal times: every
    # candidate's C, model energy and input energy are the bits of that candidate computed
    # over every column with no rotation kept (_candidate as fit_quality calls it).
    schedule = att_schedule()
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(echo_samples(schedule, 70.0, 12.0, 0.4, snr_db=0.0, seed=4), 0)
    alpha = (C + 12.0) / (C - 12.0)
    hop = 28
    t_s = float(schedule.hops(hop + 1, 1).start_s[0]) + 2 * 70.0 / C
    args = _kernel_args(refiner, hop, t_s, alpha)
    prefix, energy, first, tail, alpha0, centre, slots, k, f, dt_lo, dt_hi, amp2, fs, hop_s = args
    m = slots.shape[0]
    rng = np.random.default_rng(9)
    n_cols = 60
    known = np.zeros((5, n_cols), dtype=np.complex128)
    known[0] = rng.normal(size=n_cols) + 1j * rng.normal(size=n_cols)
    known[1] = rng.choice(schedule.tones_hz, n_cols) * (1.0 + rng.uniform(-0.02, 0.02, n_cols))
    # Starts within 1 ms of a window's edge (where a narrower reach would miss them) and,
    # a quarter of them, far before every window.
    edge = t_s + rng.choice(np.concatenate([dt_lo, dt_hi]), n_cols) / alpha
    known[2] = edge + rng.uniform(-1e-3, 1e-3, n_cols)
    known[2, ::4] = t_s - rng.uniform(0.2, 0.4, n_cols)[::4]
    known[3] = known[2].real + rng.uniform(0.001, 0.012, n_cols)
    known[4] = t_s - rng.uniform(0.0, 0.02, n_cols)
    times = t_s + 1e-4 * np.arange(-4.0, 5.0)  # ±0.4 ms: past the reach's slack
    alphas = alpha + 1e-3 * np.arange(-3.0, 4.0)
    t = np.tile(times, alphas.size)
    a = np.repeat(alphas, times.size)
    n = t.size
    got = (np.empty(n, complex), np.empty(n), np.empty(n))
    kernels.candidate_sums(
        *args, t, a, np.zeros(n), *got, np.empty((n, 0), dtype=np.complex128), known
    )
    near, n_near = kernels._every_column(m, known)
    assert n_near[0] == n_cols
    no_key, no_rot = np.empty(0), np.empty(0, dtype=np.complex128)
    no_edges = np.empty((5, 0, 0), dtype=np.complex128)
    consts, coef = kernels._scratch(slots, prefix)
    for c in range(n):
        d_c_a = kernels._line(alpha0, slots, f, dt_lo, dt_hi, hop_s, a[c], 0.0, consts, coef)
        want = kernels._candidate(
            prefix, energy, first, tail, centre, slots, k, amp2, fs, t[c], False, d_c_a,
            consts, coef, no_rot, known, near, n_near, no_key, no_rot, no_rot, no_edges, True,
        )  # fmt: skip
        for g, w in zip(got, want, strict=True):
            assert np.asarray(g[c]).tobytes() == np.asarray(w).tobytes()
    # The known hops move the sums (the comparison reads their integrals).
    bare = np.empty(n, complex)
    kernels.candidate_sums(
        *args, t, a, np.zeros(n), bare, np.empty(n), np.empty(n),
        np.empty((n, 0), dtype=np.complex128), np.zeros((5, 0), dtype=np.complex128),
    )  # fmt: skip
    assert np.min(np.abs(bare - got[0])) > 1e-3 * np.max(np.abs(got[0]))


def test_a_searchs_candidate_is_the_candidates_own_c_bit_for_bit() -> None:
    # maximise reads C alone (_candidate_c: no energies); along a row of carried phasors and
    # known columns' ends it is _candidate's C, the same bits, at a constant time scale and
    # under a rate.
    args, alpha, t_s, known = _echo_with_known_hops(3)
    prefix, energy, first, tail, alpha0, centre, slots, k, f, dt_lo, dt_hi, amp2, fs, hop_s = args
    m = slots.shape[0]
    near, n_near = kernels._every_column(m, known)
    step, n_t = 1e-4, 9
    compared = 0
    for a, gamma in ((alpha + 2e-4, 0.0), (alpha - 1e-4, 0.003)):
        consts, coef = kernels._scratch(slots, prefix)
        d_c_a = kernels._line(alpha0, slots, f, dt_lo, dt_hi, hop_s, a, gamma, consts, coef)
        curved = gamma != 0.0
        t0 = t_s - 0.5 * (n_t - 1) * step
        phasors = np.empty(m, dtype=np.complex128)
        turn = np.empty(m, dtype=np.complex128)
        edges = np.empty((5, m, known.shape[1]), dtype=np.complex128)
        kernels._row_phasors(centre, slots, t0, curved, d_c_a, consts, step, phasors, turn)
        kernels._row_edges(known, near, n_near, t0, curved, d_c_a, consts, step, edges)
        no_key, no_rot = np.empty(0), np.empty(0, dtype=np.complex128)
        for j in range(n_t):
            if j:
                kernels._advance(phasors, turn)
                kernels._advance_edges(edges, n_near)
            t = t0 + j * step
            full = kernels._candidate(
                prefix, energy, first, tail, centre, slots, k, amp2, fs, t, curved, d_c_a,
                consts, coef, no_rot, known, near, n_near, no_key, no_rot, phasors, edges,
                True,
            )[0]  # fmt: skip
            alone = kernels._candidate_c(
                prefix, first, tail, slots, k, fs, t, curved, d_c_a, consts, coef, known, near,
                n_near, no_key, no_rot, phasors, edges,
            )  # fmt: skip
            assert np.complex128(alone).tobytes() == np.complex128(full).tobytes()
            compared += abs(full) > 0
    assert compared == 2 * n_t


def test_the_ended_test_is_the_numpy_expression_bit_for_bit() -> None:
    # CoherentRefiner._ended's F test: max_k (M − 1)(F_k − F_{M−1}) − limit (total − F_k) > 0
    # with F_k = |Σ_{i≤k} h_i|² / Σ_{i≤k} a_i², over seeded hops of M = 3 … 29 (silent first
    # hops included), at limits on both sides of the decision.
    rng = np.random.default_rng(27)
    decided = []
    for trial in range(400):
        m = int(rng.integers(3, 30))
        h = rng.normal(size=m) + 1j * rng.normal(size=m)
        inv_energy = np.abs(rng.normal(size=m))
        if trial % 4 == 0:
            inv_energy[0] = 0.0
        inv_amp2 = np.abs(rng.normal(size=m))
        end_m = float(m - 1)
        limit = end_m * rng.uniform(0.0, 0.5)
        total = float(np.dot(h.real * h.real + h.imag * h.imag, inv_amp2))
        c = np.cumsum(h)
        fitted = (c.real * c.real + c.imag * c.imag) * inv_energy
        lead = fitted[:-1]
        want = bool(np.max(end_m * (lead - fitted[-1]) - limit * (total - lead)) > 0.0)
        assert kernels.ended_gain(h, inv_energy, total, end_m, limit) == want
        decided.append(want)
    assert 50 < sum(decided) < 350  # both outcomes are exercised
    nan_h = np.array([1.0, np.nan, 2.0], dtype=np.complex128)
    assert not kernels.ended_gain(nan_h, np.ones(3), 1.0, 2.0, 0.1)  # np.max of NaN > 0


def test_windows_left_without_noise_keep_their_hop_terms_coherences() -> None:
    # Known hops whose energies exceed the windows' (other echoes' fits taken out of a
    # window they overlap: their energies are subtracted, not their overlaps) leave no noise:
    # E/N0 is inf, and each coherence is still the hop terms' own, against an expected 1. A
    # codeword ghost beside two echoes at one speed 1 m apart (att, 0 dB) read a run coherence
    # of 1 there and was reported 60 m off its echoes.
    args, alpha, t_s, known = _echo_with_known_hops(3)
    known[0] *= 3.0  # their energies: several times the windows'
    schedule = att_schedule()
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    tones = refiner._codeword(28).tones
    n_tones = len(schedule.tones_hz)
    m = tones.shape[0]
    per_hop = np.empty((1, m), dtype=np.complex128)
    sums = (np.empty(1, complex), np.empty(1), np.empty(1))
    kernels.candidate_sums(
        *args, np.array([t_s]), np.array([alpha]), np.zeros(1), *sums, per_hop, known
    )  # fmt: skip
    c, es, signal = sums[0][0], sums[1][0], sums[2][0]
    assert signal - 2.0 * abs(c) ** 2 / es <= 0.0  # the windows hold no noise left
    h = per_hop[0]
    rho = abs(h.sum()) ** 2 / (m * np.sum(np.abs(h) ** 2))
    by_tone = [h[tones == g] for g in range(n_tones)]
    rho_tone = sum(abs(t.sum()) ** 2 for t in by_tone) / sum(
        t.size * np.sum(np.abs(t) ** 2) for t in by_tone
    )
    r = kernels.RUN_HOPS
    runs = [h[b : b + r] for b in range(m - r + 1)]
    rho_run = sum(abs(u.sum()) ** 2 for u in runs) / sum(r * np.sum(np.abs(u) ** 2) for u in runs)
    got = kernels.fit_quality(*args, known, 0.0, tones, n_tones, t_s, alpha)
    en0, g_rho, e_rho, g_tone, e_tone, g_run, e_run = got[:7]
    assert en0 == np.inf
    assert (e_rho, e_tone, e_run) == (1.0, 1.0, 1.0)
    assert np.allclose([g_rho, g_tone, g_run], [rho, rho_tone, rho_run], rtol=1e-9, atol=0.0)
    assert rho_run < 0.85  # not one echo's: the echo test's run fraction refuses it
