"""Map board sample indices to host time: a least-squares line through SYNC pairs.

Each SYNC the board sends pairs a sample index with the board's time; the host pairs the
same index with its own clock when the SYNC arrives. Transport latency adds a small,
mostly constant delay and some jitter; a straight-line fit ``t = t0 + (index - i0) / rate``
over many pairs averages the jitter and measures the true rate of the board's oscillator
against the host clock. The experiment runner maps stage telemetry (host time) onto sample
time with :meth:`SampleClockFit.sample_index` and samples onto host time with
:meth:`SampleClockFit.host_time`.
"""

from __future__ import annotations

import threading
from collections import deque

import numpy as np

from hil.errors import ConfigError


class SampleClockFit:
    """Least-squares fit of host time (s) against board sample index.

    Parameters
    ----------
    nominal_rate_hz:
        The configured sample rate, Hz: used until two pairs are known.
    max_pairs:
        Most recent pairs kept (older ones are forgotten, so slow drift is tracked).

    Examples
    --------
    >>> fit = SampleClockFit(1_000_000.0)
    >>> for k in range(5):
    ...     fit.add(k * 100_000, 10.0 + k * 0.1 * (1 + 20e-6))  # board 20 ppm slow
    >>> round(fit.rate_hz, 3), round(fit.host_time(250_000), 9)
    (999980.0, 10.250005)
    >>> fit.sample_index(10.250005)
    250000
    """

    def __init__(self, nominal_rate_hz: float, max_pairs: int = 256) -> None:
        if not nominal_rate_hz > 0:
            raise ConfigError("nominal_rate_hz", nominal_rate_hz, "> 0 Hz")
        if max_pairs < 2:
            raise ConfigError("max_pairs", max_pairs, ">= 2")
        self.nominal_rate_hz = float(nominal_rate_hz)
        self._pairs: deque[tuple[int, float]] = deque(maxlen=max_pairs)
        self._lock = threading.Lock()
        self._fit: tuple[float, float, float] | None = None  # (i0, t0, seconds per sample)

    def add(self, sample_index: int, host_time_s: float) -> None:
        """Record one (sample index, host time in s) pair and refit."""
        with self._lock:
            self._pairs.append((int(sample_index), float(host_time_s)))
            self._fit = self._solve()

    @property
    def pairs(self) -> int:
        """Number of pairs in the fit."""
        return len(self._pairs)

    def pair_list(self) -> list[tuple[int, float]]:
        """The pairs in the fit, oldest first: ``(sample_index, host_time_s)``. The fit keeps
        only the latest ``max_pairs``; a copy, safe while another thread adds pairs."""
        with self._lock:
            return list(self._pairs)

    def _solve(self) -> tuple[float, float, float]:
        idx = np.array([p[0] for p in self._pairs], dtype=np.float64)
        t = np.array([p[1] for p in self._pairs])
        i0, t0 = float(idx.mean()), float(t.mean())
        di = idx - i0
        denom = float(di @ di)
        slope = float(di @ (t - t0)) / denom if denom > 0 else 1.0 / self.nominal_rate_hz
        return i0, t0, slope

    def _params(self) -> tuple[float, float, float]:
        if self._fit is None:
            raise ConfigError(
                "sync pairs", 0, ">= 1", "wait for the board's first SYNC (start the stream)"
            )
        return self._fit

    @property
    def rate_hz(self) -> float:
        """Board sample rate measured on the host clock, Hz."""
        return 1.0 / self._params()[2]

    def host_time(self, sample_index: float) -> float:
        """Host time (s) at which board sample ``sample_index`` was taken."""
        i0, t0, slope = self._params()
        return t0 + (sample_index - i0) * slope

    def sample_index(self, host_time_s: float) -> int:
        """Nearest board sample index at host time ``host_time_s`` (s)."""
        i0, t0, slope = self._params()
        return round(i0 + (host_time_s - t0) / slope)

    def residuals_s(self) -> np.ndarray:
        """Host time minus the fit at every pair (s): the transport's jitter."""
        i0, t0, slope = self._params()
        with self._lock:
            idx = np.array([p[0] for p in self._pairs], dtype=np.float64)
            t = np.array([p[1] for p in self._pairs])
        return t - (t0 + (idx - i0) * slope)
