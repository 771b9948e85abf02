"""Stage 1 of the two-stage GCAS search: coarse correlators, group comb and Doppler choice.

Every ``B`` baseband samples (one block, on the absolute grid of block indices ``b``) and for
every Doppler hypothesis ``d`` and tone ``k``:

    P[b, d, k] = Σ_{r<B} y[bB + r] · exp(−j2π ν[d, k] (bB + r)/fs)        (block partial sum)
    v[b, d, k] = Σ_{i<Q_d} P[b − i, d, k]          (a window of Q_d·B samples ending at bB + B − 1)
    G_d[b]     = Σ_k w[d, k] |v[b, d, k]|²
    U_d[b]     = U_d[b − Q_d] + G_d[b] − G_d[b − M Q_d]             (uniform comb, O(1))
    Acc_d[b]   = Σ_{m<M} G_d[b − round(m H_d)]                     (rounded lags)

``H_d`` is the exact hop length in blocks (``L_d/B``, not an integer in general). The uniform
comb's terms drift by ``m·|Q_d − H_d|`` blocks (for ``L_d/B`` near a half-integer it loses most
of its later terms, and the hypothesis then loses to a ghost at low SNR); rounding each term's
lag on its own keeps the M terms within half a block, but costs M adds. So per block the
uniform comb ranks all hypotheses and only the :data:`COARSE_SHORTLIST` best (and the largest
peaks across hypotheses: other echoes' lobes) get the rounded comb (cost per block nearly
independent of M). Per block: ``h_d Acc_d[b]`` of those, the statistic
``s[b] = max h_d Acc_d[b]``, its hypothesis ``d̂[b]`` and, on every
``noise_every``-th block, the unit-correlator noise floor ``median_{d,k}(|v|² σ_d)/ln 2``
(``σ_d`` rescales a window of ``Q_d B`` samples to the exact ``N_d``). The loops are compiled
(:func:`hil.estimation.kernels.coarse_search`); the moving sums are differences of float64
cumulative sums. Samples before the first one after a :meth:`CoarseSearch.reset` count as
zero, and any chunking of the input gives the same bits.

>>> import numpy as np
>>> cs = CoarseSearch(1000.0, [[100.0]], [3], block=4, m_hops=2)
>>> s, d_hat, noise, b0, acc = cs.process(np.exp(2j * np.pi * 100.0 * np.arange(40) / 1000.0))
>>> b0, np.round(s, 3).tolist()  # |v|² = 12² once 3 blocks are in; Acc adds 2 hops
(0, [16.0, 64.0, 144.0, 160.0, 208.0, 288.0, 288.0, 288.0, 288.0, 288.0])
>>> cs.comb_lags.tolist()  # H_d defaults to Q_d
[[0, 3]]
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from hil.estimation.kernels import coarse_search


class CoarseBlocks(NamedTuple):
    """Stage 1's output for the blocks completed by one call, ``nb`` of them from absolute
    block ``first_block``: ``stat`` (shape ``(nb,)``, ``s[b]``), ``d_hat`` (shape ``(nb,)``),
    ``noise`` (shape ``(nb,)``, NaN off the ``noise_every`` grid) and ``acc``
    (``h_d Acc_d[b]``, shape ``(nb, D)``, −inf off the shortlist)."""

    stat: NDArray[np.float64]
    d_hat: NDArray[np.int64]
    noise: NDArray[np.float64]
    first_block: int
    acc: NDArray[np.float64]


#: Blocks per frame of the block rotation (one set of transcendental calls per frame).
FRAME_BLOCKS = 64
#: Hypotheses per block that get the comb with per-term rounded lags (chosen by the O(1)
#: uniform comb), so that the cost per block hardly grows with M.
COARSE_SHORTLIST = 8


class CoarseSearch:
    """Coarse correlators and group comb with explicit state (see the module docstring).

    Parameters
    ----------
    fs_hz:
        Baseband sample rate, Hz.
    freqs_hz:
        Correlator frequencies ``ν[d, k]``, Hz, shape ``(D, K)``.
    block_lengths:
        ``Q_d``, blocks per hop window, shape ``(D,)``, each >= 1.
    block:
        Samples per block ``B``.
    m_hops:
        Hops ``M`` in the comb.
    hop_blocks:
        ``H_d``, the exact hop length in blocks (shape ``(D,)``; default ``Q_d``).
    cell_weights:
        ``w[d, k]`` (shape ``(D, K)``; default ones).
    hyp_weights:
        ``h_d`` (shape ``(D,)``; default ones).
    noise_every:
        Blocks between noise-floor estimates (absolute grid).
    noise_scale:
        ``σ_d`` (shape ``(D,)``; default ones).
    peak_lobe, peak_count:
        Beside the shortlist, the ``peak_count`` largest peaks of the uniform comb across
        hypotheses (each greater than the ``peak_lobe`` hypotheses on either side) get the
        rounded comb: the lobes of weaker echoes at other speeds (default none).
    """

    def __init__(
        self,
        fs_hz: float,
        freqs_hz: ArrayLike,
        block_lengths: ArrayLike,
        *,
        block: int,
        m_hops: int,
        hop_blocks: ArrayLike | None = None,
        cell_weights: ArrayLike | None = None,
        hyp_weights: ArrayLike | None = None,
        noise_every: int = 4,
        noise_scale: ArrayLike | None = None,
        peak_lobe: int = 1,
        peak_count: int = 0,
    ) -> None:
        if not (math.isfinite(fs_hz) and fs_hz > 0):
            raise ConfigError("fs_hz", fs_hz, "> 0 Hz")
        if int(block) != block or block < 1:
            raise ConfigError("block", block, "an integer >= 1 (samples per block)")
        if int(m_hops) != m_hops or m_hops < 1:
            raise ConfigError("m_hops", m_hops, "an integer >= 1")
        if int(peak_lobe) != peak_lobe or peak_lobe < 1:
            raise ConfigError("peak_lobe", peak_lobe, "an integer >= 1 (hypotheses)")
        if int(peak_count) != peak_count or peak_count < 0:
            raise ConfigError("peak_count", peak_count, "an integer >= 0")
        if int(noise_every) != noise_every or noise_every < 1:
            raise ConfigError("noise_every", noise_every, "an integer >= 1 (blocks)")
        nu = np.asarray(freqs_hz, dtype=np.float64)
        if nu.ndim != 2 or nu.size == 0 or not np.all(np.isfinite(nu)):
            raise ConfigError("freqs_hz", f"shape {nu.shape}", "a finite (D, K) array in Hz")
        n_hyp, n_tones = nu.shape
        q = np.asarray(block_lengths)
        if q.shape != (n_hyp,) or np.any(q < 1) or np.any(q != np.round(q)):
            raise ConfigError("block_lengths", q.tolist(), f"{n_hyp} integers >= 1")
        self.fs_hz = float(fs_hz)
        self.block = int(block)
        self.m_hops = int(m_hops)
        self.noise_every = int(noise_every)
        self.block_lengths = q.astype(np.int64)
        self.n_hyp, self.n_tones = n_hyp, n_tones
        h = self.block_lengths.astype(np.float64) if hop_blocks is None else hop_blocks
        hop = np.asarray(h, dtype=np.float64)
        if hop.shape != (n_hyp,) or not np.all(np.isfinite(hop)) or np.any(hop < 1):
            raise ConfigError("hop_blocks", hop.tolist(), f"{n_hyp} finite lengths >= 1 block")
        #: Lag of term m for hypothesis d, blocks, shape ``(D, M)``.
        self.comb_lags = np.round(np.arange(self.m_hops)[None, :] * hop[:, None]).astype(np.int64)
        cells = nu.reshape(-1) / self.fs_hz  # cycles per sample, (D·K,)
        r = np.arange(self.block, dtype=np.float64)
        within = np.exp(-2j * np.pi * np.mod(r[:, None] * cells[None, :], 1.0))  # (B, D·K)
        self._within = (np.ascontiguousarray(within.real), np.ascontiguousarray(within.imag))
        fb = np.arange(FRAME_BLOCKS, dtype=np.float64) * self.block
        step = np.exp(-2j * np.pi * np.mod(fb[:, None] * cells[None, :], 1.0))  # (F, D·K)
        self._step = (np.ascontiguousarray(step.real), np.ascontiguousarray(step.imag))
        self._cycles_per_block = cells * self.block
        self._cell_w = self._vector(cell_weights, (n_hyp, n_tones), "cell_weights")
        self._hyp_w = self._vector(hyp_weights, (n_hyp,), "hyp_weights")
        self._noise_scale = self._vector(noise_scale, (n_hyp,), "noise_scale")
        # Ring lengths: powers of two (rows by masking), longer than the longest reach back.
        q_max = int(self.block_lengths.max())
        self._h_cum = 1 << q_max.bit_length()
        self._h_g = 1 << max(int(self.comb_lags.max()), self.m_hops * q_max).bit_length()
        self.shortlist = min(COARSE_SHORTLIST, n_hyp)
        self.peak_lobe, self.peak_count = int(peak_lobe), int(peak_count)
        self.reset(0)

    @staticmethod
    def _vector(value: ArrayLike | None, shape: tuple[int, ...], name: str) -> NDArray[np.float64]:
        if value is None:
            return np.ones(int(np.prod(shape)))
        arr = np.asarray(value, dtype=np.float64)
        if arr.shape != shape:
            raise ConfigError(name, f"shape {arr.shape}", f"finite weights >= 0 of shape {shape}")
        bad = ~(np.isfinite(arr) & (arr >= 0))
        if bad.any():
            where = tuple(int(i) for i in np.argwhere(bad)[0])
            raise ConfigError(
                f"{name}{list(where)}", float(arr[where]), f"finite weights >= 0 of shape {shape}"
            )
        return np.ascontiguousarray(arr.reshape(-1))

    def reset(self, next_index: int = 0) -> None:
        """Forget all sums; the next input sample has absolute baseband index ``next_index``."""
        self._next = int(next_index)
        self._next_block = self._next // self.block
        # Samples of the incomplete block (earlier samples of it count as zero).
        self._carry = np.zeros(self._next - self._next_block * self.block, dtype=np.complex128)
        n_cells = self.n_hyp * self.n_tones
        self._cum = np.zeros((2, n_cells))
        self._cum_ring = np.zeros((self._h_cum, 2, n_cells))
        self._g_ring = np.zeros((self.n_hyp, self._h_g))
        self._uacc_ring = np.zeros((self.n_hyp, self._h_cum))
        self._frame_rot = np.zeros((2, n_cells))

    @property
    def next_block(self) -> int:
        """Absolute index of the next block to be completed."""
        return self._next_block

    def process(self, y: ArrayLike) -> CoarseBlocks:
        """Consume complex baseband samples ``y`` (shape ``(n,)``); the blocks they complete
        (:class:`CoarseBlocks`)."""
        ys = np.asarray(y, dtype=np.complex128).reshape(-1)
        self._next += ys.shape[0]
        buf = np.concatenate((self._carry, ys)) if self._carry.size else ys
        nb = buf.shape[0] // self.block
        used = nb * self.block
        self._carry = buf[used:].copy()
        b0 = self._next_block
        s = np.empty(nb)
        d_hat = np.empty(nb, dtype=np.int64)
        noise = np.empty(nb)
        acc = np.empty((nb, self.n_hyp))
        if nb:
            coarse_search(
                np.ascontiguousarray(buf[:used]), b0, self.block, *self._within, *self._step,
                self._cycles_per_block, FRAME_BLOCKS, self.block_lengths, self.n_tones,
                self.comb_lags, self._cell_w, self._hyp_w, self.noise_every, self._noise_scale,
                self._cum, self._cum_ring, self._g_ring, self._uacc_ring, self.shortlist,
                self.peak_lobe, self.peak_count, self._frame_rot, s, d_hat, noise, acc,
            )  # fmt: skip
            self._next_block += nb
        return CoarseBlocks(s, d_hat, noise, b0, acc)
