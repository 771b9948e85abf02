"""The two-stage GCAS search (``search="two-stage"``, the default): the boundaries of the full
search at a fraction of its cost.

Stage 1 (:class:`~hil.estimation.coarse_search.CoarseSearch`) runs the unit correlators and
the comb on blocks of ``B`` baseband samples (windows of ``Q_d = round(L_d/B)`` blocks, the
comb's lags rounded per term for a shortlist of hypotheses) and gives, per block, the comb of
each shortlisted hypothesis, ``d̂`` and the noise floor. Its candidate cells (block,
hypothesis) and the hypotheses compared for each come from a rule
(:mod:`hil.estimation.gcas.candidates`): every echo's cell, or the strongest per hop with
its block's runner-up. Stage 2 (:class:`~hil.estimation.gcas.exact.ExactHistory`, straight
from the baseband history, ``w·|u|²`` cached per sample) evaluates the exact sums ``A``
within ``±(W + 6)`` samples of each candidate for its hypotheses (only the samples that can
hold a maximum), keeps the one with the larger weighted maximum (the group statistic cannot
tell a hypothesis from its ghost, every tone seen as its neighbour at another speed; the
codeword sums can), moves the window onto a peak at its edge, drops a peak that repeats an
earlier one, and evaluates ``d ± 1`` at the peak sample for the Doppler
interpolation. The hot loops of both stages are compiled (:mod:`hil.estimation.kernels`).
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.estimation.coarse_search import CoarseSearch
from hil.estimation.gcas.candidates import (
    SECOND_ECHO_HOPS,
    CandidateCells,
    EveryEcho,
    StrongestEcho,
    second_echo_rows,
)
from hil.estimation.gcas.exact import ExactHistory
from hil.estimation.gcas.front_end import FrontEnd
from hil.estimation.gcas.options import check_coarse_step
from hil.estimation.gcas.still_codewords import StillCodewords
from hil.estimation.gcas.threshold import (
    NOISE_STRIDE,
    Cfar,
    Peak,
    median_spread,
    peaks_of,
    seconds_marked,
    threshold_peaks,
    window_means,
)
from hil.estimation.kernels import (
    fine_doppler,
    fine_keep,
    fine_pick,
    fine_recentre,
    first_possible_cells,
    masked_peak_cells,
    peak_cells,
    peak_indices,
    runner_up_pairs,
)
from hil.estimation.row_buffer import RowBuffer

#: Peaks remembered to drop a repeat of one (:meth:`TwoStageSearch._distinct`): more than
#: the echoes one hop can hold.
RECENT_PEAKS = 32
#: Lobes of other echoes across the hypotheses that stage 1 measures beside the strongest's
#: shortlist, per block (:class:`~hil.estimation.coarse_search.CoarseSearch`).
COARSE_PEAKS = 8
#: Margin over a sidelobe's envelope of the coarse statistic (:func:`doppler_leak`): the
#: ripple of two echoes' beat and of noise.
LEAK_MARGIN = 2.0
#: Times the two-stage search moves its fine window onto an edge peak, at most.
RECENTRE_STEPS = 4
#: A hypothesis and its two neighbours on the Doppler grid (offsets, shape (1, 3)).
_NEIGHBOURS = np.arange(-1, 2, dtype=np.int64)[None, :]


def doppler_leak(fe: FrontEnd) -> NDArray[np.float64]:
    """How much of one echo's coarse statistic reaches a hypothesis ``Δd`` steps from the one
    it peaks at, at most, times :data:`LEAK_MARGIN` (shape ``(D,)``, by ``Δd``): a cell below
    that beside a stronger one is its Doppler sidelobe, not another echo.

    A tone received ``x`` Doppler cells (``c/(2 f_c T_h)``) off a correlator's gives
    ``sinc²(x)`` of its power, at most ``1/(π x)²`` beyond the main lobe; a window across two
    hops holds two parts, each within that envelope, while the echo's own statistic there is
    at least half its peak: ``4/(π x)²``. ``x`` counts from half a step inside (the echo lies
    between hypotheses); within the main lobe (``x < 1``) nothing is called a sidelobe (the
    search's ±lobe maximum decides there).
    """
    step = fe.grid.speed_step_mps
    cell = fe.sound_speed_mps / (2.0 * fe.center_hz * fe.hop_s)
    dd = np.arange(fe.grid.size, dtype=np.float64)
    x = np.maximum(dd - 0.5, 0.0) * step / cell
    leak = np.where(x >= 1.0, LEAK_MARGIN / (np.pi * np.maximum(x, 1.0)) ** 2, 0.0)
    return np.ascontiguousarray(leak)


class TwoStageSearch:
    """:class:`~hil.estimation.gcas.search.SearchStrategy` with coarse block correlators
    (stage 1) and exact codeword sums around their candidates (stage 2); keeps the complex
    baseband history, from which every exact unit correlator is recomputed on demand."""

    def __init__(
        self, fe: FrontEnd, cfar: Cfar, *, coherent: bool, runner_up_ratio: float,
        coarse_step: int, every_echo: bool,
    ) -> None:  # fmt: skip
        self._fe, self._cfar = fe, cfar
        self._coherent = coherent
        self._runner_up_ratio = runner_up_ratio
        b = self._B = check_coarse_step(coarse_step, fe.n_min)
        self._q = np.maximum(1, np.round(fe.grid.exact_lengths / b)).astype(np.int64)  # (D,)
        self._c_shift = self._coarse_shift()
        self._hc = max(1, fe.half_width // b)
        self._min_shift = int(np.min(self._c_shift))
        self.fine_half = fe.search_half + 6
        #: Peaks of one echo met from two candidates lie within this many samples.
        self.search_half_window = fe.search_half
        reach = int(np.max(self._c_shift)) + self.fine_half  # samples past the block start
        self._c_lookahead = self._hc + max(0, -(-reach // b))
        self.coarse = CoarseSearch(
            fe.fs_bb,
            fe.nu,
            self._q,
            block=b,
            m_hops=fe.m_hops,
            hop_blocks=fe.grid.exact_lengths / b,
            cell_weights=fe.tone_w,
            hyp_weights=fe.grid.weights,
            noise_every=max(1, NOISE_STRIDE // b),
            noise_scale=fe.grid.lengths / (self._q * b),
            peak_lobe=fe.lobe_hypotheses,
            peak_count=COARSE_PEAKS,
        )
        c_keep = (fe.cfar_window + 2 * fe.n_max + 4) // b + 4
        self._cs_ring = RowBuffer(c_keep, (), np.float64)
        self._cd_ring = RowBuffer(c_keep, (), np.int64)  # d̂ (the time–codeword map)
        self._cn_ring = RowBuffer(c_keep, (), np.float64)
        self._ca_ring = RowBuffer(c_keep, (fe.grid.size,), np.float64)  # h_d Acc_d per block
        #: The candidates' rule (:mod:`hil.estimation.gcas.candidates`).
        inner = int(round(SECOND_ECHO_HOPS * fe.n_min / b))
        self.candidates: CandidateCells = (
            EveryEcho(self._hc, fe.lobe_hypotheses, doppler_leak(fe), inner, second_echo_rows(fe))
            if every_echo
            else StrongestEcho(self._hc, fe.lobe_hypotheses, fe.grid.size)
        )
        y_keep = (
            int(fe.lags.max()) + fe.n_max + 2 * self.fine_half + (self._c_lookahead + 2) * b
            + abs(int(np.min(self._c_shift))) + RECENTRE_STEPS * self.fine_half + 8
        )  # fmt: skip
        #: A peak comes out from the stage-2 history: at most this far behind the newest
        #: baseband sample (:attr:`SearchStrategy.decision_lag`).
        self.decision_lag = y_keep
        #: The baseband history and its exact correlators (stage 2).
        self.exact = ExactHistory(fe, keep=y_keep, block=b, widest=2 * self.fine_half + 1)
        self._hyp_w = self.exact.hyp_w
        #: With the refinement, a still candidate's second codeword too
        #: (:mod:`hil.estimation.gcas.still_codewords`).
        #: Hypotheses at which two echoes of one speed may tie in a window
        #: (:func:`second_echo_rows`; none without the refinement, which tells them apart).
        self._pair_rows = (
            second_echo_rows(fe) if every_echo else np.zeros(fe.grid.size, dtype=np.bool_)
        )
        self._beside = StillCodewords(fe, runner_up_ratio, self._pair_rows) if every_echo else None
        self.reset(0)

    def _coarse_shift(self) -> NDArray[np.int64]:
        """Coarse block → fine sample of a candidate, per hypothesis (baseband samples).

        The coarse window (``Q_d·B`` samples) peaks ``(Q_d·B − N_d)/2`` later than the exact
        one, and term ``m`` of the coarse comb sits ``ℓ_{d,m} − B·lag_m`` samples off the exact
        one (``lag_m`` rounded in blocks, as stage 1 does), which moves its peak by their mean.
        """
        fe, b = self._fe, self._B
        hop_blocks = fe.grid.exact_lengths / b
        lag_blocks = np.round(np.arange(fe.m_hops)[None, :] * hop_blocks[:, None])  # (D, M)
        shift: NDArray[np.int64] = np.round(
            b
            - 1
            - 0.5 * (self._q * b - fe.grid.lengths)
            + np.mean(fe.lags - b * lag_blocks, axis=1)
        ).astype(np.int64)
        return shift

    def reset(self, b0: int) -> None:
        self.coarse.reset(b0)
        c0 = self.coarse.next_block
        for ring in (self._cs_ring, self._cd_ring, self._cn_ring, self._ca_ring):
            ring.reset(c0)
        self.exact.reset(b0)
        self._origin = b0
        self._c_origin = c0
        self._c_valid_from = -(-(b0 + self._fe.settle) // self._B) + 1
        self._det_next = c0
        #: The latest peaks given out (:meth:`_distinct`): codeword, peak sample, hypothesis.
        self._recent: deque[tuple[int, int, int]] = deque(maxlen=RECENT_PEAKS)

    # ------------------------------------------------------------------ streaming
    def process(self, y: NDArray[np.complex128]) -> list[Peak]:
        """Stage 1 on the new baseband samples ``y``; stage 2 at the decided candidates."""
        self.exact.append(y)
        blocks = self.coarse.process(y)
        if blocks.stat.shape[0]:
            c0 = blocks.first_block
            self._cs_ring.append(blocks.stat, c0)
            self._cd_ring.append(blocks.d_hat, c0)
            self._cn_ring.append(blocks.noise, c0)
            self._ca_ring.append(blocks.acc, c0)
        return self.flush()

    def flush(self) -> list[Peak]:
        """Decide the coarse candidates whose look-ahead has arrived (blocks below the next
        block minus the look-ahead); exact codeword sums around each (stage 2)."""
        return self._decide_blocks(self._cs_ring.next_index - self._hc)

    def next_decision_index(self, samples_seen: int) -> int:
        return max(self._decision_input(), samples_seen)

    def _decision_input(self) -> int:
        """The next decision index from the coarse blocks completed so far.

        A candidate is a coarse peak cell (greater than the cells in the ``hc`` blocks before
        it and the hypotheses within one Doppler cell, not smaller than those after), so the
        earliest block that can still hold one is the first undecided block with a cell
        greater than its predecessors and not exceeded by a cell already known after it (or
        the next block to come). It is decided once the ``hc`` blocks after it are complete
        and its fine window (which ends ``c_shift`` of its hypotheses, at least the smallest
        of the cells that can still peak there, plus ``2·fine_half`` samples past its start)
        has arrived; baseband sample ``k`` exists once input sample ``k·R`` has.
        """
        next_block = self.coarse.next_block
        h = self._hc
        lo = self._det_next
        first = max(lo - h, self._c_origin)
        shift = self._min_shift
        if next_block > lo:
            s = np.array(self._ca_ring.span(first, next_block), dtype=np.float64)
            s[: max(0, self._c_valid_from - first)] = -np.inf
            cand, sets = self.candidates.first_possible(s, lo - first, next_block - first)
            cand += first
            if cand < next_block:  # its hypotheses are known: the earliest of their windows
                shift = int(self._c_shift[sets].max(axis=1).min())
        else:
            cand = max(lo, next_block)
        late = cand * self._B + shift + 2 * self.fine_half
        need_bb = max((cand + h + 1) * self._B - 1, late)
        return need_bb * self._fe.baseband.decimation + 1

    def _decide_blocks(self, stop: int) -> list[Peak]:
        """Stage 2 for the coarse candidate cells in blocks ``< stop``."""
        lo = self._det_next
        if stop <= lo:
            return []
        first = max(lo - self._hc, self._c_origin)
        acc = np.array(self._ca_ring.span(first, min(stop + self._hc, self._ca_ring.next_index)))
        acc[: max(0, self._c_valid_from - first)] = -np.inf
        rows, sets, second = self.candidates.cells(acc, lo - first, stop - first)
        cand_b = rows + first
        # A candidate waits until its fine window has arrived (its shift depends on d).
        late = cand_b * self._B + self._c_shift[sets].max(axis=1) + 2 * self.fine_half
        wait = np.flatnonzero(late >= self.exact.next_index)
        if wait.size:
            stop = int(cand_b[wait[0]])
            keep = cand_b < stop
            cand_b, sets, second = cand_b[keep], sets[keep], second[keep]
        self._det_next = stop
        if cand_b.size == 0:
            return []
        peaks = self._fine_stage(cand_b, sets, second)
        return self._distinct(peaks)

    def _distinct(self, peaks: list[Peak]) -> list[Peak]:
        """``peaks`` without those that repeat an earlier one: two candidate cells of one echo
        (a block's best with its runner-up, neighbours across the lobe) whose stage 2 met on
        the same codeword within the fine window and one Doppler cell. Decided in candidate
        order, so any chunking keeps the same peaks. A second echo's peak
        (:attr:`~hil.estimation.gcas.threshold.Peak.second`, decided only beside a partner
        or two echoes measured at its speed) never hides a later one: its cell is often the
        shoulder of the greater maximum beside it, whose stage 2 meets that maximum's own
        peak."""
        out: list[Peak] = []
        w, hd, recent = self.search_half_window, self.candidates.lobe, self._recent
        for p in peaks:
            word, n_star, d0 = p.codeword, p.n_star, p.d0
            for q_word, q_n, q_d in recent:  # a plain loop: some 30 peaks per candidate
                if q_word == word and abs(q_n - n_star) <= w and abs(q_d - d0) <= hd:
                    break
            else:
                out.append(p)
                if not p.second:
                    recent.append((word, n_star, d0))
        return out

    # ------------------------------------------------------------------ stage 2
    def _fine_stage(
        self, cand_b: NDArray[np.int64], sets: NDArray[np.int64], second: NDArray[np.int8]
    ) -> list[Peak]:
        """Stage 2: exact codeword sums around the coarse candidate cells: blocks ``cand_b``
        (shape ``(C,)``), each with the hypotheses ``sets`` (shape ``(C, H)``, its own first)
        of which the best by the exact sums is kept.

        The sums come from :func:`~hil.estimation.kernels.codeword_sums`, everything between
        them from small compiled kernels (:func:`~hil.estimation.kernels.fine_pick`,
        ``fine_recentre``, ``fine_keep``, ``fine_doppler``): written in NumPy, that work is
        some 60 small array calls per estimate, whose overhead would dominate the call that
        emits it. The sums stay a kernel of their own because a kernel that calls them
        inside takes several times as long to compile on first use (about 30 s).
        :meth:`_fine_stage_reference` is the NumPy formulation; tests check that both give
        the same estimates, bit for bit.
        """
        w = self.fine_half
        pair = np.ascontiguousarray(sets, dtype=np.int64)
        centres = np.empty(pair.shape, dtype=np.int64)
        np.add(cand_b[:, None] * self._B, self._c_shift[pair], out=centres)
        a2 = self.exact.sums(centres, pair, w, prune=True)
        d0, centre, a, s_win, i_pk, edges = fine_pick(
            a2, pair, centres, self._hyp_w, w, RECENTRE_STEPS > 0
        )
        for it in range(RECENTRE_STEPS):
            if edges.size == 0:
                break
            sums = self.exact.sums(centre[edges], d0[edges, None], w)
            edges = fine_recentre(a, sums, edges, s_win, i_pk, centre, w, it + 1 < RECENTRE_STEPS)
        n_pk = centre - w + i_pk
        stat = self._cell_statistic(cand_b, sets[:, 0])
        peak = s_win[np.arange(cand_b.shape[0]), i_pk]
        mean, thr, hit = self._cfar.test(n_pk, peak, stat, self)
        if hit.size == 0:
            return []
        keep, peak, word, ratio, dn, sides = fine_keep(
            hit, a, s_win, i_pk, d0, self._fe.grid.size, w, float(self._runner_up_ratio),
            self._pair_rows,
        )  # fmt: skip
        if keep.size == 0:
            return []
        kept = hit[keep]
        side = self.exact.sums(n_pk[kept], sides, 0)
        dd = fine_doppler(side, a, kept, i_pk, word, d0, sides)
        peaks = peaks_of(n_pk[kept], peak, word, ratio, dn, d0[kept], dd, mean[kept], thr[kept])
        peaks = seconds_marked(peaks, second[kept])
        if self._beside is None:
            return peaks
        return self._beside.add_columns(
            peaks, a[kept], centre[kept] - w, d0[kept], word, peak, mean[kept], thr[kept]
        )

    def _fine_stage_reference(
        self, cand_b: NDArray[np.int64], sets: NDArray[np.int64], second: NDArray[np.int8]
    ) -> list[Peak]:
        """:meth:`_fine_stage` as NumPy expressions (the reference the compiled path is
        tested against)."""
        w = self.fine_half
        centres = cand_b[:, None] * self._B + self._c_shift[sets]
        a2 = self.exact.sums(centres, sets, w, prune=True)  # (C, H, 2w + 1, J)
        # Weighted as stage 1 ranks them (the reverberation band's weights); a hypothesis
        # pruned whole (−inf) cannot win, even at weight 0.
        best = a2.max(axis=(2, 3))
        score = np.where(np.isfinite(best), best * self._hyp_w[sets], -np.inf)
        pick = np.argmax(score, axis=1)
        r = np.arange(cand_b.shape[0])
        d0, centre, a = sets[r, pick], centres[r, pick], a2[r, pick]  # a: (C, 2w + 1, J)
        cand_d = sets[:, 0]
        # A peak on the window's edge lies outside it (early in the stream the coarse comb
        # is not yet full): move the window onto that edge, a few times at most (later only
        # once: the look-ahead covers one window more; earlier is in the history).
        for it in range(RECENTRE_STEPS):
            ip = np.argmax(a.max(axis=2), axis=1)
            edge = np.flatnonzero((ip == 0) | ((ip == 2 * w) & (it == 0)))
            if edge.size == 0:
                break
            centre[edge] += ip[edge] - w
            a[edge] = self.exact.sums(centre[edge], d0[edge, None], w)[:, 0]
        dset = np.minimum(np.maximum(d0[:, None] + _NEIGHBOURS, 0), self._fe.grid.size - 1)

        def sides(hit: NDArray[np.int64], n_pk: NDArray[np.int64]) -> NDArray[np.float64]:
            return self.exact.sums(n_pk, dset[hit][:, [0, 2]], 0)[:, :, 0]

        tested = self._cell_statistic(cand_b, cand_d)

        def test(
            n_pk: NDArray[np.int64], peak: NDArray[np.float64]
        ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
            return self._cfar.test(n_pk, peak, tested, self)

        return threshold_peaks(
            centre, w, dset, a, sides, test, self._runner_up_ratio, self._beside, second,
            self._pair_rows,
        )  # fmt: skip

    def _cell_statistic(
        self, cand_b: NDArray[np.int64], cand_d: NDArray[np.int64]
    ) -> NDArray[np.float64] | None:
        """The coarse statistic of each candidate cell (its own hypothesis, not its block's
        best: another echo may hold that) for the ``"statistic"`` CFAR; None in bank mode."""
        if self._cfar.mode != "statistic":
            return None
        stat: NDArray[np.float64] = self._ca_ring.rows(cand_b)[np.arange(cand_b.size), cand_d]
        return stat

    # ------------------------------------------------------------------ CFAR history
    def noise_floor(self, n_pk: NDArray[np.int64]) -> NDArray[np.float64]:
        """μ_U over the trailing CFAR window of each peak sample ``n_pk``, from the coarse
        noise floor on blocks (the peak's block may not be complete yet)."""
        fe, b, ring = self._fe, self._B, self._cn_ring
        lo = np.maximum(n_pk - fe.cfar_window, self._origin + fe.n_max)
        hi = np.minimum(n_pk // b, ring.next_index - 1)
        lo = np.minimum(np.maximum(lo // b, self._c_origin), hi)
        return window_means(ring, lo, hi, fe.cfar_window // b + 2)

    def statistic_moments(self, n_star: int) -> tuple[float, float]:
        """Median and MAD-based std of the coarse statistic over the trailing CFAR window
        that ends one hop before ``n_star`` (in blocks)."""
        b = self._B
        w, guard, n_star = self._fe.cfar_window // b, -(-self._fe.n_max // b), n_star // b
        lo = max(n_star - guard - w, self._c_valid_from)
        return median_spread(self._cs_ring, lo, n_star - guard)

    # ------------------------------------------------------------------ sums
    def terms(self, idx: NDArray[np.int64], dcol: NDArray[np.int64]) -> NDArray[Any]:
        return self.exact.terms(idx, dcol, self._coherent)

    def unit_values(self, n_star: int, d0: int, tone: NDArray[np.int64]) -> NDArray[np.complex128]:
        return self.exact.unit_values(n_star, d0, tone)

    def map_hypotheses(self, count: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        stop = self.exact.next_index
        idx = np.arange(stop - count, stop, dtype=np.int64)
        if self._cd_ring.next_index > self._c_origin:
            # np.clip's bounds as two ufuncs (integers: the same values, without its wrapper).
            blk = idx // self._B
            np.maximum(blk, self._c_origin, out=blk)
            np.minimum(blk, self._cd_ring.next_index - 1, out=blk)
            d_map: NDArray[np.int64] = self._cd_ring.rows(blk)
        else:
            d_map = np.zeros(idx.shape[0], dtype=np.int64)
        return idx, d_map

    def retained(self, count: int) -> NDArray[np.int64]:
        return self.exact.retained(count, self._origin)

    # ------------------------------------------------------------------ warm-up
    def warm_up(self) -> None:
        """Every stage-2 kernel on one made-up candidate, and the exact windows that the
        coherent readout and the time–codeword map read (also when noncoherent)."""
        peak_indices(np.zeros(3), 1, 0, 3)
        peak_cells(np.zeros((3, 2)), 1, 1, 0, 3, np.zeros(2))
        first_possible_cells(np.zeros((3, 2)), 1, 1, 0, 3, np.zeros(2))
        masked_peak_cells(np.zeros((3, 2)), 1, 1, 0, 1, 0, 3, 0.0, 1.0)
        runner_up_pairs(np.zeros((1, 3)), np.zeros(1, dtype=np.int64))
        one = np.zeros((1, 1), dtype=np.int64)
        w = self.fine_half
        self.exact.sums(one[:, 0], one, w, prune=True)
        two = np.zeros((1, 2), dtype=np.int64)
        a2 = self.exact.sums(two, two, w, prune=True)
        d0, centre, a, s_win, i_pk, edges = fine_pick(a2, two, two, self._hyp_w, w, True)
        sums = self.exact.sums(centre[edges], d0[edges, None], w)
        fine_recentre(a, sums, edges, s_win, i_pk, centre, w, True)
        _, _, word, _, _, sides = fine_keep(
            one[0], a, s_win, i_pk, d0, self._fe.grid.size, w, 1.0, self._pair_rows
        )
        side = self.exact.sums(one[0], sides, 0)
        fine_doppler(side, a, one[0], i_pk, word, d0, sides)
        self.exact.windows(one[:, 0], one[:, 0], 1)
        self.exact.load_value_kernel()
        if self._beside is not None:
            self._beside.load_kernel()
