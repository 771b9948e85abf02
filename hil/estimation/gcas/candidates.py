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

An echo 3-6 dB below another 1-1.6 Doppler cells of a hop away (2.6-4 m/s on att, closer
than the ``±lobe`` hypotheses of that one's cell) is no maximum over ``±lobe``: the greater
echo's main lobe holds a cell of the window at every block. Where its boundary is a maximum
of its own over ``±hc`` blocks and ``±``:data:`MASKED_OWN` hypothesis, and the greater cell
of the window lies :data:`MASKED_APART` blocks or more from it (the greater echo's Doppler
response peaks at that echo's own boundary, so its shoulders and sidelobes are not such
peaks), it is a candidate too (:func:`~hil.estimation.kernels.masked_peak_cells`, marked
:data:`~hil.estimation.gcas.threshold.MASKED_PEAK`), from :data:`MASKED_LEVEL` of the
greater cell up to :data:`SECOND_LEVEL`, in ``second_rows``. It is decided like a second
maximum, beside the measured greater echo (``NEIGHBOUR_CELLS``), and not where an echo
measured at its speed has its boundary (that echo is followed where its fit puts it:
:meth:`~hil.estimation.refine.CoherentRefiner.followed_near`). Measured on att at 0 / -10
dB (independent synthesis, the second 5 dB weaker, 2 s): 3.3 m/s apart 0.0 / 0.0 -> 0.66 /
0.94, 4 m/s 0.0 / 0.91 -> 1.0 / 1.0; a lone target: 3.5 more candidates per second at 0 dB.

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
from hil.estimation.gcas.threshold import MASKED_PEAK, SECOND_MAX
from hil.estimation.kernels import (
    first_possible_cells,
    masked_peak_cells,
    peak_cells,
    runner_up_pairs,
    second_peak_cells,
)
from hil.estimation.reverb_band import doppler_resolution_mps

#: Where a second maximum of one Doppler row is looked for (:class:`EveryEcho`): from this
#: fraction of a hop beside a greater one.
SECOND_ECHO_HOPS = 0.1
#: What a second maximum must reach of the greater one within ``±hc`` blocks: two echoes of
#: one level read 0.97-1.0 of each other; one echo's row halfway between its boundaries
#: 0.25-0.5 of its peak.
SECOND_LEVEL = 0.6
#: A masked peak (:class:`EveryEcho`): the maximum of its row over this many hypotheses
#: either side and of its column over ``±hc`` blocks, ...
MASKED_OWN = 1
#: ... whose greater cell within the lobe lies at least this many blocks away (a stronger
#: echo's Doppler response peaks at that echo's own boundary, within a block of it) ...
MASKED_APART = 2
#: ... and which reaches this fraction of that greater cell (an echo 10 dB below it reads
#: 0.1), but not :data:`SECOND_LEVEL`: there a local maximum beside a greater one is noise's
#: (measured on att at 0 and -10 dB, one target: 0.67-1.0 of the greater).
MASKED_LEVEL = 0.08


class CandidateCells(Protocol):
    """A rule of :class:`~hil.estimation.gcas.search_two_stage.TwoStageSearch` for its
    candidates; ``acc`` rows are blocks (shape ``(n, D)``, −inf off the shortlist)."""

    #: Hypotheses within which two peaks of one codeword are one echo (:meth:`TwoStageSearch.
    #: _distinct`).
    lobe: int

    def cells(
        self, acc: NDArray[np.float64], lo: int, hi: int
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int8]]:
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
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int8]]:
        rows, cols = peak_cells(acc, self.hc, self.lobe, lo, hi, self.leak)
        n_cols = acc.shape[1]
        r2, c2 = masked_peak_cells(
            acc, self.hc, self.lobe, MASKED_OWN, MASKED_APART, lo, hi, MASKED_LEVEL,
            SECOND_LEVEL,
        )  # fmt: skip
        kind2 = np.full(r2.shape[0], MASKED_PEAK, dtype=np.int8)
        if self.inner < self.hc:
            r3, c3 = second_peak_cells(
                acc, self.hc, self.inner, self.lobe, lo, hi, self.leak, SECOND_LEVEL
            )
            r2, c2 = np.concatenate([r3, r2]), np.concatenate([c3, c2])
            kind2 = np.concatenate([np.full(r3.shape[0], SECOND_MAX, dtype=np.int8), kind2])
        keep = self.second_rows[c2]
        second = np.zeros(rows.shape[0], dtype=np.int8)
        if not keep.any():  # the usual block: no second maximum where one is looked for
            return rows, np.ascontiguousarray(cols[:, None]), second
        # A cell both rules give is one candidate, a second maximum.
        key, first = np.unique(r2[keep] * n_cols + c2[keep], return_index=True)
        if key.size:
            # One row-major order for all (the decisions' order, whatever the blocks).
            rows = np.concatenate([rows, key // n_cols])
            cols = np.concatenate([cols, key % n_cols])
            second = np.concatenate([second, kind2[keep][first]])
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
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int8]]:
        rows, cols = peak_cells(acc, self.hc, self._all, lo, hi, self._none)
        return rows, self._with_runner_up(acc[rows], cols), np.zeros(rows.shape[0], np.int8)

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
        ``d`` (``d`` itself where there is none), shape ``(C, 2)``
        (:func:`~hil.estimation.kernels.runner_up_pairs`)."""
        return runner_up_pairs(
            np.ascontiguousarray(rows, dtype=np.float64), np.ascontiguousarray(cols, dtype=np.int64)
        )


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


def new_pair_rows(fe: FrontEnd) -> NDArray[np.bool_]:
    """The hypotheses where a refused fit is first tried as two echoes of one speed (shape
    ``(D,)``; :mod:`hil.estimation.refine_pair`): :func:`second_echo_rows` whose rows, and
    every row within the detector's lobe of them, hear every tone (none masked by the
    reverberation band, ``fe.tone_w``). Where a tone is masked a still echo's tone lands on
    the row's cells, and its ghost there, read over the other tones, fits two echoes of one
    speed better than one (att, a still echo 6 dB above a -15 m/s target, band of 5 m/s: two
    such pairs at 22.5 m/s in 0.6 s)."""
    rows = second_echo_rows(fe)
    if fe.tone_w is None:
        return rows
    masked = np.any(np.asarray(fe.tone_w) < 1.0, axis=1).astype(np.float64)
    reach = np.ones(2 * fe.lobe_hypotheses + 1)
    out: NDArray[np.bool_] = rows & (np.convolve(masked, reach, mode="same") == 0)
    return out
