"""The full GCAS search (``search="full"``, the reference): every unit correlator at every
baseband sample (SPEC §3 steps 2–3 and 6).

The bank gives ``u[n, d, k]`` (:class:`~hil.estimation.unit_correlators.UnitCorrelatorBank`),
``U = |u|²`` weighted per cell by the reverberation band; the group correlators
``G_d = Σ_k U[:, d, k]`` are accumulated over ``M`` hops by the comb recursion
``Acc_d[n] = Acc_d[n − N_d] + G_d[n] − G_d[n − M N_d]`` (cost independent of ``M``), and
``d̂[n] = argmax_d w_d Acc_d[n]``. Candidates are the local maxima over ``±N_min/2`` of the
group statistic ``g[n] = max_d w_d Acc_d[n]``; at each, the exact sums ``A`` are evaluated
for ``n`` within ``±W`` at ``d̂`` and its neighbours (:mod:`hil.estimation.gcas.threshold`),
so that the cost per sample does not depend on ``M``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.estimation.gcas.front_end import FrontEnd
from hil.estimation.gcas.still_codewords import StillCodewords
from hil.estimation.gcas.sums import CodewordSums
from hil.estimation.gcas.threshold import (
    NOISE_STRIDE,
    Cfar,
    Peak,
    local_maxima,
    median_spread,
    threshold_peaks,
    window_means,
)
from hil.estimation.kernels import peak_indices
from hil.estimation.row_buffer import RowBuffer
from hil.estimation.unit_correlators import UnitCorrelatorBank


class FullSearch:
    """:class:`~hil.estimation.gcas.search.SearchStrategy` evaluating every hypothesis at
    every baseband sample; keeps ``u`` (complex when ``coherent``) for the sums."""

    def __init__(
        self, fe: FrontEnd, sums: CodewordSums, cfar: Cfar, *, coherent: bool,
        runner_up_ratio: float, still_codewords: bool,
    ) -> None:  # fmt: skip
        self._fe, self._sums, self._cfar = fe, sums, cfar
        self._coherent = coherent
        self._runner_up_ratio = runner_up_ratio
        #: With the refinement, a still candidate's second codeword too
        #: (:mod:`hil.estimation.gcas.still_codewords`).
        self._beside = StillCodewords(fe, runner_up_ratio) if still_codewords else None
        self.bank = UnitCorrelatorBank(fe.fs_bb, fe.nu, fe.grid.lengths)
        d, k, m = fe.grid.size, fe.n_tones, fe.m_hops
        lag_keep = int(fe.lags.max()) + 2 * fe.search_half + fe.half_width + 2
        self._u_ring = RowBuffer(lag_keep, (d, k), np.complex64 if coherent else np.float32)
        self._g_ring = RowBuffer(m * fe.n_max + 1, (d,), np.float64)
        self._acc_ring = RowBuffer(fe.n_max + 1, (d,), np.float64)
        det_keep = fe.cfar_window + 2 * fe.n_max + 4
        #: A peak's statistic is read from the detection history: at most this far behind
        #: the newest baseband sample (:attr:`SearchStrategy.decision_lag`).
        self.decision_lag = det_keep
        self._s_ring = RowBuffer(det_keep, (), np.float64)
        self._dhat_ring = RowBuffer(det_keep, (), np.int64)
        self._noise_ring = RowBuffer(det_keep, (), np.float64)
        self.reset(0)

    def reset(self, b0: int) -> None:
        self.bank.reset(b0)
        for ring in (
            self._u_ring, self._g_ring, self._acc_ring, self._s_ring, self._dhat_ring,
            self._noise_ring,
        ):  # fmt: skip
            ring.reset(b0)
        self._origin = b0
        self._valid_from = b0 + self._fe.settle
        self._det_next = b0

    # ------------------------------------------------------------------ streaming
    def process(self, y: NDArray[np.complex128]) -> list[Peak]:
        fe = self._fe
        a0 = self.bank.next_index
        u = self.bank.process_last(y)  # (D, K, n): samples on the contiguous axis
        n = u.shape[2]
        power = np.square(u.real) + np.square(u.imag)
        masked = power if fe.tone_w is None else power * fe.tone_w[:, :, None]
        grp = masked.sum(axis=1, dtype=np.float64).T
        kept: NDArray[Any] = masked
        if self._coherent:
            kept = u if fe.tone_w is None else u * fe.tone_w[:, :, None]
        self._u_ring.append(kept.transpose(2, 0, 1), a0)
        self._g_ring.append(grp, a0)
        acc = _comb(grp, a0, self._g_ring, self._acc_ring, fe.grid.lengths, fe.m_hops)
        self._acc_ring.append(acc, a0)
        wacc = acc * fe.grid.weights[None, :]
        d_hat = np.argmax(wacc, axis=1)
        self._s_ring.append(np.take_along_axis(wacc, d_hat[:, None], axis=1)[:, 0], a0)
        self._dhat_ring.append(d_hat, a0)
        idx = a0 + np.arange(n, dtype=np.int64)
        self._noise_ring.append(_noise_floor(power, idx), a0)
        return self.flush()

    def flush(self) -> list[Peak]:
        return self._detect(self._s_ring.next_index - self._fe.half_width)

    def next_decision_index(self, samples_seen: int) -> int:
        return samples_seen

    def warm_up(self) -> None:
        peak_indices(np.zeros(3), 1, 0, 3)

    # ------------------------------------------------------------------ sums
    def map_hypotheses(self, count: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        stop = self._dhat_ring.next_index
        return np.arange(stop - count, stop, dtype=np.int64), self._dhat_ring.span(
            stop - count, stop
        )

    def retained(self, count: int) -> NDArray[np.int64]:
        ring = self._u_ring
        stop = ring.next_index
        count = int(min(count, stop - self._origin, ring.available - self._fe.lags.max() - 1))
        return np.arange(stop - count, stop, dtype=np.int64)

    def terms(self, idx: NDArray[np.int64], dcol: NDArray[np.int64]) -> NDArray[Any]:
        pos = self._u_ring.position(idx[:, None] - self._fe.lags[dcol])  # (n, M)
        terms: NDArray[Any] = self._u_ring.array[pos, dcol[:, None], :]
        return terms

    def unit_values(self, n_star: int, d0: int, tone: NDArray[np.int64]) -> NDArray[np.complex128]:
        pos = self._u_ring.position(n_star - self._fe.lags[d0])
        v: NDArray[np.complex128] = self._u_ring.array[pos, d0, tone].astype(np.complex128)
        return v

    # ------------------------------------------------------------------ detection
    def _detect(self, stop: int) -> list[Peak]:
        """Decide the candidates ``< stop`` (their ±N_min/2 look-ahead has arrived)."""
        fe = self._fe
        lo = self._det_next
        if stop <= lo:
            return []
        cand = local_maxima(self._s_ring, lo, stop, fe.half_width, self._origin, self._valid_from)
        self._det_next = stop
        if cand.size == 0:
            return []
        # Exact codeword sums A[n, d, j] for every candidate at once: n within ±W of the
        # candidate, d at the chosen hypothesis and its two neighbours.
        w = fe.search_half
        offs = np.arange(-w, w + 1, dtype=np.int64)
        d0 = self._dhat_ring.rows(cand)
        dset = np.clip(d0[:, None] + np.arange(-1, 2)[None, :], 0, fe.grid.size - 1)
        n_idx = np.broadcast_to(
            cand[:, None, None] + offs[None, :, None], (*cand.shape, 2 * w + 1, 3)
        )
        d_idx = np.broadcast_to(dset[:, None, :], n_idx.shape)
        flat_n, flat_d = n_idx.reshape(-1), d_idx.reshape(-1)
        a = self._sums.reduce(self.terms(flat_n, flat_d), flat_n, flat_d, False).reshape(
            *n_idx.shape, -1
        )

        def sides(hit: NDArray[np.int64], n_pk: NDArray[np.int64]) -> NDArray[np.float32]:
            side: NDArray[np.float32] = a[hit, n_pk - cand[hit] + w][:, [0, 2], :]
            return side

        tested = self._s_ring.rows(cand) if self._cfar.mode == "statistic" else None

        def test(
            n_pk: NDArray[np.int64], peak: NDArray[np.float64]
        ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
            return self._cfar.test(n_pk, peak, tested, self)

        return threshold_peaks(
            cand, w, dset, a[:, :, 1, :], sides, test, self._runner_up_ratio, self._beside
        )

    def noise_floor(self, n_pk: NDArray[np.int64]) -> NDArray[np.float64]:
        """μ_U over the trailing CFAR window of each peak sample ``n_pk``."""
        fe = self._fe
        lo = np.maximum(n_pk - fe.cfar_window, self._origin + fe.n_max)
        return window_means(self._noise_ring, lo, n_pk, fe.cfar_window + 1)

    def statistic_moments(self, n_star: int) -> tuple[float, float]:
        """Median and MAD-based std of the group statistic over the trailing CFAR window
        that ends one hop (``N_max``) before ``n_star``."""
        guard = self._fe.n_max
        lo = max(n_star - guard - self._fe.cfar_window, self._valid_from)
        return median_spread(self._s_ring, lo, n_star - guard)


def _noise_floor(power: NDArray[np.float32], idx: NDArray[np.int64]) -> NDArray[np.float64]:
    """μ_U estimate on the absolute grid of :data:`NOISE_STRIDE` samples; NaN elsewhere.

    ``power`` is ``|u|²`` with samples last, shape ``(D, K, n)``; ``idx`` the sample indices.
    """
    out = np.full(idx.shape[0], np.nan)
    on = np.flatnonzero(idx % NOISE_STRIDE == 0)
    if on.size:
        # One contiguous row of D·K cells per sample: the median partitions along rows.
        flat = np.ascontiguousarray(power[:, :, on].reshape(-1, on.size).T)
        out[on] = np.median(flat, axis=1) / math.log(2.0)
    return out


def _comb(
    grp: NDArray[np.float64],
    a0: int,
    g_ring: RowBuffer,
    acc_ring: RowBuffer,
    lengths: NDArray[np.int64],
    m_hops: int,
) -> NDArray[np.float64]:
    """Comb accumulation ``Acc_d[n] = Acc_d[n − N_d] + G_d[n] − G_d[n − M N_d]`` of the new
    rows ``grp`` (shape ``(n, D)``, first index ``a0``) with the histories of ``G`` and ``Acc``
    in ``g_ring`` and ``acc_ring``; ``lengths`` is ``N_d`` (shape ``(D,)``) in ring rows."""
    n, d = grp.shape
    cols = np.arange(d)
    idx = a0 + np.arange(n, dtype=np.int64)
    # Flat take() of G_d[n − M N_d]: cheaper than 2-D fancy indexing.
    flat = g_ring.position(idx[:, None] - (m_hops * lengths)[None, :]) * d + cols
    g_old = np.take(g_ring.array.reshape(-1), flat)
    x = grp - g_old
    # Every N_d >= N_min, so the N_min samples of one step depend only on earlier steps:
    # all hypotheses advance together, one step of the recursion per numpy call.
    h = int(lengths.max())
    work = np.empty((h + n, d))
    work[:h] = acc_ring.span(a0 - h, a0)
    flat_work = work.reshape(-1)
    back = (h - lengths[None, :]) * d + cols  # flat offset of Acc_d[n − N_d]
    step = int(lengths.min())
    for s in range(0, n, step):
        e = min(s + step, n)
        src = np.take(flat_work, back + d * np.arange(s, e)[:, None])
        np.add(src, x[s:e], out=work[h + s : h + e])
    return work[h:]
