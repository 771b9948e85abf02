"""Which cells of stage 1 become candidates of the two-stage search (time blocks × Doppler
hypotheses of the coarse statistic ``h_d Acc_d[b]``), and which hypotheses stage 2 compares
for each.

:class:`EveryEcho` (with the refinement, the default): every local maximum over ``±hc``
blocks and one Doppler resolution cell that stands above the Doppler sidelobes of its row
(:func:`~hil.estimation.gcas.search_two_stage.doppler_leak`): several echoes per hop. Their
ghosts (tones read as the neighbouring tone at another speed) and the sidelobes left become
candidates too; the refinement's likelihood test tells them from echoes
(:mod:`hil.estimation.refine`).

Two echoes of one Doppler cell (a formation) put two peaks in that cell's row every hop, and
any two boundaries of one row lie within half a hop of each other: the weaker is never the
maximum over ``±hc`` blocks. So a second maximum is a candidate too where it is the maximum
over ``±inner`` blocks (:data:`SECOND_ECHO_HOPS` of a hop: one echo's row falls from its
boundary to the middle of the hop with no maximum of its own), reaches :data:`SECOND_LEVEL`
of the greater one, and lies in a row away from the reverberation band's edges and the
span's (``second_rows``: there one echo's leak into a mismatched Doppler cell ripples along
the row) and outside the still reverberation's cells. Its peak is decided only beside a
partner or two echoes measured at its speed, or beside an echo measured at a nearby speed
(:meth:`~hil.estimation.refine.CoherentRefiner.beside_known`: two echoes within a Doppler
cell of a hop of each other share the detector's cell, and the weaker one's boundary is only
a second maximum of its row), and its fit and the other's need each other taken out (the
refinement's partners, :data:`~hil.estimation.refine.PARTNER_COHERENCE`). Measured on att at
0 dB (two closing targets at 10 m/s, independent synthesis): per-target detection 3 m apart
0.26 / 0.28 before, 1.0 / 1.0 with both; 10.1 m apart 0.46 / 0.54 and 1.0 / 1.0. Echoes
whose boundaries lie within about a tenth of a hop of each other (modulo the hop) are one
peak of the coarse row and stay one candidate.

:class:`StrongestEcho` (without it: the detector alone cannot tell an echo from a ghost):
the strongest cell over ``±hc`` blocks and every hypothesis, compared in stage 2 with the
block's runner-up more than one step away (the codeword sums tell a hypothesis from its
ghost, the group statistic cannot): one echo per hop.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from hil.estimation.gcas.front_end import FrontEnd
from hil.estimation.kernels import first_possible_cells, peak_cells, second_peak_cells
from hil.estimation.reverb_band import doppler_resolution_mps

#: Where a second maximum of one Doppler row is looked for (:class:`EveryEcho`): from this
#: fraction of a hop beside a greater one.
SECOND_ECHO_HOPS = 0.1
#: What a second maximum must reach of the greater one within ``±hc`` blocks: two echoes of
#: one level read 0.97-1.0 of each other; one echo's row halfway between its boundaries
#: 0.25-0.5 of its peak.
SECOND_LEVEL = 0.6


class CandidateCells(Protocol):
    """A rule of :class:`~hil.estimation.gcas.search_two_stage.TwoStageSearch` for its
    candidates; ``acc`` rows are blocks (shape ``(n, D)``, −inf off the shortlist)."""

    #: Hypotheses within which two peaks of one codeword are one echo (:meth:`TwoStageSearch.
    #: _distinct`).
    lobe: int

    def cells(
        self, acc: NDArray[np.float64], lo: int, hi: int
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
        """Candidates in rows ``[lo, hi)``: their rows (shape ``(C,)``), the hypotheses
        stage 2 compares for each (shape ``(C, H)``, the cell's own first) and whether each is
        a second maximum of its row (shape ``(C,)``: decided only beside a partner or two
        echoes measured at its speed,
        :meth:`hil.estimation.refine.CoherentRefiner.beside_known`)."""
        ...

    def first_possible(
        self, acc: NDArray[np.float64], lo: int, hi: int
    ) -> tuple[int, NDArray[np.int64]]:
        """The first row in ``[lo, hi)`` that can still hold a candidate once the rows from
        ``hi`` on arrive (``hi`` if none) and the hypothesis sets of its possible cells."""
        ...


class EveryEcho:
    """Every echo's cell (module docstring): ``hc`` blocks, ``lobe`` hypotheses (one Doppler
    resolution cell), ``leak`` the sidelobe bound by hypothesis distance (shape ``(D,)``);
    second maxima over ``±inner`` blocks in the hypotheses ``second_rows`` (shape ``(D,)``,
    bool)."""

    def __init__(
        self, hc: int, lobe: int, leak: NDArray[np.float64], inner: int,
        second_rows: NDArray[np.bool_],
    ) -> None:  # fmt: skip
        self.hc, self.lobe, self.leak = hc, lobe, np.ascontiguousarray(leak)
        self.inner = min(max(1, int(inner)), hc)
        self.second_rows = np.asarray(second_rows, dtype=np.bool_)

    def cells(
        self, acc: NDArray[np.float64], lo: int, hi: int
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
        rows, cols = peak_cells(acc, self.hc, self.lobe, lo, hi, self.leak)
        second = np.zeros(rows.shape[0], dtype=np.bool_)
        if self.inner < self.hc:
            r2, c2 = second_peak_cells(
                acc, self.hc, self.inner, self.lobe, lo, hi, self.leak, SECOND_LEVEL
            )
            keep = self.second_rows[c2]
            if keep.any():
                # One row-major order for both (the decisions' order, whatever the blocks).
                rows, cols = np.concatenate([rows, r2[keep]]), np.concatenate([cols, c2[keep]])
                second = np.concatenate([second, np.ones(int(keep.sum()), dtype=np.bool_)])
                order = np.lexsort((cols, rows))
                rows, cols, second = rows[order], cols[order], second[order]
        return rows, np.ascontiguousarray(cols[:, None]), second

    def first_possible(
        self, acc: NDArray[np.float64], lo: int, hi: int
    ) -> tuple[int, NDArray[np.int64]]:
        row, mask = first_possible_cells(acc, self.hc, self.lobe, lo, hi, self.leak)
        return int(row), np.flatnonzero(mask)[:, None]


class StrongestEcho:
    """The strongest cell per ``±hc`` blocks with its block's runner-up (module docstring);
    ``lobe`` as :class:`EveryEcho`'s (for repeats only)."""

    def __init__(self, hc: int, lobe: int, n_hyp: int) -> None:
        self.hc, self.lobe = hc, lobe
        self._all = n_hyp
        self._none = np.zeros(n_hyp)

    def cells(
        self, acc: NDArray[np.float64], lo: int, hi: int
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
        rows, cols = peak_cells(acc, self.hc, self._all, lo, hi, self._none)
        return rows, self._with_runner_up(acc[rows], cols), np.zeros(rows.shape[0], np.bool_)

    def first_possible(
        self, acc: NDArray[np.float64], lo: int, hi: int
    ) -> tuple[int, NDArray[np.int64]]:
        row, mask = first_possible_cells(acc, self.hc, self._all, lo, hi, self._none)
        cols = np.flatnonzero(mask)
        if cols.size == 0:
            return int(row), np.zeros((0, 2), dtype=np.int64)
        return int(row), self._with_runner_up(np.repeat(acc[row : row + 1], cols.size, 0), cols)

    @staticmethod
    def _with_runner_up(rows: NDArray[np.float64], cols: NDArray[np.int64]) -> NDArray[np.int64]:
        """``(d, d₂)`` per cell: ``d₂`` its row's best hypothesis more than one step from
        ``d`` (``d`` itself where there is none), shape ``(C, 2)``."""
        far = np.abs(np.arange(rows.shape[1])[None, :] - cols[:, None]) > 1
        masked = np.where(far, rows, -np.inf)
        second = np.argmax(masked, axis=1)
        found = np.isfinite(masked[np.arange(cols.size), second])
        pairs = np.empty((cols.size, 2), dtype=np.int64)
        pairs[:, 0] = cols
        pairs[:, 1] = np.where(found, second, cols)
        return pairs


def second_echo_rows(fe: FrontEnd) -> NDArray[np.bool_]:
    """The hypotheses whose rows are searched for a second maximum (shape ``(D,)``,
    :class:`EveryEcho`): searched at full weight, and more than
    one Doppler resolution cell and a step from a refused or down-weighted hypothesis and from
    the span's ends, where one echo's leak into a mismatched cell ripples along the row; and
    not in the still reverberation's cells (with the band off, the lone scatterers of sparse
    reverberation would each be a second echo beside the last)."""
    still = np.abs(fe.grid.speeds_mps) < doppler_resolution_mps(
        fe.tones_hz, fe.hop_s, fe.sound_speed_mps
    )
    bad = (fe.grid.weights < 1.0) | np.asarray(fe.refused_hypotheses, dtype=np.bool_) | still
    bad[0] = bad[-1] = True
    reach = np.ones(2 * (fe.lobe_hypotheses + 1) + 1)
    rows: NDArray[np.bool_] = np.convolve(bad.astype(np.float64), reach, mode="same") == 0
    return rows
