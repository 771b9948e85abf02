"""The kept width-1 exact unit correlators (``ExactHistory.values``, the time-codeword map's
terms) are the bits ``ExactHistory.windows`` computes, whatever was asked before."""

from __future__ import annotations

import numpy as np

from hil.estimation.gcas.search_two_stage import TwoStageSearch
from hil.signals.schedule import HopSchedule

from .conftest import echo_samples, make_gcas


def _fresh(history: object, first: np.ndarray, dd: np.ndarray) -> np.ndarray:
    """``windows`` of width 1: computed anew from the history, nothing kept."""
    return history.windows(first, dd, 1)[:, 0, :]  # type: ignore[attr-defined]


def test_kept_values_equal_the_windows_bit_for_bit(rc_schedule: HopSchedule) -> None:
    rx = make_gcas(rc_schedule, search="two-stage", reverb_speed_mps=0.0)
    assert isinstance(rx.strategy, TwoStageSearch)
    exact = rx.strategy.exact
    x = echo_samples(rc_schedule, 50.0, 10.0, 0.6, snr_db=0.0, seed=5)
    rng = np.random.default_rng(3)
    n_len = rx.strategy._fe.grid.lengths
    hits = 0
    for i in range(0, x.shape[0], 7_000):
        rx.process(x[i : i + 7_000])
        stop = exact.next_index
        held_from = stop - exact._ring.available
        # Windows held whole, partly dropped from the history, and not yet arrived; the
        # same (first, d) asked again (kept) and on every hypothesis.
        # The stretch around the oldest sample held is asked at every block: kept while
        # held whole, then partly dropped (read as zero there, as computed anew).
        edge = held_from + np.arange(-100, 150)
        first = np.concatenate([edge, rng.integers(held_from - 200, stop + 20, 60)])
        dd = np.concatenate([np.full(edge.shape, 7), rng.integers(0, n_len.size, 60)])
        first = np.concatenate([first, np.arange(stop - 400, stop)])
        dd = np.concatenate([dd, np.full(400, 7)])
        for _ in range(2):
            got = exact.values(first, dd)
            want = _fresh(exact, first, dd)
            assert got.tobytes() == want.tobytes()
        kept = (first - n_len[dd] + 1 >= held_from) & (first < stop)
        slots = first & (exact._value_n.shape[1] - 1)
        hits += int(np.count_nonzero(exact._value_n[dd[kept], slots[kept]] == first[kept]))
    assert hits > 0  # the kept path was read, not only the computed one


def test_kept_values_after_a_gap_are_the_new_history_s(rc_schedule: HopSchedule) -> None:
    rx = make_gcas(rc_schedule, search="two-stage", reverb_speed_mps=0.0)
    assert isinstance(rx.strategy, TwoStageSearch)
    exact = rx.strategy.exact
    a = echo_samples(rc_schedule, 50.0, 10.0, 0.3, snr_db=0.0, seed=6)
    b = echo_samples(rc_schedule, 40.0, -5.0, 0.3, snr_db=0.0, seed=7)
    rx.process(a)
    stop = exact.next_index
    old = stop - 1 - np.arange(0, 400, 10)
    dd = np.full(old.shape, 11)
    exact.values(old, dd)  # kept
    rx.process(b, gap_before=50)  # the history restarts after the gap
    new = exact.next_index - 1 - np.arange(0, 400, 10)
    for first in (old, new):
        assert exact.values(first, dd).tobytes() == _fresh(exact, first, dd).tobytes()
    # The old windows are no longer held: they read the restarted (empty) history.
    assert not np.any(exact.values(old, dd))


def test_the_map_terms_are_the_windows_computed_anew(rc_schedule: HopSchedule) -> None:
    """``ExactHistory.terms`` (the time-codeword map's) from the kept values: ``w·|u|²``
    (float32) and ``w·u`` (complex64) of ``windows`` to the bit, with and without the
    reverberation band's weights."""
    x = echo_samples(rc_schedule, 50.0, 10.0, 0.5, snr_db=0.0, seed=8)
    rng = np.random.default_rng(9)
    for extra in ({"reverb_speed_mps": 0.0}, {}):
        rx = make_gcas(rc_schedule, search="two-stage", **extra)  # type: ignore[arg-type]
        assert isinstance(rx.strategy, TwoStageSearch)
        exact, fe = rx.strategy.exact, rx.strategy._fe
        for i in range(0, x.shape[0], 9_000):
            rx.process(x[i : i + 9_000])
            idx = rx.strategy.retained(300)
            dcol = np.repeat(rng.integers(0, fe.grid.size, idx.size // 30 + 1), 30)[: idx.size]
            first = (idx[:, None] - fe.lags[dcol]).reshape(-1)
            u = _fresh(exact, first, np.repeat(dcol, fe.m_hops)).reshape(idx.size, fe.m_hops, -1)
            w = None if fe.tone_w is None else fe.tone_w[dcol][:, None, :]
            power = (np.square(u.real) + np.square(u.imag)).astype(np.float32)
            coherent = u.astype(np.complex64)
            if w is not None:
                power, coherent = power * w, coherent * w
            assert exact.terms(idx, dcol, False).tobytes() == power.tobytes()
            assert exact.terms(idx, dcol, True).tobytes() == coherent.tobytes()
        assert extra or fe.tone_w is not None  # the weighted case was run
