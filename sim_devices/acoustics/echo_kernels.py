"""Compiled per-sample loops of a grid echo's block (numba): the echo of one path added to a
block, around NumPy's float32 cosine.

:meth:`~sim_devices.acoustics.grid_echo.GridEcho.render` reads, for every receive sample, the
interval's delay cubic and gain quadratic, the transmit's hop at the emission time and its
phase; as NumPy expressions that is some twenty passes over temporaries per path and block.
:func:`gains_and_emission_times` and :func:`transmit_phases` do them in two loops and
:func:`add_echo` multiplies and adds the result to the block; NumPy's float32 cosine in
between stays (its values are the reference). The loops run one grid interval, or one hop,
at a time over views indexed from 0, the interval's or hop's values held: the compiler then
vectorises them (no gather, no negative-index check per sample).

Same bits as the NumPy form (:meth:`GridEcho.render` with
:meth:`~sim_devices.acoustics.transmit_eval.TransmitEvaluator.at_sorted_times`): every output
is the same sequence of IEEE operations (Horner from the highest power, float32 where the
NumPy form is float32, ``rint`` half to even), compiled without ``fastmath`` (no
reassociation, no fused multiply-add). Compiled with ``cache=True`` (see
:mod:`~sim_devices.acoustics.reverb_kernels`).
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

_JIT: dict[str, Any] = {"cache": True, "nogil": True}
_TWO_PI_F32 = np.float32(2.0 * np.pi)


@numba.njit(**_JIT)
def gains_and_emission_times(
    t: Any,
    u: Any,
    offsets: Any,
    coeffs: Any,
    gains: Any,
    amplitude: Any,
    scale: bool,
    gain_out: Any,
    emit_out: Any,
) -> bool:
    """Gain and emission time of every sample of a block; whether the emission times are
    non-decreasing (the transmit is read at sorted times).

    Sample ``i`` (receive time ``t[i]`` s, position ``u[i]`` in its grid interval, each shape
    ``(n,)``) of interval ``j`` (samples ``offsets[j] … offsets[j + 1] − 1``, ``offsets``
    shape ``(m + 1,)``): delay ``d = ((c3 u + c2) u + c1) u + c0`` (s, column ``j`` of
    ``coeffs``, shape ``(4, m)``) and ``t − d`` into ``emit_out`` (float64); gain
    ``(g2 u + g1) u + g0`` in float32 (column ``j`` of ``gains``, ``(3, m)``, ``u`` rounded to
    float32), times ``amplitude`` (float32) when ``scale``, into ``gain_out`` (float32). The
    loop runs interval by interval, the interval's coefficients held, so the compiler
    vectorises it; each sample's operations are the same.
    """
    for j in range(offsets.shape[0] - 1):
        c0, c1, c2, c3 = coeffs[0, j], coeffs[1, j], coeffs[2, j], coeffs[3, j]
        g0, g1, g2 = gains[0, j], gains[1, j], gains[2, j]
        a, b = offsets[j], offsets[j + 1]
        # Views of the interval, indexed from 0: no negative-index wrap to check per sample.
        ts, us, emit, gain = t[a:b], u[a:b], emit_out[a:b], gain_out[a:b]
        for i in range(b - a):
            ui = us[i]
            d = c3 * ui
            d = d + c2
            d = d * ui
            d = d + c1
            d = d * ui
            d = d + c0
            emit[i] = ts[i] - d
            u32 = np.float32(ui)
            g = g2 * u32
            g = g + g1
            g = g * u32
            g = g + g0
            if scale:
                g = g * amplitude
            gain[i] = g
    backwards = False
    for i in range(1, emit_out.shape[0]):
        backwards |= emit_out[i] < emit_out[i - 1]
    return not backwards


@numba.njit(**_JIT)
def transmit_phases(
    t: Any,
    snap_start_s: Any,
    start_s: Any,
    freq_hz: Any,
    half_chirp: Any,
    phase_cycles: Any,
    chirped: bool,
    first_hop: int,
    end_hop: int,
    phase_out: Any,
    hop_out: Any,
) -> None:
    """The transmit's phase (rad, float32, in ``[−π, π]``) at the non-decreasing times ``t``
    (s, shape ``(n,)``) into ``phase_out``, and each time's hop into ``hop_out`` (int64).

    Time ``t[i]`` is in hop ``j``: the last of ``first_hop … end_hop − 1`` whose
    ``snap_start_s`` it reaches (``first_hop`` before them all); its phase in cycles is
    ``φ_j + τ (f_j + ½ k_j τ)`` (``τ f_j`` unless ``chirped``), ``τ = t − start_s[j]``,
    reduced to ``[−½, ½]`` cycle, rounded to float32 and times 2π in float32. The times of
    hop ``j`` are the run from the first that reaches ``snap_start_s[j]`` (a binary search,
    ``t`` being sorted) to the first that reaches the next hop's; each run is one loop with
    the hop's values held, which the compiler vectorises.
    """
    n = t.shape[0]
    lo = 0
    for j in range(first_hop, end_hop):
        hi = n
        if j + 1 < end_hop:
            hi = max(lo, np.searchsorted(t, snap_start_s[j + 1]))
        start, freq, half, phi = start_s[j], freq_hz[j], half_chirp[j], phase_cycles[j]
        ts, phase, hop = t[lo:hi], phase_out[lo:hi], hop_out[lo:hi]  # views from 0
        for i in range(hi - lo):
            cyc = ts[i] - start
            if chirped:
                rate = cyc * half
                rate = rate + freq
                cyc = cyc * rate
            else:
                cyc = cyc * freq
            cyc = cyc + phi
            cyc = cyc - np.rint(cyc)
            phase[i] = np.float32(cyc) * _TWO_PI_F32
            hop[i] = j
        lo = hi


@numba.njit(**_JIT)
def add_echo(gain: Any, transmit: Any, hop: Any, hop_amplitude: Any, unit: bool, out: Any) -> None:
    """``out[i] += gain[i] · transmit[i]`` (the product in float32, as the NumPy form; the
    transmit times ``hop_amplitude[hop[i]]`` first unless ``unit``), ``out`` float64."""
    if unit:
        for i in range(out.shape[0]):
            out[i] += np.float64(gain[i] * transmit[i])
        return
    for i in range(out.shape[0]):
        s = transmit[i] * hop_amplitude[hop[i]]
        out[i] += np.float64(gain[i] * s)
