"""The exact phase of a hop schedule at consecutive sample indices, in one compiled loop.

:meth:`HopSchedule.instantaneous_phase <hil.signals.schedule.HopSchedule.instantaneous_phase>`
at the times ``n / fs`` of samples ``n0 … n0 + count − 1`` is a dozen NumPy passes over
temporaries (the period split, the boundary snap, a search, the gathers, the reduction mod
2π): about 50 ns a sample. The tank's own echoes convolve that transmit frame by frame
(:class:`~sim_devices.acoustics.tank_response.TankEchoes`), so it is their largest cost after
the FFTs. :func:`sample_phases` runs the same per-sample arithmetic in one loop (numba).

Same bits as the NumPy form: every output is the same sequence of IEEE operations in the same
order (``n / fs``; ``floor``; the fold and snap of ``HopSchedule._split``; the hop found as
:func:`numpy.searchsorted` ``side="right"`` finds it; the reduction as :func:`numpy.mod`
computes it for floats, ``fmod`` and a sign fix-up; then ``base + 2π (f τ + ½ k τ τ)`` left to
right), compiled without ``fastmath`` (no reassociation, no fused multiply-add). The cosine is
left to NumPy (its values are the reference). Compiled with ``cache=True`` (see
:mod:`~sim_devices.acoustics.reverb_kernels`).

>>> from hil.signals.schedule import HopSchedule
>>> sch = HopSchedule.from_segments("demo", [1000.0, 2000.0], [0, 1], 0.001)
>>> n = np.arange(-50, 450)
>>> bool(np.array_equal(sample_phases(sch, -50, 500, 1e5), sch.instantaneous_phase(n / 1e5)))
True
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from hil.signals.schedule import BOUNDARY_SNAP_S, TWO_PI, HopSchedule
from sim_devices.acoustics.trajectory import FloatArray

_JIT: dict[str, Any] = {"cache": True, "nogil": True}


def sample_phases(schedule: HopSchedule, n0: int, count: int, fs_hz: float) -> FloatArray:
    """``schedule.instantaneous_phase(n / fs_hz)`` (rad) for ``n = n0 … n0 + count − 1``
    (any ``n0``, negative too), bit for bit; shape ``(count,)``."""
    out = np.empty(int(count))
    _phases(
        int(n0), float(fs_hz), float(schedule.t0_s), float(schedule.period_s),
        np.ascontiguousarray(schedule.start_s, dtype=np.float64),
        np.ascontiguousarray(schedule.phase_rad, dtype=np.float64),
        float(schedule.period_phase_rad),
        np.ascontiguousarray(schedule.freq_hz, dtype=np.float64),
        np.ascontiguousarray(schedule.chirp_hz_per_s, dtype=np.float64),
        BOUNDARY_SNAP_S, TWO_PI, out,
    )  # fmt: skip
    return out


@numba.njit(**_JIT)
def _phases(
    n0: int,
    fs: float,
    t0: float,
    period: float,
    start_s: Any,
    phase_rad: Any,
    period_phase: float,
    freq_hz: Any,
    chirp: Any,
    snap: float,
    two_pi: float,
    out: Any,
) -> None:
    """Phase (rad) of samples ``n0 …`` into ``out`` (float64, ``(count,)``): for ``t = n / fs``
    the period ``q`` and the time ``τ`` into it, folded and snapped to the hop boundaries
    within ``snap`` s; the hop ``r`` (the last of ``start_s``, shape ``(P,)``, that ``τ + snap``
    reaches, clipped to ``0 … P − 1``); ``(φ_r + q Δφ) mod 2π + 2π (f_r τ_r + ½ k_r τ_r τ_r)``,
    ``τ_r = τ − start_s[r]``."""
    hops = start_s.shape[0]
    last = 0
    for i in range(out.shape[0]):
        t = np.float64(n0 + i) / fs
        rel = t - t0
        q = np.floor(rel / period)
        tau = rel - q * period
        if tau + snap >= period:
            q = q + 1.0
            tau = tau - period
        if tau + snap < 0.0:
            q = q - 1.0
            tau = tau + period
        probe = tau + snap
        # The last hop whose start ``probe`` reaches (searchsorted right, less one); the
        # previous sample's hop is checked first, as consecutive samples mostly share one.
        if last < 0 or not (
            start_s[last] <= probe and (last + 1 == hops or start_s[last + 1] > probe)
        ):
            last = 0
            while last < hops and start_s[last] <= probe:
                last += 1
            last -= 1
        r = min(max(last, 0), hops - 1)
        dt = tau - start_s[r]
        total = phase_rad[r] + np.float64(np.int64(q)) * period_phase
        # numpy.mod for floats: fmod, moved into [0, 2π) by adding the divisor when the
        # signs differ; a zero remainder takes the divisor's sign. Inside (0, 2π) that is
        # the value itself (fmod is exact), without the library call.
        if 0.0 < total < two_pi:
            base = total
        else:
            base = np.fmod(total, two_pi)
            if base != 0.0:
                if (two_pi < 0.0) != (base < 0.0):
                    base += two_pi
            else:
                base = math.copysign(0.0, two_pi)
        out[i] = base + two_pi * (freq_hz[r] * dt + 0.5 * chirp[r] * dt * dt)
