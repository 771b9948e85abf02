"""Compiled per-scatterer loops of one reverberation frame with one Doppler bin (numba).

:meth:`~sim_devices.acoustics.reverberation.VolumeReverberation._render_frame` turns every
scatterer's emission time into a whole-sample delay ``k`` and a sub-sample phase, then sums
the complex weights per ``k`` (the delay-amplitude train). As NumPy expressions over the
~2·10⁵ scatterers of a tank that is a dozen passes over temporaries a frame; here it is two
loops, around NumPy's float32 cosine and sine (kept: they are the reference values).

Same bits as the NumPy form: every output is the same sequence of IEEE operations
(``rint`` rounds half to even as :func:`numpy.rint`; a float64 product rounded to float32 as
``astype``; the sums run over the scatterers in order from 0, as :func:`numpy.bincount`
adds its weights), compiled without ``fastmath`` (no reassociation, no fused multiply-add).
Compiled with ``cache=True``: a fresh checkout compiles on the first frame (about a second)
and writes ``__pycache__``; later processes load the machine code.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

_JIT: dict[str, Any] = {"cache": True, "nogil": True}


@numba.njit(**_JIT)
def delays_and_phases(
    t_c: float,
    emit_s: Any,
    alpha_b: float,
    unit: bool,
    fs: float,
    phase_per_sample: float,
    k_out: Any,
    phase_out: Any,
) -> tuple[int, int]:
    """Whole-sample delay and sub-sample phase of each scatterer; the smallest and largest
    delay.

    ``emit_s`` (s, shape ``(m,)``): emission times; the delay is
    ``d = (t_c − emit_s) / α_b · fs`` samples (``/ α_b`` left out when ``unit``, α_b = 1),
    ``k = rint(d)`` into ``k_out`` (int64, ``(m,)``) and the phase
    ``phase_per_sample · α_b (d − k)`` rad, rounded to float32, into ``phase_out``
    (float32, ``(m,)``; ``α_b ·`` left out when ``unit``). ``m >= 1``.
    """
    k_lo = np.int64(0)
    k_hi = np.int64(0)
    for i in range(emit_s.shape[0]):
        d = t_c - emit_s[i]
        if not unit:
            d = d / alpha_b
        d = d * fs
        k = np.rint(d)
        frac = d - k
        if not unit:
            frac = alpha_b * frac
        phase_out[i] = np.float32(phase_per_sample * frac)
        ki = np.int64(k)
        k_out[i] = ki
        if i == 0 or ki < k_lo:
            k_lo = ki
        if i == 0 or ki > k_hi:
            k_hi = ki
    return int(k_lo), int(k_hi)


@numba.njit(**_JIT)
def weighted_trains(
    k: Any, amp: Any, cos_phase: Any, sin_phase: Any, re_out: Any, im_out: Any
) -> None:
    """``re_out[k[i]] += amp[i] · cos_phase[i]`` and ``im_out[k[i]] += amp[i] · sin_phase[i]``
    over ``i`` in order (``re_out``, ``im_out``: float64, zeroed by the caller, longer than
    ``max(k)``; ``cos_phase``, ``sin_phase`` float32, widened exactly to float64)."""
    for i in range(k.shape[0]):
        j = k[i]
        re_out[j] += np.float64(cos_phase[i]) * amp[i]
        im_out[j] += np.float64(sin_phase[i]) * amp[i]
