"""A second codeword at a candidate: two echoes of one speed arriving at once.

With the reverberation band off, every still echo (a target at rest, the near water, the
walls) peaks in the same few Doppler hypotheses, those slower than one Doppler resolution
cell (:func:`~hil.estimation.reverb_band.in_reverberation`). Stage 1 keeps one candidate per
half hop and Doppler cell, and stage 2 takes the codeword whose sum is the largest at the
candidate's peak. Where a later transmit hop's near-water echo arrives together with a still
target's boundary (dense reverberation: every boundary whose delay, modulo the hop, falls
within the near water's delays), the codeword the stronger of the two fills wins, and the
target's boundary gets no detection of its own, though its own codeword's sum peaks in the
same window.

So, for a candidate on a still hypothesis, the largest other codeword of its window is a
candidate too (:func:`second_codeword`) where its sum peaks inside the window (not on its
edge), beats the codewords left by the runner-up ratio, and stands above the candidate's
threshold by the first echo's share of it: at one sample two codewords' sums hold the very
same unit correlator in every term whose tone they share (:func:`shared_terms`), so the
first echo adds ``(peak − mean)·shared/M`` to the second codeword's sum, which the noise
threshold does not count. The readout decides it as any other detection (the refinement's
echo test with the echoes it measured taken out, the clutter and point-echo rules), and only
where the first was refused (:meth:`~hil.estimation.gcas.readout.Readout.decide_all`).

Two moving echoes of one speed whose delays differ by a whole number of hops (a formation
7.5 m apart on att) arrive together the same way on every boundary, on two codewords whose
sums tie. At the hypotheses where a second echo of one speed is looked for
(:func:`~hil.estimation.gcas.search_two_stage.second_echo_rows`) the runner-up test reads the
third codeword where the first two tie (:func:`~hil.estimation.kernels.fine_keep`), and the
window's second codeword is a candidate too where it reaches
:data:`~hil.estimation.gcas.candidates.SECOND_LEVEL` of the first (one echo's other codewords
hold at most ``shared/M`` of it, 0.5 on att), marked
:attr:`~hil.estimation.gcas.threshold.Peak.second`: decided beside a partner or two echoes
measured at that speed, whatever became of the first (no still scatterer field there).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from hil.estimation.detection import parabolic_offset
from hil.estimation.doppler_grid import DopplerGrid
from hil.estimation.gcas.candidates import SECOND_LEVEL
from hil.estimation.gcas.front_end import FrontEnd
from hil.estimation.gcas.threshold import Peak
from hil.estimation.kernels import second_codeword_rows
from hil.estimation.reverb_band import doppler_resolution_mps
from hil.signals.schedule import HopSchedule


class SecondCodeword(NamedTuple):
    """Another codeword's peak in a candidate's window: ``sample`` of the window (index),
    ``codeword``, its sum ``value`` (statistic units), ``ratio`` (``value`` over the largest
    codeword left at that sample, neither the first nor this one; inf where none) and the
    parabolic offset ``dn`` (samples, within ±1)."""

    sample: int
    codeword: int
    value: float
    ratio: float
    dn: float


def still_hypotheses(
    grid: DopplerGrid,
    tones_hz: NDArray[np.float64],
    hop_s: float,
    sound_speed_mps: float,
    refused: NDArray[np.bool_],
) -> NDArray[np.bool_]:
    """The hypotheses that hold still echoes and are searched (shape ``(D,)``): slower than
    one Doppler resolution cell, at full weight (the band off there) and not refused."""
    cell = doppler_resolution_mps(tones_hz, hop_s, sound_speed_mps)
    still: NDArray[np.bool_] = (
        (np.abs(grid.speeds_mps) < cell) & (grid.weights >= 1.0) & ~np.asarray(refused)
    )
    return still


def shared_terms(schedule: HopSchedule, m_hops: int) -> NDArray[np.int64]:
    """How many of their ``M`` terms two codewords give the same tone (shape ``(J, J)``):
    term ``m`` of codeword ``j`` is hop ``j − m``'s tone, the same every code period.

    >>> from hil.signals.presets import check_design, get_preset
    >>> s = shared_terms(check_design(get_preset("att").spec("random-cyclic")), 10)
    >>> s.shape, int(s[0, 0]), bool((s == s.T).all())
    ((17, 17), 10, True)
    """
    words = schedule.code.shape[0]
    tones = np.stack(
        [schedule.hops(j - m_hops + 1, m_hops).tone_index[::-1] for j in range(words)]
    )  # (J, M): term m of codeword j
    shared: NDArray[np.int64] = (tones[:, None, :] == tones[None, :, :]).sum(axis=2)
    return shared


def second_codeword(
    window: NDArray[np.float64],
    first: int,
    threshold: float,
    leak: NDArray[np.float64],
    runner_up_ratio: float,
) -> SecondCodeword | None:
    """The largest codeword other than ``first`` in a candidate's window of exact sums
    (``window`` shape ``(2w + 1, J)``: samples × codewords), counted less the first echo's
    share of each codeword (``leak``, shape ``(J,)``, statistic units); None where it peaks
    on the window's edge, stays below ``threshold`` plus its leak, or does not beat the
    codewords left at its peak by ``runner_up_ratio``.

    >>> w = np.array([[1.0, 0.5, 0.1], [9.0, 4.0, 0.2], [2.0, 0.5, 0.1]])
    >>> second_codeword(w, 0, 3.0, np.zeros(3), 1.05)
    SecondCodeword(sample=1, codeword=1, value=4.0, ratio=20.0, dn=0.0)
    >>> second_codeword(w, 0, 3.0, np.array([0.0, 1.5, 0.0]), 1.05) is None
    True
    """
    n, words = window.shape
    if words < 2 or n < 3:
        return None
    best = window.max(axis=0) - leak
    best[first] = -np.inf
    j = int(np.argmax(best))
    column = window[:, j]
    i = int(np.argmax(column))
    value = float(column[i])
    if not (0 < i < n - 1) or not value >= threshold + float(leak[j]):
        return None
    rest = np.delete(window[i], [first, j])
    third = float(rest.max()) if rest.size else 0.0
    ratio = value / third if third > 0 else np.inf
    if not ratio >= runner_up_ratio:
        return None
    dn = parabolic_offset(float(column[i - 1]), value, float(column[i + 1]))
    return SecondCodeword(i, j, value, float(ratio), dn)


class StillCodewords:
    """The rule of this module for one front end: which hypotheses hold still echoes, the
    codewords' shared terms, and the runner-up ratio of the search (``runner_up_ratio``).

    ``pair_rows`` (shape ``(D,)``, bool): moving hypotheses whose candidates also give their
    window's second codeword, marked :attr:`~hil.estimation.gcas.threshold.Peak.second` (two
    echoes of one speed whose boundaries arrive together: decided beside a partner or two echoes
    measured at that speed, :meth:`~hil.estimation.refine.CoherentRefiner.beside_known`)."""

    def __init__(
        self, fe: FrontEnd, runner_up_ratio: float, pair_rows: NDArray[np.bool_] | None = None
    ) -> None:
        self.still = still_hypotheses(
            fe.grid, fe.tones_hz, fe.hop_s, fe.sound_speed_mps, fe.refused_hypotheses
        )
        self.pair = (
            np.zeros(fe.grid.size, dtype=np.bool_)
            if pair_rows is None
            else np.asarray(pair_rows, dtype=np.bool_) & ~self.still
        )
        self._share = shared_terms(fe.schedule, fe.m_hops) / fe.m_hops
        self._ratio = float(runner_up_ratio)

    def add(
        self, peaks: list[Peak], windows: NDArray[np.floating], first: NDArray[np.int64]
    ) -> list[Peak]:
        """``peaks``, each on a still hypothesis (or a moving one of ``pair_rows``) followed
        by its window's second codeword where it has one (``beside``). ``windows[i]``: the
        exact sums of ``peaks[i]``'s window at its hypothesis (shape ``(P, 2w + 1, J)``),
        whose row 0 is baseband sample ``first[i]`` (shape ``(P,)``)."""
        n = len(peaks)
        d0 = np.fromiter((p.d0 for p in peaks), np.int64, n)
        word = np.fromiter((p.codeword for p in peaks), np.int64, n)
        level = np.fromiter((p.peak for p in peaks), np.float64, n)
        mean = np.fromiter((p.mean for p in peaks), np.float64, n)
        thr = np.fromiter((p.threshold for p in peaks), np.float64, n)
        return self.add_columns(peaks, windows, first, d0, word, level, mean, thr)

    def add_columns(
        self, peaks: list[Peak], windows: NDArray[np.floating], first: NDArray[np.int64],
        d0: NDArray[np.int64], word: NDArray[np.int64], level: NDArray[np.float64],
        mean: NDArray[np.float64], thr: NDArray[np.float64],
    ) -> list[Peak]:  # fmt: skip
        """:meth:`add` given the peaks' fields as arrays too (shape ``(P,)``: ``d0``,
        ``codeword``, ``peak``, ``mean``, ``threshold``), as stage 2 has them: the same
        peaks, without reading the fields back from ``peaks``."""
        still, pair = self.still[d0], self.pair[d0]
        if not (still.any() or pair.any()):
            return peaks
        # Compiled: as array expressions, some 30 calls per batch of a few windows cost more
        # than the windows' sums (second_codeword is the reference, tested equal).
        idx, sample, code, value, ratio, dn = second_codeword_rows(
            np.ascontiguousarray(windows, dtype=np.float64), still, pair, word, level,
            level - mean, thr, self._share, self._ratio, SECOND_LEVEL,
        )  # fmt: skip
        if idx.size == 0:
            return peaks
        seconds: dict[int, Peak] = {}
        for k, i in enumerate(idx.tolist()):
            seconds[i] = peaks[i]._replace(
                n_star=int(first[i]) + int(sample[k]), peak=float(value[k]),
                codeword=int(code[k]), ratio=float(ratio[k]), dn=float(dn[k]),
                beside=True, second=bool(pair[i]),
            )  # fmt: skip
        out: list[Peak] = []
        for i, p in enumerate(peaks):
            out.append(p)
            if i in seconds:
                out.append(seconds[i])
        return out

    def load_kernel(self) -> None:
        """Load the compiled second-codeword kernel (else the first still peak does)."""
        one = np.zeros(1, dtype=np.int64)
        zero, no = np.zeros(1), np.zeros(1, dtype=np.bool_)
        second_codeword_rows(
            np.zeros((1, 3, 2)), no, no, one, zero, zero, zero, self._share, 1.0, SECOND_LEVEL
        )
