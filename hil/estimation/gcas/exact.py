"""Exact unit correlators and codeword sums recomputed from the complex baseband history (stage
2 of the two-stage search, its coherent readout and its time–codeword map).

Every value is a function of its own sample, hypothesis and window alone
(:func:`~hil.estimation.kernels.exact_windows`, :func:`~hil.estimation.kernels.codeword_sums`),
so batching and chunking cannot change a bit. The codeword sums cache ``w·|u|²`` per
absolute sample (slot ``n mod cap``, stamped with ``n``) and never cache a sample that has
not arrived.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.estimation.gcas.front_end import FrontEnd
from hil.estimation.kernels import codeword_sums, exact_values, exact_windows
from hil.estimation.row_buffer import RowBuffer
from hil.resident_arrays import resident_zeros

#: Anchor grid of the stage-2 prefix sums, baseband samples (values cached per sample).
EXACT_ANCHOR = 16
#: Stamp of an empty cache slot (no sample index can equal it; −1 can, before a stream's
#: first sample).
NO_SAMPLE = np.iinfo(np.int64).min


class ExactHistory:
    """The last ``keep`` baseband samples and the exact correlators computed from them.

    ``block`` is the coarse step B of the candidates' grid and ``widest`` the widest window
    of codeword sums asked for (samples); both size the cache.
    """

    def __init__(self, fe: FrontEnd, *, keep: int, block: int, widest: int) -> None:
        self._fe = fe
        self._ring = RowBuffer(keep, (), np.complex128)
        self._nu_fs = fe.nu / fe.fs_bb  # (D, K)
        self._table: NDArray[np.float64] | None = None
        self.phasor_table(max(widest, EXACT_ANCHOR))
        reach = int(fe.lags.max()) + fe.n_max + widest - 1 + 2 * EXACT_ANCHOR + 2 * block
        cap = 1 << int(math.ceil(math.log2(2 * reach)))
        # Mapped at construction, so that no live block faults them in page by page
        # (hil.resident_arrays).
        self._cache_p = resident_zeros((fe.grid.size, fe.n_tones, cap))
        self._cache_max = resident_zeros((fe.grid.size, cap))
        self._cache_n = np.full((fe.grid.size, cap), NO_SAMPLE, dtype=np.int64)
        # The kept exact unit correlators of width-1 windows (exact_values) and their window
        # ends: made at the first call of values (the time-codeword map's), none without it.
        self._value_u: NDArray[np.float64] | None = None
        self._value_n: NDArray[np.int64] | None = None
        #: Hypothesis weights of the reverberation band, shape ``(D,)``.
        self.hyp_w = np.ascontiguousarray(fe.grid.weights, dtype=np.float64)
        code, m_idx = fe.code, np.arange(fe.m_hops)
        self._term_tone = code[(np.arange(fe.n_codewords)[None, :] - m_idx[:, None]) % code.size]
        tone_w = fe.tone_w if fe.tone_w is not None else np.ones((fe.grid.size, fe.n_tones))
        self._cell_w = np.ascontiguousarray(tone_w, dtype=np.float64)

    def reset(self, b0: int) -> None:
        """Forget the history and the cache; the next sample is ``b0``."""
        self._ring.reset(b0)
        self._cache_n.fill(NO_SAMPLE)
        if self._value_n is not None:
            self._value_n.fill(NO_SAMPLE)

    def append(self, y: NDArray[np.complex128]) -> None:
        """The next baseband samples."""
        self._ring.append(y, self._ring.next_index)

    @property
    def next_index(self) -> int:
        """Index of the next baseband sample to arrive."""
        return self._ring.next_index

    def retained(self, count: int, origin: int) -> NDArray[np.int64]:
        """The last (at most ``count``) sample indices, from ``origin`` on, whose M terms can
        be recomputed: the window of the oldest term reaches ``N_max`` samples further back
        than its lag."""
        fe, ring = self._fe, self._ring
        stop = ring.next_index
        count = int(min(count, stop - origin, ring.available - fe.lags.max() - 1 - fe.n_max))
        return np.arange(stop - count, stop, dtype=np.int64)

    def phasor_table(self, width: int) -> NDArray[np.float64]:
        """``e^{−j2πν[d, k] i/fs}`` for offsets ``i < N_max + width − 1``, shape
        ``(D, ·, K, 2)`` (re, im), grown on demand."""
        need = self._fe.n_max + width - 1
        if self._table is None or self._table.shape[1] < need:
            i = np.arange(need, dtype=np.float64)
            ph = np.exp(-2j * np.pi * np.mod(i[None, :, None] * self._nu_fs[:, None, :], 1.0))
            self._table = np.ascontiguousarray(np.stack((ph.real, ph.imag), axis=-1))
        return self._table

    def windows(
        self, first: NDArray[np.int64], dd: NDArray[np.int64], width: int
    ) -> NDArray[np.complex128]:
        """Exact unit correlators ``u[first_r + t, dd_r, k]`` for ``t < width`` (shape
        ``(R, width, K)``; ``first`` and ``dd`` of shape ``(R,)``)."""
        ring = self._ring
        out = np.empty((first.shape[0], width, self._fe.n_tones, 2))
        exact_windows(
            ring.array[: ring.available], ring.next_index - ring.available,
            np.ascontiguousarray(first, dtype=np.int64), np.ascontiguousarray(dd, dtype=np.int64),
            width, self._fe.grid.lengths, self._nu_fs, self.phasor_table(width), out,
        )  # fmt: skip
        return out[..., 0] + 1j * out[..., 1]

    def values(self, first: NDArray[np.int64], dd: NDArray[np.int64]) -> NDArray[np.complex128]:
        """:meth:`windows` of width 1, ``u[first_r, dd_r, k]`` (shape ``(R, K)``), each value
        kept for the calls after while its window is held (:func:`exact_values`): the same
        bits."""
        out = self._value_parts(first, dd)
        return out[..., 0] + 1j * out[..., 1]

    def _value_parts(self, first: NDArray[np.int64], dd: NDArray[np.int64]) -> NDArray[np.float64]:
        """:meth:`values` as re and im, shape ``(R, K, 2)``."""
        ring, fe = self._ring, self._fe
        if self._value_u is None or self._value_n is None:
            cap = self._cache_n.shape[1]
            self._value_u = resident_zeros((fe.grid.size, cap, fe.n_tones, 2))
            self._value_n = np.full((fe.grid.size, cap), NO_SAMPLE, dtype=np.int64)
        out = np.empty((first.shape[0], 1, fe.n_tones, 2))
        exact_values(
            ring.array[: ring.available], ring.next_index - ring.available,
            np.ascontiguousarray(first, dtype=np.int64), np.ascontiguousarray(dd, dtype=np.int64),
            fe.grid.lengths, self._nu_fs, self.phasor_table(1), self._value_u, self._value_n, out,
        )  # fmt: skip
        return out[:, 0]

    def load_value_kernel(self) -> None:
        """Load :func:`exact_values`' compiled code (else the time-codeword map's first block
        does) on one-slot arrays of the same types, the values' store left unmade."""
        fe = self._fe
        exact_values(
            np.zeros(1, dtype=np.complex128), 0, np.zeros(1, dtype=np.int64),
            np.zeros(1, dtype=np.int64), fe.grid.lengths, self._nu_fs, self.phasor_table(1),
            np.zeros((1, 1, fe.n_tones, 2)), np.full((1, 1), NO_SAMPLE, dtype=np.int64),
            np.empty((1, 1, fe.n_tones, 2)),
        )  # fmt: skip

    def sums(
        self, centre: NDArray[np.int64], dset: NDArray[np.int64], half: int, prune: bool = False
    ) -> NDArray[np.float64]:
        """Exact noncoherent ``A[n, d, j]`` for ``n`` within ``±half`` of ``centre`` (shape
        ``(C,)``, or ``(C, nd)``: one per hypothesis) at the hypotheses ``dset`` (shape
        ``(C, nd)``): shape ``(C, nd, 2·half + 1, J)`` (with ``prune``, rows that cannot
        hold a maximum are −inf)."""
        fe, ring = self._fe, self._ring
        width = 2 * half + 1
        out = np.empty((centre.shape[0], dset.shape[1], width, fe.n_codewords))
        # A fresh writable array every time: a read-only view (what broadcasting gives when
        # no copy is needed) is another numba signature, loaded mid-stream on first use.
        centres = np.empty(dset.shape, dtype=np.int64)
        centres[...] = centre.reshape(dset.shape[0], -1)
        codeword_sums(
            ring.array[: ring.available], ring.next_index - ring.available, ring.next_index,
            centres,
            np.ascontiguousarray(dset, dtype=np.int64), half, fe.lags, fe.grid.lengths,
            self.phasor_table(EXACT_ANCHOR), self._term_tone, self._cell_w, EXACT_ANCHOR,
            self._cache_p, self._cache_max, self._cache_n, self.hyp_w, prune, out,
        )  # fmt: skip
        return out

    def terms(
        self, idx: NDArray[np.int64], dcol: NDArray[np.int64], coherent: bool
    ) -> NDArray[Any]:
        """Unit-correlator values of the M terms ``u[n − ℓ_{d,m}, d, k]`` of samples ``idx``
        at hypotheses ``dcol``, weighted, shape ``(n, M, K)``: ``w·u`` (complex64) when
        ``coherent``, else ``w·|u|²`` (float32)."""
        n, m, tone_w = idx.shape[0], self._fe.m_hops, self._fe.tone_w
        first = (idx[:, None] - self._fe.lags[dcol]).reshape(-1)
        parts = self._value_parts(first, np.repeat(dcol, m)).reshape(n, m, -1, 2)
        w = None if tone_w is None else tone_w[dcol][:, None, :]
        if coherent:
            uc = (parts[..., 0] + 1j * parts[..., 1]).astype(np.complex64)
            return uc if w is None else uc * w
        # |u|² from the parts themselves: the complex u's parts are these but for the sign
        # of a zero, which the squares drop (the same bits, two temporaries fewer).
        p = (np.square(parts[..., 0]) + np.square(parts[..., 1])).astype(np.float32)
        return p if w is None else p * w

    def unit_values(self, n_star: int, d0: int, tone: NDArray[np.int64]) -> NDArray[np.complex128]:
        """``w·u[n* − ℓ_{d0,m}, d0, tone_m]`` for the M terms (shape ``(M,)``)."""
        m = self._fe.m_hops
        first = n_star - self._fe.lags[d0]
        u = self.windows(first, np.full(m, d0, dtype=np.int64), 1)[:, 0, :]
        v: NDArray[np.complex128] = u[np.arange(m), tone]
        if self._fe.tone_w is not None:
            v = v * self._fe.tone_w[d0, tone]
        return v
