"""Fast evaluation of the transmit signal at non-decreasing times (echo and reverberation hot path).

:meth:`HopSchedule.evaluate <hil.signals.schedule.HopSchedule.evaluate>` locates the hop of
every time with a search and takes a float64 cosine per sample (about 50 ns per sample). The
times an echo reads (emission times of consecutive receive samples) are sorted, so here the
hops overlapping the span are looked up once (from a cached window), each hop's first sample
is found by one ``searchsorted``, and within a hop the phase is

    Φ = φ_h + 2π (f_h τ + ½ k_h τ²),   τ = t − t_h,

formed in cycles in float64, reduced to ``[−½, ½]`` cycle and only then rounded to float32
for a float32 cosine (vectorised, about 20x faster than float64's). The result is ``s(t)``
to float32 precision: at most 3e-7 of the amplitude off the exact
:meth:`~hil.signals.schedule.HopSchedule.evaluate` (half a float32 ulp of a phase in
``[−π, π]`` plus the cosine's own error; −130 dB, below a 24-bit ADC's step).

A time within :data:`~hil.signals.schedule.BOUNDARY_SNAP_S` before a hop start belongs to the
new hop, as in :meth:`~hil.signals.schedule.HopSchedule.locate`. The value at ``t[i]`` depends
on ``t[i]`` alone (given sorted ``t``), so block-wise callers stay chunking-invariant.

A waveform that is not a :class:`~hil.signals.schedule.HopSchedule` is evaluated with its
own ``evaluate`` (exact, float64).

>>> from hil.signals.schedule import HopSchedule
>>> sch = HopSchedule.from_segments("demo", [1000.0, 2000.0], [0, 1], 0.001)
>>> t = np.linspace(0.0, 0.004, 41)
>>> bool(np.max(np.abs(TransmitEvaluator(sch).at_sorted_times(t) - sch.evaluate(t))) < 3e-7)
True
"""

from __future__ import annotations

import math
from bisect import bisect_right
from itertools import pairwise
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.signals.schedule import BOUNDARY_SNAP_S, HopSchedule, HopTable
from sim_devices.acoustics.echo import TransmitWaveform
from sim_devices.acoustics.trajectory import FloatArray

#: Largest error of :meth:`TransmitEvaluator.at_sorted_times` against the exact evaluation,
#: as a fraction of the hop amplitude (float32 phase rounding and cosine).
FLOAT32_TRANSMIT_ERROR = 3e-7

#: Average samples per hop from which hops are processed one by one rather than by repetition.
LONG_HOP_SAMPLES = 2048
#: Hops fetched from the schedule at a time (and cached).
HOP_WINDOW = 64

_TWO_PI_F32 = np.float32(2.0 * math.pi)


class HopWindow:
    """Consecutive hops ``first … first + len − 1`` as the arrays the evaluation uses."""

    def __init__(self, hops: HopTable) -> None:
        self.first = int(hops.index[0])
        self.size = len(hops)
        self.start_s = hops.start_s
        self.snap_start_s = hops.start_s - BOUNDARY_SNAP_S
        self.freq_hz = hops.freq_hz
        self.half_chirp = 0.5 * hops.chirp_hz_per_s
        self.phase_cycles = hops.phase_rad * (1.0 / (2.0 * math.pi))
        self.amplitude = hops.amplitude.astype(np.float32)
        # Whole-window flags: computing a zero chirp term, or scaling by 1, changes no bit.
        self.chirped = bool(np.any(hops.chirp_hz_per_s != 0.0))
        self.unit = bool(np.all(hops.amplitude == 1.0))


