"""Compiled GCAS kernels against plain NumPy references: peaks, pruned and cached sums."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from hil.estimation.gcas import NO_SAMPLE, GcasReceiver
from hil.estimation.gcas.search_two_stage import TwoStageSearch
from hil.estimation.kernels import (
    _codeword_row,
    _order_down,
    first_possible_cells,
    masked_peak_cells,
    median,
    peak_cells,
    peak_indices,
    runner_up_pairs,
    second_peak_cells,
)

from .conftest import FS, C, att_schedule, echo_samples


def _peaks_reference(s: np.ndarray, h: int) -> np.ndarray:
    """First maxima over ±h with SciPy filters (the implementation the kernel replaced)."""
    centred = ndimage.maximum_filter1d(s, size=2 * h + 1, mode="constant", cval=-np.inf)
    before = ndimage.maximum_filter1d(s, size=h, origin=(h - 1) // 2, mode="constant", cval=-np.inf)
    prev = np.concatenate(([-np.inf], before[:-1]))
    return np.flatnonzero((s >= centred) & (s > prev))


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.sampled_from([-np.inf, 0.0, 1.0, 2.0, 3.0, 2.5]), min_size=1, max_size=60),
    st.integers(1, 6),
)
def test_peak_indices_equal_the_filter_reference(values: list[float], h: int) -> None:
    s = np.array(values)
    assert peak_indices(s, h, 0, s.shape[0]).tolist() == _peaks_reference(s, h).tolist()


def test_peak_indices_of_a_window_are_those_of_the_whole() -> None:
    s = np.random.default_rng(3).normal(size=500)
    whole = peak_indices(s, 7, 0, 500)
    part = peak_indices(s, 7, 120, 377)
    assert part.tolist() == [i for i in whole.tolist() if 120 <= i < 377]


VALUES = st.sampled_from([-np.inf, 0.0, 1.0, 2.0, 3.0, 2.5])


def _cells_reference(s: np.ndarray, hr: int, hc: int, leak: np.ndarray) -> list[tuple[int, int]]:
    """:func:`peak_cells` written out: first maxima over ±hr rows × ±hc columns (row-major
    ties), above the leak of every other cell of the row."""
    n, d = s.shape
    out = []
    for i in range(n):
        for j in range(d):
            v = s[i, j]
            if not v > -np.inf:
                continue
            window = [
                (a, b) for a in range(max(0, i - hr), min(n, i + hr + 1))
                for b in range(max(0, j - hc), min(d, j + hc + 1))
            ]  # fmt: skip
            earlier = all(s[a, b] < v for a, b in window if (a, b) < (i, j))
            later = all(s[a, b] <= v for a, b in window if (a, b) > (i, j))
            with np.errstate(invalid="ignore"):  # −inf · 0 leaks nothing (NaN compares false)
                above = not any(s[i, b] * leak[abs(j - b)] >= v for b in range(d))
            if earlier and later and above:
                out.append((i, j))
    return out


CELL_ROWS = st.lists(st.lists(VALUES, min_size=4, max_size=4), min_size=1, max_size=14)


@settings(max_examples=200, deadline=None)
@given(CELL_ROWS, st.integers(1, 3), st.integers(1, 3), st.sampled_from([0.0, 0.5]))
def test_peak_cells_equal_the_written_out_rule(
    rows: list[list[float]], hr: int, hc: int, far_leak: float
) -> None:
    s = np.array(rows)
    leak = np.array([0.0, 0.0, far_leak, far_leak])
    got_rows, got_cols = peak_cells(s, hr, hc, 0, s.shape[0], leak)
    assert list(zip(got_rows.tolist(), got_cols.tolist(), strict=True)) == _cells_reference(
        s, hr, hc, leak
    )


@settings(max_examples=200, deadline=None)
@given(
    CELL_ROWS, st.integers(2, 4), st.integers(1, 3), st.integers(1, 3),
    st.sampled_from([0.0, 0.5]), st.sampled_from([0.0, 0.6, 0.9]),
)  # fmt: skip
def test_second_peak_cells_equal_the_written_out_rule(
    rows: list[list[float]], hr: int, inner: int, hc: int, far_leak: float, level: float
) -> None:
    s = np.array(rows)
    leak = np.array([0.0, 0.0, far_leak, far_leak])
    inner = min(inner, hr - 1)
    got_rows, got_cols = second_peak_cells(s, hr, inner, hc, 0, s.shape[0], leak, level)
    wide = set(_cells_reference(s, hr, hc, leak))
    want = []
    for i, j in _cells_reference(s, inner, hc, leak):
        top = s[max(0, i - hr) : i + hr + 1, max(0, j - hc) : j + hc + 1].max()
        if (i, j) not in wide and s[i, j] >= level * top:
            want.append((i, j))
    assert list(zip(got_rows.tolist(), got_cols.tolist(), strict=True)) == want


@settings(max_examples=200, deadline=None)
@given(
    CELL_ROWS, st.integers(1, 4), st.integers(1, 3), st.integers(0, 1), st.integers(1, 3),
    st.sampled_from([0.0, 0.3]), st.sampled_from([0.6, 1.0]),
)  # fmt: skip
def test_masked_peak_cells_equal_the_written_out_rule(
    rows: list[list[float]], hr: int, hc: int, own: int, apart: int, level: float, below: float
) -> None:
    s = np.array(rows)
    own = min(own, hc - 1)
    got_rows, got_cols = masked_peak_cells(s, hr, hc, own, apart, 0, s.shape[0], level, below)
    want = []
    for i, j in _cells_reference(s, hr, own, np.full(4, np.nan)):  # no leak test
        window = s[max(0, i - hr) : i + hr + 1, max(0, j - hc) : j + hc + 1]
        top_row = max(0, i - hr) + int(np.argmax(window)) // window.shape[1]
        top, v = window.max(), s[i, j]
        if abs(top_row - i) >= apart and level * top <= v < below * top:
            want.append((i, j))
    assert list(zip(got_rows.tolist(), got_cols.tolist(), strict=True)) == want


def test_a_weaker_echo_beside_a_stronger_ones_lobe_is_a_masked_cell() -> None:
    # Five hypotheses, lobe 2: a stronger echo's boundary at row 2 in column 1, its main lobe
    # over columns 0-2 and its Doppler response in column 3 peaking at its own boundary; a
    # weaker echo in column 4 with its boundary at row 6, half of the greatest cell within
    # two hypotheses of it (0.8, the stronger one's main lobe), which hides it from a
    # ±2-hypothesis maximum.
    s = np.array([
        [0.3, 0.5, 0.5, 0.2, 0.1],
        [0.5, 0.8, 0.6, 0.3, 0.1],
        [0.6, 1.0, 0.8, 0.35, 0.1],
        [0.5, 0.8, 0.6, 0.3, 0.1],
        [0.4, 0.6, 0.4, 0.3, 0.2],
        [0.4, 0.6, 0.4, 0.3, 0.3],
        [0.4, 0.6, 0.4, 0.3, 0.4],
        [0.4, 0.6, 0.4, 0.3, 0.3],
    ])  # fmt: skip
    assert peak_cells(s, 4, 2, 0, 8, np.zeros(5))[1].tolist() == [1]
    rows, cols = masked_peak_cells(s, 4, 2, 1, 2, 0, 8, 0.08, 0.6)
    assert list(zip(rows.tolist(), cols.tolist(), strict=True)) == [(6, 4)]
    # The stronger one's own response in column 3 peaks at its boundary: never a masked cell.
    assert masked_peak_cells(s, 4, 2, 0, 2, 0, 8, 0.0, 1.0)[1].tolist() == [4]
    # Reaching the bound's fraction of the greater cell it is not one.
    assert masked_peak_cells(s, 4, 2, 1, 2, 0, 8, 0.08, 0.45)[0].tolist() == []


def test_a_second_echo_within_half_a_hop_of_a_greater_one_is_a_second_cell() -> None:
    # One row (one Doppler cell): two echoes' peaks 3 blocks apart (1.0 and 0.9), one echo's
    # trough (0.4) and a bump on it (0.45) between boundaries; hc = 5 blocks, inner = 1; the
    # rows decided are those with hc rows known after them, as in the search.
    row = np.array([0.5, 0.7, 1.0, 0.8, 0.85, 0.9, 0.6, 0.4, 0.45, 0.4, 0.5, 0.6])
    s = row[:, None]
    none = np.zeros(1)
    assert peak_cells(s, 5, 1, 0, 7, none)[0].tolist() == [2]
    assert second_peak_cells(s, 5, 1, 1, 0, 7, none, 0.6)[0].tolist() == [5]
    assert second_peak_cells(s, 5, 1, 1, 0, 7, none, 0.95)[0].tolist() == []


def test_peak_cells_of_one_column_are_peak_indices() -> None:
    s = np.random.default_rng(5).normal(size=300)
    rows, cols = peak_cells(s[:, None], 6, 1, 0, 300, np.zeros(1))
    assert rows.tolist() == peak_indices(s, 6, 0, 300).tolist() and not cols.any()


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(CELL_ROWS, st.lists(st.lists(VALUES, min_size=4, max_size=4), max_size=6),
       st.integers(1, 3), st.integers(1, 3), st.data())  # fmt: skip
def test_first_possible_cells_are_the_earliest_any_continuation_can_make(
    known: list[list[float]], later: list[list[float]], hr: int, hc: int, data: st.DataObject
) -> None:
    s = np.array(known)
    hi = s.shape[0]
    lo = data.draw(st.integers(0, hi))
    leak = np.array([0.0, 0.0, 0.5, 0.5])
    first, mask = first_possible_cells(s, hr, hc, lo, hi, leak)
    assert lo <= first <= hi
    # No continuation makes a cell of an earlier row (or outside the mask) a peak ...
    ext = np.concatenate((s, np.array(later).reshape(-1, 4)))
    rows, cols = peak_cells(ext, hr, hc, lo, hi, leak)
    assert all(r > first or (r == first and mask[c]) for r, c in zip(rows, cols, strict=True))
    # ... and one that only falls makes the masked cells of `first` peaks (a known row).
    if first < hi:
        low = np.concatenate((s, np.full((hr, 4), -np.inf)))
        rows, cols = peak_cells(low, hr, hc, lo, hi, leak)
        assert {(first, int(c)) for c in np.flatnonzero(mask)} <= set(
            zip(rows.tolist(), cols.tolist(), strict=True)
        )


def two_stage(rx: GcasReceiver) -> TwoStageSearch:
    """The two-stage search that ``rx`` holds."""
    assert isinstance(rx.strategy, TwoStageSearch)
    return rx.strategy


def _stage_two_receiver(m_hops: int = 10) -> tuple[GcasReceiver, np.ndarray, np.ndarray]:
    """A receiver fed an echo, with candidate centres and hypotheses of its recent blocks."""
    schedule = att_schedule()
    rx = GcasReceiver(
        schedule, FS, sound_speed_mps=C, max_speed_mps=30.0, max_range_m=100.0, m_hops=m_hops
    )
    rx.process(echo_samples(schedule, 55.0, 9.0, 0.6, snr_db=-12.0, seed=4))
    search = two_stage(rx)
    stop = search._cs_ring.next_index - 20
    cand_b = np.arange(stop - 300, stop, 10)
    d_hat = search._cd_ring.rows(cand_b)
    pair = np.stack([d_hat, np.clip(d_hat + 29, 0, rx.grid.size - 1)], axis=1)  # and a ghost's
    centres = cand_b[:, None] * search._B + search._c_shift[pair]
    return rx, centres, pair


def test_pruned_sums_keep_every_maximum_of_the_full_sums() -> None:
    rx, centres, pair = _stage_two_receiver()
    search = two_stage(rx)
    w = search.fine_half
    full = search.exact.sums(centres, pair, w)
    pruned = search.exact.sums(centres, pair, w, prune=True)
    assert np.all(np.isfinite(full))
    assert np.count_nonzero(np.isinf(pruned)) > pruned.size // 2  # most rows were skipped
    evaluated = np.isfinite(pruned)
    assert np.array_equal(pruned[evaluated], full[evaluated])
    r = np.arange(pair.shape[0])
    best = np.argmax(full.max(axis=(2, 3)), axis=1)
    assert np.array_equal(best, np.argmax(pruned.max(axis=(2, 3)), axis=1))
    a_full, a_pruned = full[r, best], pruned[r, best]  # (C, 2w + 1, J)
    ip = np.argmax(a_full.max(axis=2), axis=1)
    assert np.array_equal(ip, np.argmax(a_pruned.max(axis=2), axis=1))
    for t in (ip - 1, ip, ip + 1):
        inside = (t >= 0) & (t <= 2 * w)
        assert np.array_equal(a_pruned[r[inside], t[inside]], a_full[r[inside], t[inside]])


def test_cached_sums_equal_sums_from_an_empty_cache() -> None:
    rx, centres, pair = _stage_two_receiver(m_hops=15)
    search = two_stage(rx)
    w = search.fine_half
    search.exact._cache_n.fill(NO_SAMPLE)
    cold = search.exact.sums(centres, pair, w)
    warm = search.exact.sums(centres, pair, w)  # every value now from the cache
    one_by_one = []
    search.exact._cache_n.fill(NO_SAMPLE)
    for c in range(centres.shape[0] - 1, -1, -1):  # another order: other fills
        one_by_one.append(search.exact.sums(centres[c : c + 1], pair[c : c + 1], w))
    assert np.array_equal(cold, warm)
    assert np.array_equal(cold, np.concatenate(one_by_one[::-1]))


def test_a_codewords_sum_adds_its_terms_in_order_bit_for_bit() -> None:
    # A_j = Σ_m w|u|² of term m's tone, added in the order m = 0, 1, ..: each row equals the
    # cached weighted powers added one term at a time (J = 17 codewords on att: four at a
    # time, and the last alone).
    rx, centres, pair = _stage_two_receiver(m_hops=15)
    exact = two_stage(rx).exact
    w = two_stage(rx).fine_half
    full = exact.sums(centres, pair, w)
    fe = rx.front_end
    tone = exact._term_tone  # (M, J)
    mask = exact._cache_n.shape[1] - 1
    assert tone.shape == (15, fe.n_codewords) and fe.n_codewords % 4 == 1
    checked = 0
    for c in range(0, centres.shape[0], 7):
        for i in range(pair.shape[1]):
            d = int(pair[c, i])
            for t in (0, w, 2 * w):
                n = centres[c, i] - w + t - fe.lags[d]  # each term's sample, shape (M,)
                assert np.all(exact._cache_n[d, n & mask] == n)  # all arrived and kept
                want = np.zeros(fe.n_codewords)
                for m in range(tone.shape[0]):
                    want += exact._cache_p[d, tone[m], n[m] & mask]
                assert full[c, i, t].tobytes() == want.tobytes()
                checked += 1
    assert checked >= 18


@pytest.mark.parametrize("n_tones", [3, 4, 5])
def test_a_codeword_row_adds_its_terms_in_order_for_any_tone_count(n_tones: int) -> None:
    # Any tone count: term m's power of codeword j's tone is added in the order m = 0, 1, ..
    # (four codewords at a time, then the rest): the same bits as adding the terms one at a
    # time, late terms (samples not yet kept) read from their own array. Seeded.
    rng = np.random.default_rng(27)
    m_hops, n_words, width, cap, d, half = 11, 17, 9, 64, 1, 4
    tone = rng.integers(0, n_tones, (m_hops, n_words)).astype(np.int64)
    cache_p = rng.random((3, n_tones, cap)) * 10.0 ** rng.uniform(-3, 3, (3, n_tones, cap))
    late = rng.random((m_hops, width)) < 0.2
    late_p = rng.random((m_hops, width, n_tones))
    lags = rng.integers(0, 40, (3, m_hops)).astype(np.int64)
    centre = np.array([[200, 300]], dtype=np.int64)
    row = np.empty(n_words)
    for t in range(width):
        got = _codeword_row(0, 1, t, half, d, centre, lags, tone, cache_p, cap - 1, late,
                            late_p, np.empty((m_hops, n_tones)), row)  # fmt: skip
        want = np.zeros(n_words)
        for m in range(m_hops):
            if late[m, t]:
                want += late_p[m, t, tone[m]]
            else:
                want += cache_p[d, tone[m], (centre[0, 1] - half - lags[d, m] + t) & (cap - 1)]
        assert row.tobytes() == want.tobytes()
        assert got == want.max()


def test_samples_not_yet_received_are_never_cached() -> None:
    rx, _, _ = _stage_two_receiver()
    search = two_stage(rx)
    newest = search.exact.next_index
    w = search.fine_half
    centre = np.array([newest - 3, newest - 40])  # windows running past the newest sample
    dset = np.array([[5, 9], [5, 9]])
    late = search.exact.sums(centre, dset, w)
    stamped = search.exact._cache_n[search.exact._cache_n != NO_SAMPLE]
    assert stamped.size > 0 and stamped.max() < newest
    # Rows whose samples had all arrived equal those of a receiver that has seen more.
    more, _, _ = _stage_two_receiver()
    ahead_search = two_stage(more)
    more.process(np.zeros(2000))
    ahead_search.exact._cache_n.fill(NO_SAMPLE)
    ahead = ahead_search.exact.sums(centre, dset, w)
    arrived = centre[:, None] - w + np.arange(2 * w + 1)[None, :] < newest  # (2, 2w + 1)
    for c in range(2):
        assert np.array_equal(late[c][:, arrived[c]], ahead[c][:, arrived[c]])


def test_a_reset_receiver_equals_a_fresh_one() -> None:
    schedule = att_schedule()
    x = echo_samples(schedule, 40.0, -6.0, 0.4, snr_db=-5.0, seed=7)

    def build() -> GcasReceiver:
        return GcasReceiver(
            schedule, FS, sound_speed_mps=C, max_speed_mps=30.0, max_range_m=100.0, m_hops=10
        )

    used = build()
    used.process(echo_samples(schedule, 70.0, 20.0, 0.4, snr_db=10.0, seed=8))
    used.reset()
    fresh = build()
    first = used.process(x) + used.flush()
    assert first == fresh.process(x) + fresh.flush() and len(first) > 10


def test_building_a_receiver_does_not_call_the_map() -> None:
    calls: list[int] = []
    rx = GcasReceiver(
        att_schedule(), FS, sound_speed_mps=C, max_speed_mps=30.0, max_range_m=100.0,
        m_hops=10, on_map=lambda t, p, v: calls.append(t.shape[0]),
    )  # fmt: skip
    assert calls == []
    rx.process(np.zeros(12_000))
    assert sum(calls) == 1000  # 12 000 input samples at R = 12


@pytest.mark.parametrize("n", [1, 2, 3, 7, 64, 255, 256])
def test_median_is_numpys_bit_for_bit(n: int) -> None:
    """The coarse search's noise floor: chi-square-like powers, few distinct values (ties
    across the middle), sorted and one-off-constant arrays, each equal to ``np.median``."""
    rng = np.random.default_rng(n)
    cases = [
        rng.normal(size=n) ** 2 * 1e-3,
        rng.integers(0, 4, size=n).astype(np.float64),
        np.sort(rng.normal(size=n)),
        np.sort(rng.normal(size=n))[::-1].copy(),
        np.where(np.arange(n) == n // 3, -2.0, 1.5),
    ]
    for a in cases:
        before = a.copy()
        got = median(a, np.empty(2 * n))
        assert got == np.median(a)
        assert np.array_equal(a, before)  # the input is left as it was


def test_runner_up_pairs_are_the_masked_argmax() -> None:
    # (d, d₂): d₂ the first largest value more than one hypothesis from d, d where that value
    # is not finite; rows of few levels (ties), ±inf and a NaN.
    rng = np.random.default_rng(30)
    for trial in range(300):
        n, n_hyp = int(rng.integers(0, 6)), int(rng.integers(1, 12))
        if trial % 2:
            rows = rng.choice([-np.inf, 0.0, 1.0, 2.0, np.inf], size=(n, n_hyp))
        else:
            rows = rng.normal(size=(n, n_hyp))
        if trial % 7 == 0 and n:
            rows[rng.integers(0, n), rng.integers(0, n_hyp)] = np.nan
        cols = rng.integers(0, n_hyp, size=n)
        far = np.abs(np.arange(n_hyp)[None, :] - cols[:, None]) > 1
        masked = np.where(far, rows, -np.inf)
        second = np.argmax(masked, axis=1)
        found = np.isfinite(masked[np.arange(n), second])
        want = np.stack((cols, np.where(found, second, cols)), axis=1)
        assert np.array_equal(runner_up_pairs(rows, cols), want.reshape(n, 2))


def test_rows_in_decreasing_bound_are_the_stable_argsort() -> None:
    rng = np.random.default_rng(31)
    for trial in range(300):
        n = int(rng.integers(1, 40))
        v = rng.integers(0, 4, n).astype(np.float64) if trial % 2 else rng.normal(size=n)
        order = np.empty(n, dtype=np.int64)
        _order_down(v, order)
        assert np.array_equal(order, np.argsort(-v, kind="stable"))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_peak_cells_over_every_column_equal_the_written_out_rule(seed: int) -> None:
    # The second search's candidates (StrongestEcho): the window spans all 64 hypotheses,
    # the row maxima shortcut; shortlisted cells among −inf, ties across rows, no leak.
    rng = np.random.default_rng(seed)
    s = np.full((40, 64), -np.inf)
    for i in range(40):
        cols = rng.choice(64, size=8, replace=False)
        s[i, cols] = rng.integers(0, 6, size=8).astype(np.float64)
    leak = np.zeros(64)
    got_rows, got_cols = peak_cells(s, 5, 64, 0, 40, leak)
    want = _cells_reference(s, 5, 64, leak)
    assert list(zip(got_rows.tolist(), got_cols.tolist(), strict=True)) == want
    assert len(want) > 0
    lo_rows, lo_cols = peak_cells(s, 5, 63, 7, 31, leak)
    assert list(zip(lo_rows.tolist(), lo_cols.tolist(), strict=True)) == [
        (i, d) for i, d in want if 7 <= i < 31
    ]
