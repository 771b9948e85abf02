"""GCAS detection tests: the CFAR threshold and the runner-up test of candidate peaks (SPEC §3
step 6; the noise moments and λ come from :mod:`hil.estimation.detection`).

CFAR modes: ``"bank"`` estimates the unit-correlator noise power ``μ_U`` (the median over
all (d, k) cells of ``U`` ÷ ln 2, the median of an exponential) averaged over a trailing
window and tests the codeword sum against the noise moments of ``s``; ``"statistic"`` is the
literal reading of SPEC §3.5 applied to the group statistic: median/MAD of ``g`` over a
trailing window that ends one hop before the candidate. The bank mode stays valid while a
target is tracked; the trailing statistic of a tracked target never returns to the noise
floor, which blinds the literal form at high SNR.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from hil.estimation.detection import noise_moments, parabolic_offsets
from hil.estimation.kernels import peak_indices
from hil.estimation.row_buffer import RowBuffer

#: Noise-floor estimate on every this-many baseband samples (absolute grid).
NOISE_STRIDE = 32


#: A candidate's kind (:meth:`~hil.estimation.gcas.candidates.CandidateCells.cells`): a
#: second maximum of its Doppler row (:attr:`Peak.second`) ...
SECOND_MAX = 1
#: ... or a peak masked by a greater one of another boundary (:attr:`Peak.masked`); 0 for
#: neither.
MASKED_PEAK = 2


class Peak(NamedTuple):
    """A candidate that passed the threshold and the runner-up test, ready for the readout.

    ``n_star``: peak sample (baseband index) with sub-sample offset ``dn``; ``peak``: the
    statistic there; ``codeword``: best codeword, ``ratio`` times the runner-up; ``d0``:
    hypothesis with offset ``dd`` (grid steps); ``mean``, ``threshold``: noise mean and
    threshold (statistic units); ``beside``: the second codeword of the peak before it
    (:mod:`hil.estimation.gcas.still_codewords`), decided only where that one is refused.
    """

    n_star: int
    peak: float
    codeword: int
    ratio: float
    dn: float
    d0: int
    dd: float
    mean: float
    threshold: float
    beside: bool = False
    #: A second echo of one speed: a second maximum of its Doppler row
    #: (:mod:`hil.estimation.gcas.candidates`) or its window's second codeword at a moving
    #: hypothesis (:mod:`hil.estimation.gcas.still_codewords`); decided only beside a partner
    #: or two echoes measured at its speed.
    second: bool = False
    #: A second echo's peak masked by a greater one of another boundary within one Doppler
    #: resolution cell (:func:`~hil.estimation.kernels.masked_peak_cells`): also
    #: :attr:`second`; not decided where an echo measured at its speed has its boundary
    #: (:meth:`~hil.estimation.refine.CoherentRefiner.followed_near`).
    masked: bool = False


class AddsBeside(Protocol):
    """Where a still peak is followed by its window's second codeword
    (:class:`~hil.estimation.gcas.still_codewords.StillCodewords`)."""

    def add(
        self, peaks: list[Peak], windows: NDArray[np.floating], first: NDArray[np.int64]
    ) -> list[Peak]:
        """``peaks`` with, after each still one, its window's second codeword where it has
        one; ``windows[i]``: the exact sums of ``peaks[i]``'s window (shape
        ``(P, 2w + 1, J)``), whose row 0 is baseband sample ``first[i]`` (shape ``(P,)``)."""
        ...


class NoiseHistory(Protocol):
    """Where a search keeps the trailing noise estimates the CFAR reads."""

    def noise_floor(self, n_pk: NDArray[np.int64]) -> NDArray[np.float64]:
        """``μ_U`` over the trailing window of each peak sample ``n_pk`` (shape ``(C,)``)."""
        ...

    def statistic_moments(self, n_star: int) -> tuple[float, float]:
        """Median and MAD-based std of the group statistic before peak sample ``n_star``."""
        ...


class Cfar:
    """The threshold ``μ̂ + λσ̂`` in mode ``"bank"`` or ``"statistic"``.

    Detection (threshold, codeword, coarse time) always runs on the noncoherent sums, so the
    noise moments are those of ``M``-term noncoherent sums.
    """

    def __init__(self, mode: str, lam: float, m_hops: int) -> None:
        self.mode = mode
        self.lam = lam
        self._moments = noise_moments(m_hops, False)

    def test(
        self,
        n_pk: NDArray[np.int64],
        peak: NDArray[np.floating[Any]],
        stat_tested: NDArray[np.float64] | None,
        history: NoiseHistory,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
        """The CFAR test of candidates peaking at samples ``n_pk`` (shape ``(C,)``): the
        noise mean and threshold per candidate and the indices of those over it. ``"bank"``
        tests the codeword-sum ``peak``; ``"statistic"`` tests ``stat_tested``, the group
        statistic at the candidates."""
        if self.mode == "bank":
            mu_u = history.noise_floor(n_pk)
            m, s = self._moments
            mean, std = m * mu_u, s * mu_u
            tested = np.asarray(peak, dtype=np.float64)
        else:
            ms = [history.statistic_moments(int(v)) for v in n_pk.tolist()]
            mean, std = np.array([v[0] for v in ms]), np.array([v[1] for v in ms])
            assert stat_tested is not None
            tested = stat_tested
        thr = mean + self.lam * std
        return mean, thr, np.flatnonzero(tested > thr)


def local_maxima(
    ring: RowBuffer, lo: int, stop: int, half: int, origin: int, valid_from: int
) -> NDArray[np.int64]:
    """Candidates: the rows ``lo <= n < stop`` of the statistic in ``ring`` that are local
    maxima over ``±half`` rows (:func:`~hil.estimation.kernels.peak_indices`), as absolute
    row indices. Rows before ``valid_from`` (accumulations not yet full) are never one; rows
    before ``origin`` (the last restart) do not exist."""
    first = max(lo - half, origin)
    last = min(stop + half, ring.next_index)
    s = np.array(ring.span(first, last), dtype=np.float64)
    s[: max(0, valid_from - first)] = -np.inf
    found: NDArray[np.int64] = peak_indices(s, half, lo - first, stop - first) + first
    return found


def window_means(
    ring: RowBuffer, lo: NDArray[np.int64], hi: NDArray[np.int64], width: int
) -> NDArray[np.float64]:
    """Mean of the finite values of ``ring`` over rows ``lo..hi`` (inclusive) per candidate
    (shapes ``(C,)``; ``width`` at least the longest span); inf where there are none.

    One fixed-length row per candidate, summed along the row: each window's sum is then
    independent of the other candidates decided with it (chunking cannot change a bit)."""
    idx = lo[:, None] + np.arange(width)
    inside = idx <= hi[:, None]
    vals = ring.rows(np.where(inside, idx, hi[:, None]))
    ok = inside & np.isfinite(vals)
    n_ok = ok.sum(axis=1)
    total = np.where(ok, vals, 0.0).sum(axis=1)
    mu: NDArray[np.float64] = np.where(n_ok > 0, total / np.maximum(n_ok, 1), np.inf)
    return mu


def median_spread(ring: RowBuffer, lo: int, hi: int) -> tuple[float, float]:
    """Median and MAD-based std of ``ring`` rows ``lo..hi−1``; (inf, 0) below 8 rows."""
    if hi - lo < 8:
        return math.inf, 0.0
    vals = np.asarray(ring.span(lo, hi))
    med = float(np.median(vals))
    return med, 1.4826 * float(np.median(np.abs(vals - med)))


def threshold_peaks(
    cand: NDArray[np.int64],
    w: int,
    dset: NDArray[np.int64],
    a: NDArray[np.floating[Any]],
    sides: Callable[[NDArray[np.int64], NDArray[np.int64]], NDArray[np.floating[Any]]],
    test: Callable[
        [NDArray[np.int64], NDArray[np.float64]],
        tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]],
    ],
    runner_up_ratio: float,
    beside: AddsBeside | None = None,
    second: NDArray[np.int8] | None = None,
    pair_rows: NDArray[np.bool_] | None = None,
) -> list[Peak]:
    """Threshold and runner-up tests of candidates centred on samples ``cand`` (shape
    ``(C,)``), as NumPy expressions: ``a`` holds ``A[n, d, j]`` at the chosen hypothesis
    (middle of ``dset``, shape ``(C, 3)``) for ``n`` within ``±w``, shape
    ``(C, 2w + 1, J)``; ``sides(hit, n)`` gives ``A`` at the two neighbouring hypotheses at
    samples ``n`` of candidates ``hit`` (shape ``(H, 2, J)``); ``test(n_pk, peak)`` is the
    CFAR test (:meth:`Cfar.test`); ``beside``: where given, each still peak is followed by
    its window's second codeword (:mod:`hil.estimation.gcas.still_codewords`); ``second``
    (shape ``(C,)``) marks the candidates that are a second maximum of their row;
    ``pair_rows`` (shape ``(D,)``) the hypotheses at which a peak tied with the runner-up is
    kept where it beats the third codeword (:func:`~hil.estimation.kernels.fine_keep`)."""
    # Threshold test for all candidates at once; only the survivors are read out.
    s_win = a.max(axis=2)  # (C, 2W + 1)
    i_pk = np.argmax(s_win, axis=1)
    n_pk = cand - w + i_pk
    peak_all = s_win[np.arange(cand.shape[0]), i_pk].astype(np.float64)
    mean, thr, hit = test(n_pk, peak_all)
    if hit.size == 0:
        return []
    # Readout quantities of every survivor at once (per-candidate numpy calls would
    # dominate the cost): peak sample, codeword, runner-up ratio, time and Doppler offsets.
    ip = i_pk[hit]
    sw = s_win[hit].astype(np.float64)
    r = np.arange(hit.size)
    peak = sw[r, ip]
    rows = a[hit, ip].astype(np.float64)  # (H, J)
    jh = np.argmax(rows, axis=1)
    runner = np.partition(rows, -2, axis=1)[:, -2] if rows.shape[1] > 1 else np.zeros(r.size)
    ratio = np.full(r.size, np.inf)
    np.divide(peak, runner, out=ratio, where=runner > 0)
    if pair_rows is not None and rows.shape[1] > 2:
        third = np.partition(rows, -3, axis=1)[:, -3]
        ratio3 = np.full(r.size, np.inf)
        np.divide(peak, third, out=ratio3, where=third > 0)
        paired = (ratio < runner_up_ratio) & pair_rows[dset[hit, 1]]
        ratio = np.where(paired, ratio3, ratio)
    keep = np.flatnonzero(ratio >= runner_up_ratio)
    if keep.size == 0:
        return []
    inner = (ip > 0) & (ip < 2 * w)
    dn = np.where(
        inner,
        parabolic_offsets(sw[r, np.maximum(ip - 1, 0)], peak, sw[r, np.minimum(ip + 1, 2 * w)]),
        0.0,
    )
    dh = dset[hit]
    side = sides(hit[keep], n_pk[hit[keep]]).astype(np.float64)  # (H', 2, J)
    jk = jh[keep]
    rk = np.arange(keep.size)
    d_in = (dh[keep, 0] != dh[keep, 1]) & (dh[keep, 2] != dh[keep, 1])
    dd = np.where(d_in, parabolic_offsets(side[rk, 0, jk], rows[keep, jk], side[rk, 1, jk]), 0.0)
    n_star = (cand[hit] - w + ip)[keep]
    peaks = peaks_of(
        n_star, peak[keep], jk, ratio[keep], dn[keep], dh[keep, 1], dd, mean[hit[keep]],
        thr[hit[keep]],
    )  # fmt: skip
    if second is not None:
        peaks = seconds_marked(peaks, second[hit[keep]])
    if beside is None:
        return peaks
    return beside.add(peaks, a[hit[keep]], cand[hit[keep]] - w)


def seconds_marked(peaks: list[Peak], second: NDArray[np.int8]) -> list[Peak]:
    """``peaks`` with :attr:`Peak.second` set where ``second`` (shape ``(len(peaks),)``) is
    :data:`SECOND_MAX` or :data:`MASKED_PEAK`, and :attr:`Peak.masked` where it is the latter."""
    if not second.any():
        return peaks
    marks = second.tolist()
    return [
        p._replace(second=True, masked=s == MASKED_PEAK) if s else p
        for p, s in zip(peaks, marks, strict=True)
    ]


def peaks_of(*columns: NDArray[Any]) -> list[Peak]:
    """:class:`Peak` rows from its nine fields as arrays of equal length, as Python numbers."""
    return [Peak(*row) for row in zip(*(c.tolist() for c in columns), strict=True)]
