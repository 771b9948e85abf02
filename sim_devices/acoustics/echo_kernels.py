"""Compiled per-sample loops of a grid echo's block (numba): the echo of one path added to a
block, around NumPy's float32 cosine.

:meth:`~sim_devices.acoustics.grid_echo.GridEcho.render` reads, for every receive sample, the
interval's delay cubic and gain quadratic, the transmit's hop at the emission time and its
phase; as NumPy expressions that is some twenty passes over temporaries per path and block.
:func:`gains_and_emission_times` and :func:`transmit_phases` do them in two loops and
:func:`add_echo` multiplies and adds the result to the block; NumPy's float32 cosine in
between stays (its values are the reference).

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
    interval: Any,
    coeffs: Any,
    gains: Any,
    amplitude: Any,
    scale: bool,
    gain_out: Any,
    emit_out: Any,
) -> bool:
    """Gain and emission time of every sample of a block; whether the emission times are
    non-decreasing (the transmit is read at sorted times).

    Sample ``i`` (receive time ``t[i]`` s, position ``u[i]`` in its grid interval
    ``interval[i]``, each shape ``(n,)``): delay ``d = ((c3 u + c2) u + c1) u + c0`` (s, the
    column of ``coeffs``, shape ``(4, m)``) and ``t − d`` into ``emit_out`` (float64); gain
    ``(g2 u + g1) u + g0`` in float32 (the column of ``gains``, ``(3, m)``, ``u`` rounded to
    float32), times ``amplitude`` (float32) when ``scale``, into ``gain_out`` (float32).
    """
    ordered = True
    for i in range(t.shape[0]):
        k = interval[i]
        ui = u[i]
        d = coeffs[3, k] * ui
        d = d + coeffs[2, k]
        d = d * ui
        d = d + coeffs[1, k]
        d = d * ui
        d = d + coeffs[0, k]
        emit_out[i] = t[i] - d
        if i and emit_out[i] < emit_out[i - 1]:
            ordered = False
        u32 = np.float32(ui)
        g = gains[2, k] * u32
        g = g + gains[1, k]
        g = g * u32
        g = g + gains[0, k]
        if scale:
            g = g * amplitude
        gain_out[i] = g
    return ordered


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
    reduced to ``[−½, ½]`` cycle, rounded to float32 and times 2π in float32.
    """
    j = first_hop
    for i in range(t.shape[0]):
        while j + 1 < end_hop and t[i] >= snap_start_s[j + 1]:
            j += 1
        hop_out[i] = j
        cyc = t[i] - start_s[j]
        if chirped:
            rate = cyc * half_chirp[j]
            rate = rate + freq_hz[j]
            cyc = cyc * rate
        else:
            cyc = cyc * freq_hz[j]
        cyc = cyc + phase_cycles[j]
        cyc = cyc - np.rint(cyc)
        phase_out[i] = np.float32(cyc) * _TWO_PI_F32


@numba.njit(**_JIT)
def add_echo(gain: Any, transmit: Any, hop: Any, hop_amplitude: Any, unit: bool, out: Any) -> None:
    """``out[i] += gain[i] · transmit[i]`` (the product in float32, as the NumPy form; the
    transmit times ``hop_amplitude[hop[i]]`` first unless ``unit``), ``out`` float64."""
    for i in range(out.shape[0]):
        s = transmit[i]
        if not unit:
            s = s * hop_amplitude[hop[i]]
        out[i] += np.float64(gain[i] * s)
