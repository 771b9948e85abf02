"""Unit Doppler correlators: one heterodyne + moving sum per (hypothesis, tone) (SPEC §3.1).

For complex baseband samples ``x[n]`` at ``fs`` (Hz) the bank computes, for every hypothesis
``d`` (``D`` of them) and tone ``k`` (``K`` of them),

    u[n, d, k] = Σ_{i<N_d} x[n − i] · exp(−j2π ν[d, k] (n − i) / fs)

with ``ν[d, k]`` the baseband frequency of the correlator (Hz; for GCAS
``ν = α_d f_k − f_c``) and ``N_d`` its window length in samples. ``n`` is the *absolute*
baseband sample index (counted from the first sample after the last :meth:`reset`, gaps
included), so the heterodyne phase — and therefore the output — is independent of how the
input is cut into blocks: any chunking gives bit-identical output.

Cost is O(1) per sample per (d, k): the moving sum is a difference of cumulative sums. The
cumulative sums are re-anchored every ``anchor`` samples of the absolute index (the running
value is subtracted from the carried history), so their magnitude stays bounded and single
precision does not drift on long streams. The heterodyne phasor of sample ``n`` is the product
``base[n // cell] · step[n % cell]`` of two precomputed tables (no transcendental function per
sample), again a function of ``n`` only.

This module is shared: GCAS uses it with ``D`` Doppler hypotheses; the JIFS receiver with its
own grid. Inputs are ``complex`` arrays of shape ``(n,)``; outputs ``complex64`` arrays of shape
``(n, D, K)``.

Examples
--------
>>> import numpy as np
>>> bank = UnitCorrelatorBank(1000.0, [[100.0, 200.0]], [10])
>>> x = np.exp(2j * np.pi * 100.0 * np.arange(30) / 1000.0)
>>> u = bank.process(x)
>>> u.shape
(30, 1, 2)
>>> np.round(np.abs(u[9:12, 0, :]), 4).tolist()  # window full from sample 9 on
[[10.0, 0.0], [10.0, 0.0], [10.0, 0.0]]
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError

Complex64Array = NDArray[np.complex64]

#: Default phasor-table length, samples.
DEFAULT_CELL = 1024
#: Default re-anchoring period of the cumulative sums, samples (a multiple of the cell).
DEFAULT_ANCHOR = 4096


class UnitCorrelatorBank:
    """A bank of ``D × K`` heterodyne moving-sum correlators with explicit state.

    Parameters
    ----------
    fs_hz:
        Sample rate of the complex input, Hz.
    freqs_hz:
        Correlator frequencies ``ν[d, k]``, Hz, shape ``(D, K)`` (must lie within ±fs/2).
    lengths:
        Window length ``N_d`` per hypothesis, samples, shape ``(D,)``, each >= 1.
    cell:
        Phasor-table length, samples.
    anchor:
        Re-anchoring period of the cumulative sums, samples; a multiple of ``cell``.
    """

    def __init__(
        self,
        fs_hz: float,
        freqs_hz: ArrayLike,
        lengths: ArrayLike,
        *,
        cell: int = DEFAULT_CELL,
        anchor: int = DEFAULT_ANCHOR,
    ) -> None:
        if not (math.isfinite(fs_hz) and fs_hz > 0):
            raise ConfigError("fs_hz", fs_hz, "> 0 Hz")
        nu = np.asarray(freqs_hz, dtype=np.float64)
        if nu.ndim != 2 or nu.size == 0 or not np.all(np.isfinite(nu)):
            raise ConfigError("freqs_hz", f"shape {nu.shape}", "a finite (D, K) array in Hz")
        if np.any(np.abs(nu) > fs_hz / 2):
            raise ConfigError(
                "freqs_hz",
                float(np.max(np.abs(nu))),
                f"|ν| <= fs/2 = {fs_hz / 2:g} Hz",
                "lower the decimation so the baseband rate covers the Doppler span",
            )
        lens = np.asarray(lengths)
        if lens.shape != (nu.shape[0],) or np.any(lens < 1) or np.any(lens != np.round(lens)):
            raise ConfigError("lengths", lens.tolist(), f"{nu.shape[0]} integers >= 1")
        if cell < 1 or anchor < cell or anchor % cell:
            raise ConfigError("anchor", anchor, f"a positive multiple of cell = {cell}")
        self.fs_hz = float(fs_hz)
        self.freqs_hz = nu
        self.lengths = lens.astype(np.int64)
        self.n_hyp, self.n_tones = nu.shape
        self.max_length = int(self.lengths.max())
        self.cell = int(cell)
        self.anchor = int(anchor)
        # Hypotheses grouped by window length: contiguous runs become slices (cheap views).
        self._groups: list[tuple[int, slice | NDArray[np.int64]]] = []
        for n_len in np.unique(self.lengths):
            idx = np.flatnonzero(self.lengths == n_len)
            contiguous = idx[-1] - idx[0] + 1 == idx.shape[0]
            sel: slice | NDArray[np.int64] = (
                slice(int(idx[0]), int(idx[-1]) + 1) if contiguous else idx
            )
            self._groups.append((int(n_len), sel))
        m = np.arange(self.cell, dtype=np.float64)
        cyc = np.mod(m[:, None, None] * (nu / self.fs_hz)[None, :, :], 1.0)
        # (D, K, cell): samples last, so the running sums run along contiguous memory.
        self._step = np.ascontiguousarray(
            np.exp(-2j * np.pi * cyc).astype(np.complex64).transpose(1, 2, 0)
        )
        self._cell_index = -1
        self._cell_phasor = self._step
        self.reset(0)

    # ------------------------------------------------------------------ state
    def reset(self, next_index: int = 0) -> None:
        """Forget all sums; the next input sample has absolute index ``next_index``."""
        self._next = int(next_index)
        self._chist = np.zeros((self.n_hyp, self.n_tones, self.max_length), dtype=np.complex64)

    @property
    def next_index(self) -> int:
        """Absolute index of the next input sample."""
        return self._next

    def _phasor(self, c: int) -> Complex64Array:
        if c != self._cell_index:
            cyc = np.mod(float(c * self.cell) * (self.freqs_hz / self.fs_hz), 1.0)
            base = np.exp(-2j * np.pi * cyc).astype(np.complex64)
            self._cell_phasor = self._step * base[:, :, None]
            self._cell_index = c
        return self._cell_phasor

    # ------------------------------------------------------------------ processing
    def process(self, x: ArrayLike) -> Complex64Array:
        """Consume complex samples ``x`` (shape ``(n,)``); return ``u``, shape ``(n, D, K)``."""
        return np.ascontiguousarray(self.process_last(x).transpose(2, 0, 1))

    def process_last(self, x: ArrayLike) -> Complex64Array:
        """As :meth:`process` with samples on the last axis: ``u``, shape ``(D, K, n)``."""
        xs = np.asarray(x).reshape(-1)
        n_total = xs.shape[0]
        out = np.empty((self.n_hyp, self.n_tones, n_total), dtype=np.complex64)
        pos = 0
        while pos < n_total:
            a = self._next
            c = a // self.cell
            b = min(a + (n_total - pos), (c + 1) * self.cell)
            self._piece(xs[pos : pos + b - a], out[:, :, pos : pos + b - a], c, a - c * self.cell)
            pos += b - a
        return out

    def power(self, x: ArrayLike) -> NDArray[np.float32]:
        """``|u|²`` for new samples ``x``, float32, shape ``(n, D, K)``."""
        u = self.process(x)
        return np.square(u.real) + np.square(u.imag)

    def _piece(self, x: NDArray[np.generic], out: Complex64Array, c: int, off: int) -> None:
        """Samples within one phasor cell, starting at offset ``off`` in the cell; ``out`` has
        shape ``(D, K, n)``."""
        n = x.shape[0]
        hist_len = self.max_length
        ext = np.empty((self.n_hyp, self.n_tones, hist_len + n), dtype=np.complex64)
        ext[:, :, :hist_len] = self._chist
        y = ext[:, :, hist_len:]
        np.multiply(self._phasor(c)[:, :, off : off + n], x.astype(np.complex64), out=y)
        # Sequential accumulation from the carried value: C[n] = C[n−1] + y[n] exactly, so any
        # split of the stream gives the same bits.
        y[:, :, 0] += self._chist[:, :, -1]
        np.cumsum(y, axis=2, out=y)
        for n_len, sel in self._groups:
            out[sel] = (
                ext[sel, :, hist_len : hist_len + n]
                - ext[sel, :, hist_len - n_len : hist_len - n_len + n]
            )
        self._chist = ext[:, :, ext.shape[2] - hist_len :].copy()
        self._next += n
        if self._next % self.anchor == 0:
            # Re-anchor: only differences of C are used, so subtracting the running value from
            # every carried entry changes nothing but the magnitude the sums grow to.
            self._chist -= self._chist[:, :, -1:].copy()
