"""Streaming complex baseband: mix a real input down by ``f_c``, low-pass, decimate by ``R``.

Baseband sample ``n`` is computed at input sample ``n·R`` (absolute index, counted from the
first input sample, gaps included) as

    y[n] = Σ_{i<T} h[i] · x[nR − i] · exp(−j2π f_c (nR − i)/fs)
         = exp(−j2π f_c nR/fs) · Σ_{i<T} (h[i] e^{+j2π f_c i/fs}) · x[nR − i]

with ``h`` a linear-phase (Kaiser-window) low-pass of ``T`` taps. The second form applies
complex taps to the real input and rotates only the decimated outputs, so the front end costs
``T/R`` complex taps per input sample and no transcendental function per input sample. The
output rotation uses the absolute index ``n`` (reduced in cycles, ``frac(n·f_c·R/fs)``), so the
output does not depend on how the input is cut into blocks.

Time of baseband sample ``n``: the filter delays by ``(T − 1)/2`` input samples, so ``y[n]``
is the complex envelope ``z(t)`` of the input at

    t_n = (n·R − (T − 1)/2) / fs   [s],    z(t) = ½ r_a(t) e^{−j2π f_c t}

(``r_a`` the analytic signal of the real input). :meth:`ComplexBaseband.time_of` returns it;
every receiver time is derived from it, which compensates the group delay exactly.

Samples before the first input sample (or before a reset after a gap) count as zero.

Examples
--------
>>> import numpy as np
>>> bb = ComplexBaseband(100_000.0, 30_000.0, decimation=10, passband_hz=3000.0)
>>> n = np.arange(20_000)
>>> y = bb.process(np.cos(2 * np.pi * 31_000.0 * n / 100_000.0))  # a tone 1 kHz above f_c
>>> y.shape, bb.fs_out_hz
((2000,), 10000.0)
>>> t = bb.time_of(np.arange(1000, 1004))
>>> bool(np.allclose(y[1000:1004], 0.5 * np.exp(2j * np.pi * 1000.0 * t), atol=1e-3))
True
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from hil.estimation.bessel_i0 import bessel_i0
from hil.estimation.kernels import mix_down

ComplexArray = NDArray[np.complex128]
FloatArray = NDArray[np.float64]


def design_lowpass(
    fs_hz: float, passband_hz: float, stopband_hz: float, attenuation_db: float = 70.0
) -> FloatArray:
    """Linear-phase Kaiser low-pass taps (odd length, unit DC gain), shape ``(T,)``.

    ``passband_hz`` is the highest frequency passed (gain within 1e-3 of 1), ``stopband_hz``
    the lowest frequency attenuated by ``attenuation_db``.

    >>> h = design_lowpass(100_000.0, 3000.0, 7000.0)
    >>> h.shape[0] % 2, round(float(h.sum()), 12)
    (1, 1.0)
    """
    if not (0 < passband_hz < stopband_hz <= fs_hz / 2):
        raise ConfigError(
            "passband_hz",
            passband_hz,
            f"0 < passband < stopband = {stopband_hz} <= fs/2 = {fs_hz / 2} Hz",
            "raise the sample rate or lower the decimation",
        )
    width = (stopband_hz - passband_hz) / (fs_hz / 2)
    numtaps, beta = kaiser_order(attenuation_db, width)
    numtaps |= 1  # odd: an integer group delay when T − 1 is even
    cutoff = 0.5 * (passband_hz + stopband_hz)
    return kaiser_lowpass(numtaps, cutoff / (fs_hz / 2), beta)


def kaiser_order(attenuation_db: float, width: float) -> tuple[int, float]:
    """Taps and Kaiser ``β`` of a lowpass with ``attenuation_db`` (dB, at least 8) of stopband
    attenuation and a transition ``width`` (fraction of Nyquist): Kaiser's formulas as in
    Oppenheim & Schafer, the numbers ``scipy.signal.kaiserord`` gives (written here so a
    receiver is built without importing ``scipy.signal``, whose import alone takes about a
    second)."""
    a = abs(attenuation_db)
    if a < 8:
        raise ConfigError("attenuation_db", attenuation_db, "at least 8 dB (Kaiser's formula)")
    if a > 50:
        beta = 0.1102 * (a - 8.7)
    elif a > 21:
        beta = 0.5842 * (a - 21) ** 0.4 + 0.07886 * (a - 21)
    else:
        beta = 0.0
    return int(math.ceil((a - 7.95) / 2.285 / (np.pi * width) + 1)), beta


def kaiser_lowpass(numtaps: int, cutoff: float, beta: float) -> NDArray[np.float64]:
    """Windowed-sinc lowpass taps (shape ``(numtaps,)``, unit gain at DC) with its cutoff at
    ``cutoff`` (fraction of Nyquist) and a Kaiser window of ``β``: the taps
    ``scipy.signal.firwin(numtaps, cutoff, window=("kaiser", beta))`` gives, bit for bit
    (same operations in the same order, with :func:`~hil.estimation.bessel_i0.bessel_i0`
    equal to ``scipy.special.i0`` to the last bit; tested against it)."""
    alpha = 0.5 * (numtaps - 1)
    m = np.arange(0, numtaps, dtype=np.float64) - alpha
    y = np.pi * np.where(cutoff * m != 0, cutoff * m, np.finfo(np.float64).eps)
    h = cutoff * (np.sin(y) / y)
    if numtaps <= 1:
        return h / np.sum(h)
    n = np.arange(0, numtaps, dtype=np.float64)
    half = (numtaps - 1) / 2.0
    h *= bessel_i0(beta * np.sqrt(1 - ((n - half) / half) ** 2.0)) / bessel_i0(
        np.asarray(beta, dtype=np.float64)
    )
    h /= np.sum(h * np.cos(np.pi * m * 0.0))
    return h


class ComplexBaseband:
    """Streaming mixer + FIR low-pass + decimator with explicit state (see module docstring).

    Parameters
    ----------
    fs_hz:
        Input sample rate, Hz.
    center_hz:
        Mixing frequency f_c, Hz.
    decimation:
        Integer decimation R; the output rate is ``fs_hz / R``.
    passband_hz:
        Highest baseband frequency (Hz, one-sided) that must pass: the band of interest
        ``B_w/2`` plus the Doppler span. The stop band starts at ``fs/R − passband_hz``, where
        aliases would land back inside the passband.
    attenuation_db:
        Stop-band attenuation of the low-pass, dB.
    taps:
        Explicit real low-pass taps (odd length) instead of the Kaiser design.
    """

    def __init__(
        self,
        fs_hz: float,
        center_hz: float,
        *,
        decimation: int,
        passband_hz: float,
        attenuation_db: float = 70.0,
        taps: ArrayLike | None = None,
    ) -> None:
        if not (math.isfinite(fs_hz) and fs_hz > 0):
            raise ConfigError("fs_hz", fs_hz, "> 0 Hz")
        if not (math.isfinite(center_hz) and 0 <= center_hz < fs_hz / 2):
            raise ConfigError("center_hz", center_hz, f"0 <= f_c < fs/2 = {fs_hz / 2} Hz")
        if int(decimation) != decimation or decimation < 1:
            raise ConfigError("decimation", decimation, "an integer >= 1")
        self.fs_hz = float(fs_hz)
        self.center_hz = float(center_hz)
        self.decimation = int(decimation)
        self.fs_out_hz = self.fs_hz / self.decimation
        if taps is None:
            stop = min(self.fs_out_hz - passband_hz, self.fs_hz / 2)
            if not stop > passband_hz:
                raise ConfigError(
                    "decimation",
                    decimation,
                    f"<= {int(self.fs_hz / (2 * passband_hz))} so that fs/R = "
                    f"{self.fs_out_hz:g} Hz exceeds twice the passband {passband_hz:g} Hz",
                    "lower the decimation",
                )
            h = design_lowpass(self.fs_hz, passband_hz, stop, attenuation_db)
        else:
            h = np.asarray(taps, dtype=np.float64).reshape(-1)
            if h.shape[0] % 2 == 0 or not np.all(np.isfinite(h)):
                raise ConfigError("taps", f"{h.shape[0]} taps", "an odd number of finite taps")
        self.passband_hz = float(passband_hz)
        self.taps = h
        self.n_taps = int(h.shape[0])
        #: Group delay of the low-pass, input samples.
        self.group_delay = (self.n_taps - 1) / 2.0
        i = np.arange(self.n_taps, dtype=np.float64)
        rot = np.exp(2j * np.pi * np.mod(i * self.center_hz / self.fs_hz, 1.0))
        # Reversed so that a window x[p−T+1 .. p] (oldest first) dots with it directly.
        g = (h * rot)[::-1]
        self._g_re = np.ascontiguousarray(g.real)
        self._g_im = np.ascontiguousarray(g.imag)
        self._cycles_per_output = self.center_hz * self.decimation / self.fs_hz
        self.reset(0)

    # ------------------------------------------------------------------ state
    def reset(self, next_input_index: int = 0) -> None:
        """Forget the filter history; the next input sample has index ``next_input_index``."""
        self._hist = np.zeros(self.n_taps - 1)
        self._next_in = int(next_input_index)

    @property
    def next_input_index(self) -> int:
        """Absolute index of the next input sample."""
        return self._next_in

    @property
    def next_output_index(self) -> int:
        """Absolute index of the next baseband sample to be produced."""
        return -(-self._next_in // self.decimation)

    def time_of(self, n: ArrayLike) -> FloatArray:
        """Time (s) of baseband samples ``n`` (group delay compensated), same shape as ``n``."""
        nn = np.asarray(n, dtype=np.float64)
        return (nn * self.decimation - self.group_delay) / self.fs_hz

    # ------------------------------------------------------------------ processing
    def process(self, block: ArrayLike) -> ComplexArray:
        """Consume real input samples (shape ``(m,)``); return the new baseband samples.

        Output sample ``k`` of the result has absolute index ``first + k`` where ``first`` is
        :attr:`next_output_index` before the call.
        """
        x = np.asarray(block, dtype=np.float64).reshape(-1)
        start = self._next_in
        buf = np.concatenate((self._hist, x))
        # buf[q] is absolute input index start − (T − 1) + q.
        end = start + x.shape[0]
        first = -(-start // self.decimation)
        last = (end - 1) // self.decimation if end > 0 else -1
        keep = self.n_taps - 1
        self._hist = buf[buf.shape[0] - keep :].copy() if keep else np.zeros(0)
        self._next_in = end
        if last < first:
            return np.zeros(0, dtype=np.complex128)
        # Window for output n ends at absolute input index nR: buf position nR − start + T − 1,
        # so it starts at nR − start.
        lo = first * self.decimation - start
        # Compiled dot products in a fixed order per output, and the rotation as real products
        # and sums each rounded once (IEEE): chunking cannot change a bit. (NumPy's complex
        # multiply rounds differently in its in-place loop, which it takes by itself for a
        # temporary over 256 KiB, so an output's last bit would depend on the block's size.)
        out = np.empty(last + 1 - first, dtype=np.complex128)
        mix_down(
            buf, lo, out.shape[0], self.decimation, self._g_re, self._g_im, first,
            self._cycles_per_output, out,
        )  # fmt: skip
        return out