class TransmitEvaluator:
    """``s(t)`` of ``waveform`` at sorted times; see the module docstring."""

    def __init__(self, waveform: TransmitWaveform) -> None:
        self.waveform = waveform
        self.schedule = waveform if isinstance(waveform, HopSchedule) else None
        if self.schedule is not None:
            self._starts = self.schedule.start_s.tolist()
        self._window: HopWindow | None = None

    def _hop_index(self, t: float) -> int:
        """Global index of the hop sounding at ``t`` (s), possibly off by one at a boundary."""
        sch = self.schedule
        assert sch is not None
        period = sch.period_s
        rel = t - sch.t0_s
        q = math.floor(rel / period)
        r = bisect_right(self._starts, rel - q * period) - 1
        return q * sch.period_hops + min(max(r, 0), sch.period_hops - 1)

    def _hops_covering(self, t_first: float, t_last: float) -> tuple[HopWindow, int, int]:
        """A window of hops and the range ``[a, b)`` in it that includes every hop sounding
        in ``[t_first, t_last]`` (s); one schedule look-up per :data:`HOP_WINDOW` hops."""
        assert self.schedule is not None
        first = self._hop_index(t_first) - 2
        last = self._hop_index(t_last) + 2
        win = self._window
        if win is None or first < win.first or last >= win.first + win.size:
            win = HopWindow(self.schedule.hops(first, max(HOP_WINDOW, last - first + 1)))
            self._window = win
        return win, first - win.first, last - win.first + 1

    def hop_window(self, t_first: float, t_last: float) -> tuple[HopWindow, int, int]:
        """The hops of the schedule sounding in ``[t_first, t_last]`` (s): a window and the
        range ``[a, b)`` in it that holds them (for a hop schedule only)."""
        return self._hops_covering(t_first, t_last)

    def at_sorted_times(self, t: FloatArray) -> NDArray[np.floating[Any]]:
        """``s(t)`` (dimensionless) at non-decreasing times ``t`` (s), shape ``(n,)``.

        float32 for a hop schedule (error at most :data:`FLOAT32_TRANSMIT_ERROR` of the
        amplitude), float64 (exact) for any other waveform.
        """
        if self.schedule is None:
            return np.asarray(self.waveform.evaluate(t), dtype=np.float64)
        n = t.shape[0]
        out = np.empty(n, dtype=np.float32)
        if n == 0:
            return out
        win, a, b = self._hops_covering(float(t[0]), float(t[-1]))
        first = np.searchsorted(t, win.snap_start_s[a + 1 : b], side="left").tolist()
        bounds = [0, *first, n]
        runs = [(a + i, lo, hi) for i, (lo, hi) in enumerate(pairwise(bounds)) if hi > lo]
        if n >= LONG_HOP_SAMPLES * len(runs):
            cyc = _cycles_by_hop(t, win, runs)
        else:
            cyc = _cycles_repeated(t, win, a, b, np.diff(np.asarray(bounds)))
        cyc -= np.rint(cyc)
        out[...] = cyc
        out *= _TWO_PI_F32
        np.cos(out, out=out)
        if not win.unit:
            for j, lo, hi in runs:
                out[lo:hi] *= win.amplitude[j]
        return out


# Two layouts of the same per-sample arithmetic (so the values never depend on which one a
# call takes): a loop over long hops, or the hop parameters repeated per sample.
def _cycles_by_hop(t: FloatArray, win: HopWindow, runs: list[tuple[int, int, int]]) -> FloatArray:
    """Phase in cycles, ``φ/2π + f τ + ½ k τ²`` (``τ = t − t_hop``), hop by hop."""
    cyc = np.empty(t.shape[0])
    for j, lo, hi in runs:
        seg = cyc[lo:hi]
        np.subtract(t[lo:hi], win.start_s[j], out=seg)
        if win.chirped:
            rate = seg * win.half_chirp[j]  # f τ + ½ k τ² = τ (f + ½ k τ)
            rate += win.freq_hz[j]
            seg *= rate
        else:
            seg *= win.freq_hz[j]
        seg += win.phase_cycles[j]
    return cyc


def _cycles_repeated(
    t: FloatArray, win: HopWindow, a: int, b: int, counts: NDArray[np.intp]
) -> FloatArray:
    """Phase in cycles with the hop parameters repeated per sample (many short hops)."""
    cyc = t - np.repeat(win.start_s[a:b], counts)
    if win.chirped:
        rate = np.repeat(win.half_chirp[a:b], counts)
        rate *= cyc
        rate += np.repeat(win.freq_hz[a:b], counts)
        cyc *= rate
    else:
        cyc *= np.repeat(win.freq_hz[a:b], counts)
    cyc += np.repeat(win.phase_cycles[a:b], counts)
    return cyc
