"""Accumulated sums ``A[n, d, j]`` from the unit-correlator values of their M terms (SPEC §3
step 4): noncoherent, or with the transmit phases restored (coherent)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.estimation.gcas.front_end import FrontEnd


class CodewordSums:
    """Reduces the terms ``u[n − ℓ_{d,m}, d, k]`` (shape ``(n, M, K)``) of samples ``n`` at
    hypotheses ``d`` to the sums of every codeword ``j``, shape ``(n, J)``.

    The terms are ``w·|u|²`` (float) or ``w·u`` (complex, kept when the receiver is coherent);
    a complex history also gives the noncoherent sums.
    """

    def __init__(self, fe: FrontEnd) -> None:
        self._time_of = fe.baseband.time_of
        m, k, j = fe.m_hops, fe.n_tones, fe.n_codewords
        m_idx = np.arange(m)
        # Cell m·K + c_{j−m} of the (M·K) terms that is term m of codeword j, shape (M, J):
        # the noncoherent sums gather these.
        self._term_cell = m_idx[:, None] * k + fe.code[(np.arange(j)[None, :] - m_idx[:, None]) % j]
        self._w_coh = _coherent_weights(fe)
        # Coherent restoration constants per (d, k): f_k α_d and the filter-delay phase ν g.
        g = fe.baseband.group_delay / fe.fs_hz
        self._fa = fe.tones_hz[None, :] * fe.grid.alphas[:, None]  # (D, K) Hz
        delta0 = (fe.grid.exact_lengths - fe.grid.lengths + 1) / (2.0 * fe.fs_bb)
        self._coh_const = np.mod(self._fa * delta0[:, None] + fe.nu * g, 1.0)  # cycles

    def reduce(
        self, terms_all: NDArray[Any], idx: NDArray[np.int64], dcol: NDArray[np.int64],
        coherent: bool,
    ) -> NDArray[np.float32]:  # fmt: skip
        """``A[n, d_n, j]`` for samples ``idx`` (shape ``(n,)``) at hypotheses ``dcol`` from
        their terms; noncoherent unless ``coherent`` (which needs complex terms)."""
        n = idx.shape[0]
        if not coherent:
            # Gather term m of every codeword j directly (tone c_{j−m}), then a sum over the
            # middle axis (sequential adds, not BLAS): each row's value does not depend on
            # how many rows are computed together.
            v = terms_all.reshape(n, -1)  # (n, M·K)
            terms = np.take(v, self._term_cell, axis=1)  # (n, M, J)
            if np.iscomplexobj(terms):
                terms = np.square(terms.real) + np.square(terms.imag)
            out: NDArray[np.float32] = np.add.reduce(terms, axis=1)  # (n, J): .sum's op
            return out
        t = self._time_of(idx)
        cyc = np.mod(self._fa[dcol] * t[:, None], 1.0) + self._coh_const[dcol]
        rot = np.exp(2j * np.pi * cyc).astype(np.complex64)  # (n, K)
        z = ((terms_all * rot[:, None, :]).reshape(n, -1, 1) * self._w_coh[None]).sum(axis=1)
        res: NDArray[np.float32] = (np.square(z.real) + np.square(z.imag)).astype(np.float32)
        return res


def _coherent_weights(fe: FrontEnd) -> NDArray[np.complex64]:
    """Codeword matrix with phases restored, shape ``(M·K, J)``: term ``m`` of codeword ``j``
    is tone ``c_{j−m}`` with the conjugate of its transmit phase at the hop's end."""
    m, k, j, p = fe.m_hops, fe.n_tones, fe.n_codewords, fe.n_codewords
    jj = np.arange(j)[None, :]
    mm = np.arange(m)[:, None]
    tone = fe.code[(jj - mm) % p]  # (M, J): tone of term m of codeword j
    onehot = (tone[:, None, :] == np.arange(k)[None, :, None]).astype(np.float32)
    # Φ_end of hop h (global, h = j − m in −M+1..P−1) is the start phase of hop h + 1.
    table = fe.schedule.hops(-m + 2, p + m - 1)
    phase_end = table.phase_rad[(jj - mm) + m - 1]  # (M, J)
    f = fe.tones_hz[tone]
    theta = phase_end + 2.0 * np.pi * np.mod(f * mm * fe.hop_s, 1.0)
    w_coh = (onehot * np.exp(-1j * theta)[:, None, :]).astype(np.complex64)
    return w_coh.reshape(m * k, j)
