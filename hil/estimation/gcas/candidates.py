"""Which cells of stage 1 become candidates of the two-stage search (time blocks × Doppler
hypotheses of the coarse statistic ``h_d Acc_d[b]``), and which hypotheses stage 2 compares
for each.

:class:`EveryEcho` (with the refinement, the default): every local maximum over ``±hc``
blocks and one Doppler resolution cell that stands above the Doppler sidelobes of its row
(:func:`~hil.estimation.gcas.search_two_stage.doppler_leak`): several echoes per hop. Their
ghosts (tones read as the neighbouring tone at another speed) and the sidelobes left become
candidates too; the refinement's likelihood test tells them from echoes
(:mod:`hil.estimation.refine`).

:class:`StrongestEcho` (without it: the detector alone cannot tell an echo from a ghost):
the strongest cell over ``±hc`` blocks and every hypothesis, compared in stage 2 with the
block's runner-up more than one step away (the codeword sums tell a hypothesis from its
ghost, the group statistic cannot): one echo per hop.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from hil.estimation.kernels import first_possible_cells, peak_cells


class CandidateCells(Protocol):
    """A rule of :class:`~hil.estimation.gcas.search_two_stage.TwoStageSearch` for its
    candidates; ``acc`` rows are blocks (shape ``(n, D)``, −inf off the shortlist)."""

    #: Hypotheses within which two peaks of one codeword are one echo (:meth:`TwoStageSearch.
    #: _distinct`).
    lobe: int

    def cells(
        self, acc: NDArray[np.float64], lo: int, hi: int
    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Candidates in rows ``[lo, hi)``: their rows (shape ``(C,)``) and the hypotheses
        stage 2 compares for each (shape ``(C, H)``, the cell's own first)."""
        ...

    def first_possible(
        self, acc: NDArray[np.float64], lo: int, hi: int
    ) -> tuple[int, NDArray[np.int64]]:
        """The first row in ``[lo, hi)`` that can still hold a candidate once the rows from
        ``hi`` on arrive (``hi`` if none) and the hypothesis sets of its possible cells."""
        ...


class EveryEcho:
    """Every echo's cell (module docstring): ``hc`` blocks, ``lobe`` hypotheses (one Doppler
    resolution cell), ``leak`` the sidelobe bound by hypothesis distance (shape ``(D,)``)."""

    def __init__(self, hc: int, lobe: int, leak: NDArray[np.float64]) -> None:
        self.hc, self.lobe, self.leak = hc, lobe, np.ascontiguousarray(leak)

    def cells(
        self, acc: NDArray[np.float64], lo: int, hi: int
    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        rows, cols = peak_cells(acc, self.hc, self.lobe, lo, hi, self.leak)
        return rows, np.ascontiguousarray(cols[:, None])

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
    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        rows, cols = peak_cells(acc, self.hc, self._all, lo, hi, self._none)
        return rows, self._with_runner_up(acc[rows], cols)

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
