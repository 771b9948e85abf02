"""Full linear convolution with one fixed response, its spectrum computed once per FFT length.

:func:`scipy.signal.oaconvolve` of a block ``x`` (shape ``(s1,)``) with a response ``h``
(``(s2,)``) falls back to a single FFT product whenever the shorter is at least half the
longer: ``irfftn(rfftn(x, L) · rfftn(h, L), L)[:s1 + s2 − 1]`` with ``L`` the next fast length
of ``s1 + s2 − 1``. A stream that convolves frame after frame with the same ``h`` (the tank's
own echoes, :class:`~sim_devices.acoustics.tank_response.TankEchoes`) recomputes ``rfftn(h, L)``
every frame: a third of the work. :class:`FixedResponseConvolver` keeps it per ``L`` and runs
the same calls in the same order otherwise, so its output is ``oaconvolve(x, h)`` bit for bit;
for shapes that oaconvolve cuts into blocks it calls oaconvolve.

>>> rng = np.random.default_rng(0)
>>> h = rng.standard_normal(300)
>>> conv = FixedResponseConvolver(h)
>>> x = rng.standard_normal(512)
>>> bool(np.array_equal(conv(x), oaconvolve(x, h))), bool(np.array_equal(conv(x), oaconvolve(x, h)))
(True, True)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy import fft as sp_fft
from scipy.signal import oaconvolve

from hil.errors import ConfigError
from sim_devices.acoustics.trajectory import FloatArray


class FixedResponseConvolver:
    """``oaconvolve(x, h)`` (``mode="full"``) for real float64 blocks ``x`` (shape ``(n,)``)
    and the fixed real response ``h`` (shape ``(m,)``, m >= 1), bit for bit (see the module
    docstring); the spectrum of ``h`` is kept for each FFT length met."""

    def __init__(self, h: ArrayLike) -> None:
        self.h = np.asarray(h, dtype=np.float64).reshape(-1)
        if self.h.size < 1:
            raise ConfigError("h", self.h.shape, "at least one tap")
        self._spectra: dict[int, np.ndarray] = {}

    def __call__(self, x: FloatArray) -> FloatArray:
        """``x * h``, shape ``(n + m − 1,)``."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        s1, s2 = x.size, self.h.size
        # The shapes for which oaconvolve takes one FFT product (its _calc_oa_lens fallback):
        # equal lengths, or the shorter at least half the longer. Length 1 and empty inputs
        # take oaconvolve's own special cases.
        if min(s1, s2) <= 1 or not (s1 == s2 or min(s1, s2) >= max(s1, s2) / 2):
            return np.asarray(oaconvolve(x, self.h), dtype=np.float64)
        full = s1 + s2 - 1
        size = sp_fft.next_fast_len(full, True)
        spectrum = self._spectra.get(size)
        if spectrum is None:
            spectrum = sp_fft.rfftn(self.h, [size], axes=[0])
            self._spectra[size] = spectrum
        out = sp_fft.irfftn(sp_fft.rfftn(x, [size], axes=[0]) * spectrum, [size], axes=[0])
        return np.array(out[:full])
