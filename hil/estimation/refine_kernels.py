"""Compiled loops of the coherent refinement (:mod:`hil.estimation.refine`): the hops' moment
prefix sums and the likelihood of candidate ``(t_rx, α)`` with its maximisation.

Arrays are C-contiguous, ``float64`` / ``complex128`` unless stated, indices ``int64``.
Compiled with ``cache=True`` like :mod:`hil.estimation.kernels`.

Hop tables (one slot ``s`` per hop, shapes with ``S`` slots, ``R + 1`` edge rows, ``P``
moments): ``prefix[s, side, j, p]`` and ``energy[s, side, j]`` are the prefix sums of the
demodulated moments and of ``x²`` at prefix position ``j`` (side 0, from the slot's first
sample) or ``tail[s] + j`` (side 1), written by :func:`assign_slots`; ``first[s]`` is the
absolute sample index of prefix position 0, ``alpha0[s]`` and ``centre[s]`` (s) the time scale
and centre of the demodulation.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

#: ``error_model="numpy"``: a division by zero gives inf or NaN instead of raising, so the
#: compiled divisions carry no zero test (every divisor here is guarded or nonzero).
_JIT: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy"}
#: Hops of the runs over which :func:`fit_quality`'s third coherence is taken.
RUN_HOPS = 3
#: Taylor terms of the in-hop Doppler rotation (:mod:`hil.estimation.refine`): the tables'
#: last axis (:func:`_fill_slot` keeps exactly this many sums).
N_MOMENTS = 7


@numba.njit(**_JIT)
def _store_row(
    prefix: Any, energy: Any, s: int, side: int, j: int, e: float, a0: float, a1: float,
    a2: float, a3: float, a4: float, a5: float, a6: float, b0: float, b1: float, b2: float,
    b3: float, b4: float, b5: float, b6: float,
) -> None:  # fmt: skip
    """Row ``j`` of slot ``s``'s side-``side`` tables: moment ``p`` has real part ``a_p`` and
    imaginary part ``b_p``; the energy is ``e``."""
    prefix[s, side, j, 0] = complex(a0, b0)
    prefix[s, side, j, 1] = complex(a1, b1)
    prefix[s, side, j, 2] = complex(a2, b2)
    prefix[s, side, j, 3] = complex(a3, b3)
    prefix[s, side, j, 4] = complex(a4, b4)
    prefix[s, side, j, 5] = complex(a5, b5)
    prefix[s, side, j, 6] = complex(a6, b6)
    energy[s, side, j] = e


@numba.njit(**_JIT)
def _fill_slot(
    x: Any, pos: int, s: int, u0: float, span: int, cycles_per_sample: float,
    hop_samples: float, prefix: Any, energy: Any,
) -> None:  # fmt: skip
    """Slot ``s``'s tables from the real input ``x``.

    The hop reads ``x[pos + k]``, ``k < span``; ``u = u0 + k`` (samples from the hop's
    centre), ``y = x e^{−j2π cycles_per_sample u}``, ``S[j, p] = Σ_{k < j} y (u/hop_samples)^p``
    and ``E[j] = Σ_{k < j} x²`` for ``0 ≤ j ≤ span``. Side 0 keeps ``j ≤ R``, side 1
    ``j ≥ span − R`` (the module's tables, ``tail = span − R``). The rotation runs as a
    recurrence renewed every 256 samples (rounding below 1e-13).

    The :data:`N_MOMENTS` sums are fourteen scalars (real and imaginary parts apart), so they
    stay in registers: sums kept in an array go through memory at every sample (2.5x the
    time), and a complex product by a real factor would spend four multiplies on it.
    """
    r = prefix.shape[2] - 1
    tail = span - r
    a0 = a1 = a2 = a3 = a4 = a5 = a6 = 0.0
    b0 = b1 = b2 = b3 = b4 = b5 = b6 = 0.0
    e = 0.0
    w = -2.0 * math.pi * cycles_per_sample
    step_r, step_i = math.cos(w), math.sin(w)
    rot_r, rot_i = 1.0, 0.0
    for j in range(span + 1):
        if j <= r:
            _store_row(prefix, energy, s, 0, j, e, a0, a1, a2, a3, a4, a5, a6,
                       b0, b1, b2, b3, b4, b5, b6)  # fmt: skip
        if j >= tail:
            _store_row(prefix, energy, s, 1, j - tail, e, a0, a1, a2, a3, a4, a5, a6,
                       b0, b1, b2, b3, b4, b5, b6)  # fmt: skip
        if j == span:
            break
        u = u0 + j
        if j % 256 == 0:
            rot_r, rot_i = math.cos(w * u), math.sin(w * u)
        v = x[pos + j]
        y_r = v * rot_r
        y_i = v * rot_i
        q = u / hop_samples
        a0 += y_r
        b0 += y_i
        pw = q
        a1 += y_r * pw
        b1 += y_i * pw
        pw *= q
        a2 += y_r * pw
        b2 += y_i * pw
        pw *= q
        a3 += y_r * pw
        b3 += y_i * pw
        pw *= q
        a4 += y_r * pw
        b4 += y_i * pw
        pw *= q
        a5 += y_r * pw
        b5 += y_i * pw
        pw *= q
        a6 += y_r * pw
        b6 += y_i * pw
        e += v * v
        rot_r, rot_i = rot_r * step_r - rot_i * step_i, rot_r * step_i + rot_i * step_r


@numba.njit(**_JIT)
def assign_slots(
    slot_hop: Any, slot_edge: Any, slot_alpha: Any, slot_used: Any, slot_first: Any,
    slot_tail: Any, slot_centre: Any, clock: int, hop_ids: Any, t_s: float, dt_lo: Any,
    dt_hi: Any, f: Any, alpha: float, slack: float, alpha_tol: float, half: int, span: int,
    valid_from: int, next_index: int, x: Any, x_origin: int, fs: float, hop_samples: float,
    prefix: Any, energy: Any, out: Any,
) -> bool:  # fmt: skip
    """The table slot of each hop of a detection at ``t_s`` (s) and time scale ``alpha``
    into ``out`` (shape ``(M,)``). Hop ``i`` (transmit edges ``dt_lo[i]``, ``dt_hi[i]`` s
    from the boundary, tone ``f[i]`` Hz) has its lower window edge at
    ``edge = (t_s + dt_lo/alpha)·fs`` (absolute samples) and its centre at
    ``t_s + ½ (dt_lo + dt_hi)/alpha`` (s): a kept slot of that hop made for an edge within
    ``slack`` samples of it and a time scale within ``alpha_tol`` of ``alpha``, else the
    least recently used slot not taken by this detection, filled now (:func:`_fill_slot`,
    from ``edge − half`` for ``span`` samples, demodulated at ``f·alpha`` about the centre).
    ``x`` holds absolute sample ``x_origin + i`` at ``i``; samples from ``valid_from`` to
    ``next_index`` are real input, held from ``x_origin`` on. Slot arrays shape ``(S,)`` are
    updated; ``clock`` marks the use. False where a hop to fill is not covered by the input
    or no longer held."""
    m_hops = hop_ids.shape[0]
    n_slots = slot_hop.shape[0]
    edge = np.empty(m_hops)
    centre = np.empty(m_hops)
    for i in range(m_hops):
        edge[i] = (t_s + dt_lo[i] / alpha) * fs
        centre[i] = t_s + 0.5 * (dt_lo[i] + dt_hi[i]) / alpha
    for i in range(m_hops):
        out[i] = -1
        for s in range(n_slots):
            if (
                slot_hop[s] == hop_ids[i]
                and abs(slot_edge[s] - edge[i]) <= slack
                and abs(slot_alpha[s] - alpha) <= alpha_tol
            ):
                out[i] = s
                slot_used[s] = clock
                break
    r = prefix.shape[2] - 1
    for i in range(m_hops):
        if out[i] >= 0:
            continue
        first = int(math.floor(edge[i])) - half
        # Only real input still held: an index before x_origin would wrap to other samples.
        if first < max(valid_from, x_origin) or first + span > next_index:
            return False
        best = -1
        for s in range(n_slots):  # the least recently used, not this detection's
            if slot_used[s] != clock and (best < 0 or slot_used[s] < slot_used[best]):
                best = s
        _fill_slot(
            x, first - x_origin, best, first - centre[i] * fs, span, f[i] * alpha / fs,
            hop_samples, prefix, energy,
        )  # fmt: skip
        slot_hop[best] = hop_ids[i]
        slot_edge[best] = edge[i]
        slot_alpha[best] = alpha
        slot_first[best] = first
        slot_tail[best] = span - r
        slot_centre[best] = centre[i]
        slot_used[best] = clock
        out[i] = best
    return True


#: Rows of a candidate line's per-hop constants (:func:`_line`): the hop's time scale, its
#: window's start and end after the boundary (s), ``−2π f α_i`` (rad/s), the received tone
#: ``f α_i`` (Hz), and under a time-scale rate the offset ``u`` of the hop's centre from the
#: hops' (s), its ``d/α_i`` (s) and the curve's mean phase over the hop (rad).
_A, _LO, _HI, _PF, _FA, _U, _DA, _CURVE = range(8)
#: Margin (s) of :func:`_columns_near`'s reach: far beyond the rounding of its bounds.
_NEAR_SLACK_S = 1e-4


@numba.njit(**_JIT)
def _line(
    alpha0: Any, slots: Any, f: Any, dt_lo: Any, dt_hi: Any, hop_s: float, alpha: float,
    gamma: float, consts: Any, coef: Any,
) -> float:  # fmt: skip
    """What every candidate of time scale ``alpha`` and rate ``gamma`` shares, per hop, into
    ``consts`` (shape ``(8, M)``, rows :data:`_A` …) and ``coef`` (shape ``(2, M, P)``: real
    and imaginary parts of ``(jθ)^p / p!``, ``θ = −2π (α_i − α0) D f``, the in-hop Doppler
    rotation's Taylor terms); returns ``d_c/α`` (s, ``d_c`` the hops' transmit centre). With
    ``gamma = 0`` every hop has the line's own time scale and no curve. Otherwise (the
    accelerating mapping of :func:`_candidate`) ``α_i`` is the time scale where the hop's
    transmit centre ``T_b + d`` (``d`` s, negative before the boundary) is heard, and the hop
    is the straight line through that point with slope ``α_i``, boundary time
    ``t_rx + d_c/α + u − d/α_i``; the point's receive offset ``u`` from the hops' centre is
    one Newton step from ``(d − d_c)/α`` (error ``O(γ²)``). A grid's row of candidates
    computes these once (the same operations each candidate would: the same bits)."""
    m_hops = slots.shape[0]
    n_mom = coef.shape[2]
    d_c = 0.5 * (dt_lo[0] + dt_hi[m_hops - 1])
    for i in range(m_hops):
        a_i = alpha
        if gamma != 0.0:
            d = 0.5 * (dt_lo[i] + dt_hi[i])
            u = (d - d_c) / alpha
            u -= 0.5 * gamma * u * u / (alpha + gamma * u)
            a_i = alpha + gamma * u
            consts[_U, i] = u
            consts[_DA, i] = d / a_i
            # The curve about the hop's tangent, ½ γ (t − m)², averaged over the hop: a phase
            # of π f γ D²/12 (D the hop's received length), second order in D beyond it.
            dur = (dt_hi[i] - dt_lo[i]) / a_i
            consts[_CURVE, i] = math.pi * f[i] * gamma * dur * dur / 12.0
        consts[_A, i] = a_i
        consts[_LO, i] = dt_lo[i] / a_i
        consts[_HI, i] = dt_hi[i] / a_i
        consts[_PF, i] = -2.0 * math.pi * f[i] * a_i
        consts[_FA, i] = f[i] * a_i
        # Σ_p (jθ)^p / p! (hi − lo), θ = −2π (α − α0) D f: the term's real recurrence.
        theta = -2.0 * math.pi * (a_i - alpha0[slots[i]]) * hop_s * f[i]
        tr = 1.0
        ti = 0.0
        for p in range(n_mom):
            coef[0, i, p] = tr
            coef[1, i, p] = ti
            g = theta / (p + 1)
            tr, ti = -ti * g, tr * g
    return d_c / alpha


@numba.njit(**_JIT)
def _edge(pos: float, last: int) -> tuple[int, float]:
    """Row and weight of fractional table position ``pos`` (linear between rows, clipped to
    rows ``0 … last + 1``)."""
    j = int(math.floor(pos))
    w = pos - j
    if j < 0:
        return 0, 0.0
    if j > last:
        return last, 1.0
    return j, w


@numba.njit(**_JIT)
def _window(
    prefix: Any, energy: Any, s: int, lo: float, hi: float, coef: Any, i: int,
    with_energy: bool,
) -> tuple[complex, float]:  # fmt: skip
    """``Σ_p coef_p (S_hi[p] − S_lo[p])`` (:func:`_window_sum`) and ``E_hi − E_lo`` of slot
    ``s`` between the fractional positions ``lo`` (side 0) and ``hi`` (side 1),
    ``coef = coef[:, i, :]``; the energy 0 unless ``with_energy`` (its four table reads are
    a sixth of a candidate's time)."""
    if not with_energy:
        return _window_sum(prefix, s, lo, hi, coef, i), 0.0
    last = prefix.shape[2] - 2
    j0, w0 = _edge(lo, last)
    j1, w1 = _edge(hi, last)
    e0 = energy[s, 0, j0]
    e1 = energy[s, 1, j1]
    e_lo = e0 + w0 * (energy[s, 0, j0 + 1] - e0)
    e_hi = e1 + w1 * (energy[s, 1, j1 + 1] - e1)
    return _window_sum(prefix, s, lo, hi, coef, i), e_hi - e_lo


@numba.njit(**_JIT)
def _candidate(
    prefix: Any, energy: Any, first: Any, tail: Any, centre: Any, slots: Any, k: Any,
    amp2: Any, fs: float, t_rx: float, curved: bool, d_c_alpha: float, consts: Any,
    coef: Any, per_hop: Any, known: Any, near: Any, n_near: Any, rot_key: Any, rot: Any,
    phasors: Any, edges: Any, with_signal: bool,
) -> tuple[complex, float, float]:  # fmt: skip
    """``(C, Σ a_i² N_i, input energy in the windows)`` of one candidate at ``t_rx`` (s) on
    the line whose per-hop constants :func:`_line` made (``consts``, ``coef``, and
    ``d_c_alpha`` its return; ``curved`` where its rate is not 0). The input energy is read
    only ``with_signal`` (else 0; ``C`` and the model's energy are the same either way).

    The time scale's rate ``gamma`` (1/s, :func:`_line`'s) maps transmit time: heard at
    ``t`` is ``T_b + d_c + α (τ − τ_c) + ½ γ (τ − τ_c)²`` with ``τ = t − t_rx``, ``T_b + d_c``
    the transmit centre of the ``M`` hops and ``τ_c = d_c/α`` (``α`` is the time scale where
    that centre is heard; the curvature, even about it, leaves the delay and time scale
    there unchanged). Each hop is heard on the curve's tangent at its own centre, with the
    curve's mean phase over the hop about that tangent, ``π f γ D²/12``, added (what is left
    is second order: below 1e-3 of a term at 20 m/s² on ``att``).
    ``gamma = 0`` is the constant time scale ``T_b + α τ``, computed without that mapping.

    Per hop ``i`` (shape ``(M,)``): ``slots`` its table slot, ``k`` the transmit phasor
    ``a_i e^{−j(φ_i + 2π f_i (T_b − T_i))}``, ``amp2`` its squared amplitude. ``per_hop``
    receives each hop's term of ``C`` (shape ``(M,)``, or ``(0,)`` for none); ``known``: the
    hops of other echoes already measured, whose part of each term and of the energy is
    taken out (:func:`_known_part`; shape ``(5, Q)``), of which hop ``i`` reads the columns
    ``near[i, :n_near[i]]`` (ascending; every column that can overlap its window:
    :func:`_columns_near`); ``rot_key`` and ``rot`` its rotations kept (:func:`_known_part`).
    ``phasors`` (complex, shape ``(M,)``): each hop's ``e^{j ph_i}`` at this candidate, made
    by the caller along a row of equally spaced times (:func:`_row_phasors`), or shape
    ``(0,)`` to compute it here; ``edges`` (complex, shape ``(5, M, Q')``) the same for the
    known columns' integrals (:func:`_row_edges`), or shape ``(5, 0, 0)``.
    """
    total = complex(0.0, 0.0)
    model = 0.0
    signal = 0.0
    for i in range(slots.shape[0]):
        s = slots[i]
        t_i = t_rx
        if curved:
            t_i = t_rx + d_c_alpha + consts[_U, i] - consts[_DA, i]
        lo_s = t_i + consts[_LO, i]
        hi_s = t_i + consts[_HI, i]
        lo = lo_s * fs - first[s] + 0.5
        hi = hi_s * fs - first[s] + 0.5
        z, e_window = _window(prefix, energy, s, lo, hi - tail[s], coef, i, with_signal)
        if phasors.shape[0]:
            term_i = k[i] * phasors[i] * z
        else:
            ph = consts[_PF, i] * (centre[s] - t_i)
            if curved:
                ph -= consts[_CURVE, i]
            term_i = k[i] * complex(math.cos(ph), math.sin(ph)) * z
        if n_near[i]:
            part, energy_part = _known_part(
                known, near, i, n_near[i], t_i, lo_s, hi_s, consts[_FA, i], rot_key, rot, edges
            )
            kp = k[i] * part
            term_i -= complex(kp.real * fs, kp.imag * fs)
            signal -= energy_part * fs
        total += term_i
        if per_hop.shape[0]:
            per_hop[i] = term_i
        model += amp2[i] * (hi - lo)
        signal += e_window
    return total, model, signal


@numba.njit(**_JIT)
def _window_sum(prefix: Any, s: int, lo: float, hi: float, coef: Any, i: int) -> complex:
    """``Σ_p coef_p (S_hi[p] − S_lo[p])`` of slot ``s`` between the fractional positions
    ``lo`` (side 0) and ``hi`` (side 1), ``coef = coef[:, i, :]`` (:func:`_window` adds the
    energy). Parts real and imaginary apart (a complex product by the real weights would
    spend four multiplies on each)."""
    last = prefix.shape[2] - 2
    j0, w0 = _edge(lo, last)
    j1, w1 = _edge(hi, last)
    zr = 0.0
    zi = 0.0
    for p in range(prefix.shape[3]):
        a = prefix[s, 0, j0, p]
        b = prefix[s, 0, j0 + 1, p]
        c = prefix[s, 1, j1, p]
        d = prefix[s, 1, j1 + 1, p]
        dr = (c.real + w1 * (d.real - c.real)) - (a.real + w0 * (b.real - a.real))
        di = (c.imag + w1 * (d.imag - c.imag)) - (a.imag + w0 * (b.imag - a.imag))
        cr = coef[0, i, p]
        ci = coef[1, i, p]
        zr += cr * dr - ci * di
        zi += cr * di + ci * dr
    return complex(zr, zi)


@numba.njit(**_JIT)
def _candidate_c(
    prefix: Any, first: Any, tail: Any, slots: Any, k: Any, fs: float, t_rx: float,
    curved: bool, d_c_alpha: float, consts: Any, coef: Any, known: Any, near: Any,
    n_near: Any, rot_key: Any, rot: Any, phasors: Any, edges: Any,
) -> complex:  # fmt: skip
    """:func:`_candidate`'s ``C`` alone, with the row's ``phasors`` (shape ``(M,)``) and
    ``edges`` given (:func:`maximise`, which reads neither energy): the same operations on
    ``C``, so the same bits, without the windows' and the model's energies."""
    total = complex(0.0, 0.0)
    for i in range(slots.shape[0]):
        s = slots[i]
        t_i = t_rx
        if curved:
            t_i = t_rx + d_c_alpha + consts[_U, i] - consts[_DA, i]
        lo_s = t_i + consts[_LO, i]
        hi_s = t_i + consts[_HI, i]
        lo = lo_s * fs - first[s] + 0.5
        hi = hi_s * fs - first[s] + 0.5
        z = _window_sum(prefix, s, lo, hi - tail[s], coef, i)
        term_i = k[i] * phasors[i] * z
        if n_near[i]:
            part, _ = _known_part(
                known, near, i, n_near[i], t_i, lo_s, hi_s, consts[_FA, i], rot_key, rot, edges
            )
            kp = k[i] * part
            term_i -= complex(kp.real * fs, kp.imag * fs)
        total += term_i
    return total


@numba.njit(**_JIT)
def _row_phasors(
    centre: Any, slots: Any, t_rx: float, curved: bool, d_c_alpha: float, consts: Any,
    step_s: float, start: Any, step: Any,
) -> None:  # fmt: skip
    """Each hop's phasor ``e^{j ph_i}`` of :func:`_candidate` at ``t_rx`` (s) on the line of
    ``consts`` (and ``d_c_alpha``, ``curved``: :func:`_line`'s) into ``start``, and the
    factor ``e^{−j PF_i step_s}`` that moves it to the candidate ``step_s`` (s) later into
    ``step`` (complex, shape ``(M,)`` each): ``ph_i`` is linear in ``t_rx`` with slope
    ``−PF_i``, so a row of equally spaced candidates costs one sine and cosine pair per hop
    and a complex product per candidate instead of a pair per candidate (:func:`_advance`;
    the product's rounding over a row of tens of steps stays near 1e-15)."""
    for i in range(slots.shape[0]):
        t_i = t_rx
        if curved:
            t_i = t_rx + d_c_alpha + consts[_U, i] - consts[_DA, i]
        ph = consts[_PF, i] * (centre[slots[i]] - t_i)
        if curved:
            ph -= consts[_CURVE, i]
        start[i] = complex(math.cos(ph), math.sin(ph))
        w = -consts[_PF, i] * step_s
        step[i] = complex(math.cos(w), math.sin(w))


@numba.njit(**_JIT)
def _advance(phasors: Any, step: Any) -> None:
    """Move :func:`_row_phasors`' phasors one step along their row (in place)."""
    for i in range(phasors.shape[0]):
        phasors[i] *= step[i]


@numba.njit(**_JIT)
def _row_edges(
    known: Any, near: Any, n_near: Any, t_rx: float, curved: bool, d_c_alpha: float,
    consts: Any, step_s: float, edges: Any,
) -> None:  # fmt: skip
    """:func:`_known_part`'s integral ends along a row of candidates from ``t_rx`` (s) in steps
    of ``step_s`` (one time scale: :func:`_line`'s ``consts``, ``d_c_alpha`` and ``curved``),
    into ``edges`` (complex, shape ``(5, M, Q')``; per hop ``i`` and column ``near[i, col]``,
    ``x = 2π (g − f_rx)``): ``e^{jx (start − t_i)}`` and ``e^{jx (end − t_i)}`` of the
    column's own interval (``t_i`` the hop's time at ``t_rx``), ``e^{jx LO_i}`` and
    ``e^{jx HI_i}`` of the window's edges (fixed along the row: they move with ``t_i``), and
    the factor ``e^{−jx step_s}`` that moves the first two one candidate on
    (:func:`_advance_edges`). The integral ``(e^{jx τ_b} − e^{jx τ_a})/(jx)`` then costs two
    complex products per candidate instead of two sine and cosine pairs."""
    for i in range(n_near.shape[0]):
        t_i = t_rx
        if curved:
            t_i = t_rx + d_c_alpha + consts[_U, i] - consts[_DA, i]
        f_rx = consts[_FA, i]
        for col in range(n_near[i]):
            h = near[i, col]
            x = 2.0 * math.pi * (known[1, h].real - f_rx)
            ta = x * (known[2, h].real - t_i)
            tb = x * (known[3, h].real - t_i)
            edges[0, i, col] = complex(math.cos(ta), math.sin(ta))
            edges[1, i, col] = complex(math.cos(tb), math.sin(tb))
            edges[2, i, col] = complex(math.cos(x * consts[_LO, i]), math.sin(x * consts[_LO, i]))
            edges[3, i, col] = complex(math.cos(x * consts[_HI, i]), math.sin(x * consts[_HI, i]))
            edges[4, i, col] = complex(math.cos(x * step_s), -math.sin(x * step_s))


@numba.njit(**_JIT)
def _advance_edges(edges: Any, n_near: Any) -> None:
    """Move :func:`_row_edges`' column ends one candidate along their row (in place)."""
    for i in range(n_near.shape[0]):
        for col in range(n_near[i]):
            edges[0, i, col] *= edges[4, i, col]
            edges[1, i, col] *= edges[4, i, col]


@numba.njit(**_JIT)
def _known_part(
    known: Any, near: Any, i: int, n_near: int, t_rx: float, lo: float, hi: float,
    f_rx: float, rot_key: Any, rot: Any, edges: Any,
) -> tuple[complex, float]:  # fmt: skip
    """What the hops of other echoes already measured put into one hop's term (before its
    transmit phasor and the sample rate) and into its window's energy (per sample rate).

    ``known`` rows (shape ``(5, Q)``, one column per hop of those echoes): the hop's complex
    weight ``w = ½ β conj(k_h)`` (``β`` its echo's fitted amplitude: the input there is
    ``Re(β Σ_h conj(k_h) e^{j2π g_h (t − t_e)})``), its received frequency ``g_h`` (Hz), the
    start and end of its received interval (s) and its echo's boundary time ``t_e`` (s); all
    real rows hold floats, the weight's row complex. The term's window is ``[lo, hi)`` (s),
    demodulated at ``f_rx`` (Hz) about ``t_rx``: the part is
    ``Σ_h w_h e^{j2π g_h (t_rx − t_e)} ∫ e^{j2π (g_h − f_rx) τ} dτ`` over the overlap
    (``τ = t − t_rx``), the energy ``Σ_h 2|w_h|²`` times the overlap's length. Only the
    columns ``near[i, :n_near]`` are read (the others cannot overlap the window).

    ``rot_key`` (float, shape ``(Q,)``) and ``rot`` (complex, shape ``(Q,)``) keep each
    column's ``e^{j2π g_h (t_rx − t_e)}`` with the ``t_rx`` it was made for: a candidate of
    the same ``t_rx`` (a search grid's column, the other hops over that column) reads it
    instead of a remainder and a sine and cosine, the same value; shape ``(0,)`` keeps none.
    ``edges`` (complex, shape ``(5, M, Q')``, or ``(5, 0, 0)`` for none): :func:`_row_edges`'
    ``e^{jx τ}`` at the integral's ends for column ``near[i, col]`` at this candidate.
    """
    part = complex(0.0, 0.0)
    energy = 0.0
    for col in range(n_near):
        h = near[i, col]
        a = max(lo, known[2, h].real)
        b = min(hi, known[3, h].real)
        if b <= a:
            continue
        g = known[1, h].real
        w = known[0, h]
        if rot_key.shape[0] and rot_key[h] == t_rx:
            r = rot[h]
        else:
            cyc = (g * (t_rx - known[4, h].real)) % 1.0
            r = complex(math.cos(2.0 * math.pi * cyc), math.sin(2.0 * math.pi * cyc))
            if rot_key.shape[0]:
                rot_key[h] = t_rx
                rot[h] = r
        x = 2.0 * math.pi * (g - f_rx)
        ta = a - t_rx
        tb = b - t_rx
        if abs(x * (tb - ta)) < 1e-9:
            dt = tb - ta
            integral = complex(math.cos(x * ta) * dt, math.sin(x * ta) * dt)
        elif edges.shape[1]:
            # The ends' phasors kept along the row: a column's own end, or the window's.
            ea = edges[0, i, col] if known[2, h].real >= lo else edges[2, i, col]
            eb = edges[1, i, col] if known[3, h].real <= hi else edges[3, i, col]
            d = eb - ea
            integral = complex(d.imag / x, -d.real / x)
        else:
            # (e^{jx tb} − e^{jx ta}) / (jx), real and imaginary parts apart.
            p = math.cos(x * tb) - math.cos(x * ta)
            q = math.sin(x * tb) - math.sin(x * ta)
            integral = complex(q / x, -p / x)
        part += w * r * integral
        energy += 2.0 * (w.real * w.real + w.imag * w.imag) * (b - a)
    return part, energy


@numba.njit(**_JIT)
def _every_column(m_hops: int, known: Any) -> tuple[Any, Any]:
    """:func:`_candidate`'s ``near`` and ``n_near`` reading every column of ``known`` for
    each of ``m_hops`` hops."""
    n_cols = known.shape[1]
    near = np.empty((m_hops, n_cols), dtype=np.int64)
    for i in range(m_hops):
        for h in range(n_cols):
            near[i, h] = h
    return near, np.full(m_hops, n_cols, dtype=np.int64)


@numba.njit(**_JIT)
def _columns_near(
    known: Any, dt_lo: Any, dt_hi: Any, t_lo: float, t_hi: float, a_lo: float, a_hi: float
) -> tuple[Any, Any]:  # fmt: skip
    """:func:`_candidate`'s ``near`` and ``n_near`` for candidates of constant time scale
    (no rate) with ``t_rx`` in ``[t_lo, t_hi]`` (s) and ``α`` in ``[a_lo, a_hi]``: the
    columns of ``known`` whose interval comes within :data:`_NEAR_SLACK_S` of a window hop
    ``i`` can have, ``[t_rx + dt_lo[i]/α, t_rx + dt_hi[i]/α]`` (monotonic in ``α``: its
    ends' extremes are at ``a_lo`` and ``a_hi``). A column left out adds nothing to any of
    them, so every sum is the same as over all columns."""
    m_hops = dt_lo.shape[0]
    n_cols = known.shape[1]
    near = np.empty((m_hops, n_cols), dtype=np.int64)
    n_near = np.zeros(m_hops, dtype=np.int64)
    for i in range(m_hops):
        lo = t_lo + min(dt_lo[i] / a_lo, dt_lo[i] / a_hi) - _NEAR_SLACK_S
        hi = t_hi + max(dt_hi[i] / a_lo, dt_hi[i] / a_hi) + _NEAR_SLACK_S
        for h in range(n_cols):
            if known[2, h].real < hi and known[3, h].real > lo:
                near[i, n_near[i]] = h
                n_near[i] += 1
    return near, n_near


@numba.njit(**_JIT)
def _scratch(slots: Any, prefix: Any) -> tuple[Any, Any]:
    """:func:`_line`'s outputs for the hops ``slots`` (shapes ``(8, M)`` and ``(2, M, P)``)."""
    m_hops = slots.shape[0]
    return np.zeros((8, m_hops)), np.empty((2, m_hops, prefix.shape[3]))


@numba.njit(**_JIT)
def candidate_sums(
    prefix: Any, energy: Any, first: Any, tail: Any, alpha0: Any, centre: Any, slots: Any,
    k: Any, f: Any, dt_lo: Any, dt_hi: Any, amp2: Any, fs: float, hop_s: float,
    t_rx: Any, alpha: Any, gamma: Any, out_c: Any, out_model: Any, out_signal: Any,
    per_hop: Any, known: Any,
) -> None:  # fmt: skip
    """:func:`_candidate` for candidates ``(t_rx[c], alpha[c], gamma[c])`` (shape ``(C,)``;
    ``gamma`` the time-scale rate, 1/s) into the outputs (shape ``(C,)``: ``C`` complex, the
    model's energy, the input's energy, or ``out_signal`` of shape ``(0,)`` where the input's
    energy is not wanted: not read) and each hop's term (``per_hop``, complex, shape
    ``(C, M)`` or ``(C, 0)`` for none); ``known`` as :func:`_candidate`.

    Per hop (shape ``(M,)``): ``slots`` its table slot, ``k`` the transmit phasor
    ``a_i e^{−j(φ_i + 2π f_i (T_b − T_i))}``, ``f`` the tone (Hz), ``dt_lo``/``dt_hi`` the
    transmit times of its start and end relative to the boundary (s, ``T_i − T_b`` and
    ``T_i + D_i − T_b``), ``amp2`` its squared amplitude; ``hop_s`` the hop length ``D`` (s).
    """
    consts, coef = _scratch(slots, prefix)
    n_cand = t_rx.shape[0]
    n_cols = known.shape[1]
    # Candidates of constant time scale (every rate 0) with known hops: each hop reads only
    # the columns its windows can meet over the candidates' times and time scales
    # (:func:`_columns_near`; a column left out adds nothing, the same sums), and the
    # candidates of one time ``t_rx`` (a grid's column across its time scales) share each
    # column's rotation (:func:`_known_part`'s ``rot_key``: the value computed for that
    # ``t_rx`` once, the same bits).
    straight = n_cand > 0 and n_cols > 0
    for c in range(n_cand):
        if gamma[c] != 0.0:
            straight = False
            break
    times = np.empty(0)
    if straight:
        times = np.unique(t_rx)
        near, n_near = _columns_near(
            known, dt_lo, dt_hi, times[0], times[-1], np.min(alpha), np.max(alpha)
        )
        rot_key = np.full((times.shape[0], n_cols), np.nan)
        rot = np.empty((times.shape[0], n_cols), dtype=np.complex128)
    else:
        near, n_near = _every_column(slots.shape[0], known)
        rot_key = np.empty((1, 0))  # no rotations kept
        rot = np.empty((1, 0), dtype=np.complex128)
    no_rot = np.empty(0, dtype=np.complex128)
    no_edges = np.empty((5, 0, 0), dtype=np.complex128)
    with_signal = out_signal.shape[0] > 0
    d_c_alpha = 0.0
    for c in range(n_cand):
        if c == 0 or alpha[c] != alpha[c - 1] or gamma[c] != gamma[c - 1]:
            d_c_alpha = _line(
                alpha0, slots, f, dt_lo, dt_hi, hop_s, alpha[c], gamma[c], consts, coef
            )
        row = np.searchsorted(times, t_rx[c]) if straight else 0
        # The flag is a constant at each call, so the compiled code without the energy has
        # no test of it left (passed as a variable, the energy's skip saved nothing).
        if with_signal:
            out_c[c], out_model[c], out_signal[c] = _candidate(
                prefix, energy, first, tail, centre, slots, k, amp2, fs, t_rx[c],
                gamma[c] != 0.0, d_c_alpha, consts, coef, per_hop[c], known, near, n_near,
                rot_key[row], rot[row], no_rot, no_edges, True,
            )  # fmt: skip
        else:
            out_c[c], out_model[c], _ = _candidate(
                prefix, energy, first, tail, centre, slots, k, amp2, fs, t_rx[c],
                gamma[c] != 0.0, d_c_alpha, consts, coef, per_hop[c], known, near, n_near,
                rot_key[row], rot[row], no_rot, no_edges, False,
            )  # fmt: skip


@numba.njit(**_JIT)
def grid_sums(
    prefix: Any, energy: Any, first: Any, tail: Any, alpha0: Any, centre: Any, slots: Any,
    k: Any, f: Any, dt_lo: Any, dt_hi: Any, amp2: Any, fs: float, hop_s: float,
    known: Any, t0: float, step_s: float, alphas: Any, out_c: Any, out_model: Any,
) -> None:  # fmt: skip
    """:func:`candidate_sums`' ``C`` and model energy ``Σ a_i² N_i`` of a grid of
    constant-speed candidates: times ``t0 + j·step_s`` (s) for ``j < n_t`` at each time scale
    ``alphas[r]`` (shape ``(R,)``), into ``out_c`` (complex) and ``out_model`` (shape
    ``(R, n_t)`` each); tables, hops and ``known`` as there.

    Each row (one time scale) turns the hops' phasors and the known columns' integral ends by
    a fixed factor a step (:func:`_row_phasors`, :func:`_row_edges`), as :func:`maximise`'s
    grid does: two complex products per hop and column instead of a sine and cosine pair each
    (the products' rounding over a row of a few tens of steps stays near 1e-15)."""
    consts, coef = _scratch(slots, prefix)
    n_rows, n_t = out_c.shape
    m_hops = slots.shape[0]
    n_cols = known.shape[1]
    near, n_near = _columns_near(
        known, dt_lo, dt_hi, t0, t0 + (n_t - 1) * step_s, np.min(alphas), np.max(alphas)
    )
    # Each time column shares the known columns' rotations across the time scales.
    rot_key = np.full((n_t, n_cols), np.nan)
    rot = np.empty((n_t, n_cols), dtype=np.complex128)
    phasors = np.empty(m_hops, dtype=np.complex128)
    turn = np.empty(m_hops, dtype=np.complex128)
    edges = np.empty((5, m_hops, n_cols), dtype=np.complex128)
    no_per_hop = np.empty(0, dtype=np.complex128)
    for r in range(n_rows):
        d_c_a = _line(alpha0, slots, f, dt_lo, dt_hi, hop_s, alphas[r], 0.0, consts, coef)
        _row_phasors(centre, slots, t0, False, d_c_a, consts, step_s, phasors, turn)
        if n_cols:
            _row_edges(known, near, n_near, t0, False, d_c_a, consts, step_s, edges)
        for j in range(n_t):
            if j:
                _advance(phasors, turn)
                if n_cols:
                    _advance_edges(edges, n_near)
            c, model, _ = _candidate(
                prefix, energy, first, tail, centre, slots, k, amp2, fs, t0 + j * step_s,
                False, d_c_a, consts, coef, no_per_hop, known, near, n_near, rot_key[j],
                rot[j], phasors, edges, False,
            )  # fmt: skip
            out_c[r, j] = c
            out_model[r, j] = model


#: :func:`maximise` outcomes.
FOUND, NO_LOBE, RECENTRE = 0, 1, 2


@numba.njit(**_JIT)
def maximise(
    prefix: Any, energy: Any, first: Any, tail: Any, alpha0: Any, centre: Any, slots: Any,
    k: Any, f: Any, dt_lo: Any, dt_hi: Any, amp2: Any, fs: float, hop_s: float,
    known: Any, gamma: float, c_mps: float, t0: float, v0: float, half_t: float,
    half_v: float, n_t: int, n_v: int, passes: int,
) -> tuple[float, float, int]:  # fmt: skip
    """The ``(t_rx, v)`` (s, m/s) maximising ``|C|²`` (tables, hops, ``known`` and the
    time-scale rate ``gamma`` as :func:`candidate_sums`, ``v`` the speed at the hops' centre;
    ``c_mps`` the sound speed) and an outcome.

    A grid of ``n_t × n_v`` points over ``t0 ± half_t`` and ``v0 ± half_v`` picks the main
    lobe: :data:`NO_LOBE` where its maximum is at either end in time, :data:`RECENTRE` with
    that point where it is at either end in speed (the caller makes tables there and
    searches again: the grid follows the tilted range–Doppler ridge toward the peak); then
    ``passes`` 2-D quadratic fits on a 3 × 3 stencil (half the grid's steps) around the best
    point, the stencil halving each pass (:data:`FOUND`).
    """
    consts, coef = _scratch(slots, prefix)
    curved = gamma != 0.0
    step_t = 2.0 * half_t / (n_t - 1)
    step_v = 2.0 * half_v / (n_v - 1)
    if curved:
        near, n_near = _every_column(slots.shape[0], known)
    else:
        # Every candidate lies within the grid widened by one grid step: the fit's stencil
        # starts at half a step and halves, each pass moving it by at most its step.
        reach_t = half_t + 2.0 * step_t
        reach_v = half_v + 2.0 * step_v
        a_lo = (c_mps + v0 - reach_v) / (c_mps - v0 + reach_v)
        a_hi = (c_mps + v0 + reach_v) / (c_mps - v0 - reach_v)
        near, n_near = _columns_near(known, dt_lo, dt_hi, t0 - reach_t, t0 + reach_t, a_lo, a_hi)
    # Each time column of the grid (and of the stencil) keeps the known columns' rotations:
    # its candidates share their t_rx across the speeds (NaN: none kept yet).
    n_cols = known.shape[1]
    rot_key = np.full((max(n_t, 3), n_cols), np.nan)
    rot = np.empty((max(n_t, 3), n_cols), dtype=np.complex128)
    # Each row of candidates (one time scale, equally spaced times) turns the hops' phasors
    # by a fixed factor a step (:func:`_row_phasors`).
    m_hops = slots.shape[0]
    phasors = np.empty(m_hops, dtype=np.complex128)
    turn = np.empty(m_hops, dtype=np.complex128)
    # So do the known columns' integral ends (:func:`_row_edges`).
    edges = np.empty((5, m_hops, n_cols), dtype=np.complex128)
    best = -1.0
    bi = 0
    bj = 0
    for i in range(n_v):
        vv = v0 - half_v + i * step_v
        a = (c_mps + vv) / (c_mps - vv)
        d_c_a = _line(alpha0, slots, f, dt_lo, dt_hi, hop_s, a, gamma, consts, coef)
        _row_phasors(centre, slots, t0 - half_t, curved, d_c_a, consts, step_t, phasors, turn)
        if n_cols:
            _row_edges(known, near, n_near, t0 - half_t, curved, d_c_a, consts, step_t, edges)
        for j in range(n_t):
            if j:
                _advance(phasors, turn)
                if n_cols:
                    _advance_edges(edges, n_near)
            cc = _candidate_c(
                prefix, first, tail, slots, k, fs, t0 - half_t + j * step_t, curved, d_c_a,
                consts, coef, known, near, n_near, rot_key[j], rot[j], phasors, edges,
            )  # fmt: skip
            pw = cc.real * cc.real + cc.imag * cc.imag
            if pw > best:
                best, bi, bj = pw, i, j
    t = t0 - half_t + bj * step_t
    if bj == 0 or bj == n_t - 1:
        return t0, v0, NO_LOBE
    v = v0 - half_v + bi * step_v
    if bi == 0 or bi == n_v - 1:
        return t, v, RECENTRE
    step_t *= 0.5
    step_v *= 0.5
    z = np.empty((3, 3))
    # The stencil's centre is a point already evaluated (the grid's best, or the best of the
    # last stencil where its fit did not move): that value is kept (the same candidate reached
    # along another row, equal to rounding).
    z_centre = best
    for _ in range(passes):
        for i in range(3):
            vv = v + (i - 1) * step_v
            a = (c_mps + vv) / (c_mps - vv)
            d_c_a = _line(alpha0, slots, f, dt_lo, dt_hi, hop_s, a, gamma, consts, coef)
            _row_phasors(centre, slots, t - step_t, curved, d_c_a, consts, step_t, phasors, turn)
            if n_cols:
                _row_edges(known, near, n_near, t - step_t, curved, d_c_a, consts, step_t, edges)
            for j in range(3):
                if j:
                    _advance(phasors, turn)
                    if n_cols:
                        _advance_edges(edges, n_near)
                if i == 1 and j == 1 and z_centre >= 0.0:
                    z[1, 1] = z_centre
                    continue
                cc = _candidate_c(
                    prefix, first, tail, slots, k, fs, t + (j - 1) * step_t, curved, d_c_a,
                    consts, coef, known, near, n_near, rot_key[j], rot[j], phasors, edges,
                )  # fmt: skip
                z[i, j] = cc.real * cc.real + cc.imag * cc.imag
        # z[i, j] ≈ z0 + gt x + gv y + ½ (htt x² + 2 htv x y + hvv y²); x, y in steps.
        gt = 0.5 * (z[1, 2] - z[1, 0])
        gv = 0.5 * (z[2, 1] - z[0, 1])
        htt = z[1, 2] - 2.0 * z[1, 1] + z[1, 0]
        hvv = z[2, 1] - 2.0 * z[1, 1] + z[0, 1]
        htv = 0.25 * (z[2, 2] - z[2, 0] - z[0, 2] + z[0, 0])
        det = htt * hvv - htv * htv
        moved = False
        z_centre = -1.0
        if htt < 0.0 and hvv < 0.0 and det > 0.0:
            x = (-hvv * gt + htv * gv) / det
            y = (htv * gt - htt * gv) / det
            if abs(x) <= 1.0 and abs(y) <= 1.0:
                t += x * step_t
                v += y * step_v
                moved = True
        if not moved:
            bi = 1
            bj = 1
            for i in range(3):
                for j in range(3):
                    if z[i, j] > z[bi, bj]:
                        bi, bj = i, j
            t += (bj - 1) * step_t
            v += (bi - 1) * step_v
            z_centre = z[bi, bj]
        step_t *= 0.5
        step_v *= 0.5
    return t, v, FOUND


@numba.njit(**_JIT)
def ended_gain(h: Any, inv_energy: Any, total: float, end_m: float, end_limit: float) -> bool:
    """:meth:`hil.estimation.refine.CoherentRefiner._ended`'s F test from the hops' terms
    ``h`` (complex, shape ``(M,)``), ``inv_energy`` (``1/Σ_{j≤i} a_j²``, shape ``(M,)``) and
    ``total = Σ |h_i|²/a_i²``: with ``c = cumsum(h)`` and ``F_k = |c_k|² inv_energy_k``,
    whether ``max_k end_m (F_k − F_{M−1}) − end_limit (total − F_k)`` over ``k < M − 1`` is
    above 0 (False where a gain is NaN, as ``np.max`` then is). The same operations in the
    same order as the NumPy expressions (a running complex sum, then elementwise), so the
    same bits."""
    m_hops = h.shape[0]
    fitted = np.empty(m_hops)
    c = h[0]
    fitted[0] = (c.real * c.real + c.imag * c.imag) * inv_energy[0]
    for i in range(1, m_hops):
        c = c + h[i]
        fitted[i] = (c.real * c.real + c.imag * c.imag) * inv_energy[i]
    last = fitted[m_hops - 1]
    above = False
    for i in range(m_hops - 1):
        lead = fitted[i]
        gain = end_m * (lead - last) - end_limit * (total - lead)
        if gain != gain:
            return False
        above = above or gain > 0.0
    return above


@numba.njit(**_JIT)
def fit_quality(
    prefix: Any, energy: Any, first: Any, tail: Any, alpha0: Any, centre: Any, slots: Any,
    k: Any, f: Any, dt_lo: Any, dt_hi: Any, amp2: Any, fs: float, hop_s: float,
    known: Any, gamma: float, tones: Any, n_tones: int, t_rx: float, alpha: float,
) -> tuple[float, float, float, float, float, float, float, complex, float]:  # fmt: skip
    """``(E/N0, ρ, E[ρ], ρ_tone, E[ρ_tone], ρ_run, E[ρ_run], C, E_s)`` of one candidate
    (:func:`hil.estimation.fit_steps.echo_quality` states them; ``C`` and ``E_s = Σ a_i² N_i``
    as :func:`candidate_sums`; ``known`` and ``gamma`` as :func:`candidate_sums`); ``tones``
    each hop's tone index (shape ``(M,)``, below ``n_tones``). E/N0 is ``inf`` where the
    windows hold no noise; the three coherences are then still the hop terms' own (their
    expected values 1, an echo's at infinite SNR): a windows' energy taken below the fit's
    by other echoes' parts (their energies are taken out, not their overlaps') says nothing
    of whether the terms add as one echo's."""
    m_hops = slots.shape[0]
    h = np.empty(m_hops, dtype=np.complex128)
    consts, coef = _scratch(slots, prefix)
    no_key, no_rot = np.empty(0), np.empty(0, dtype=np.complex128)  # no rotations kept
    d_c_alpha = _line(alpha0, slots, f, dt_lo, dt_hi, hop_s, alpha, gamma, consts, coef)
    c, es, signal = _candidate(
        prefix, energy, first, tail, centre, slots, k, amp2, fs, t_rx, gamma != 0.0,
        d_c_alpha, consts, coef, h, known, *_every_column(m_hops, known), no_key, no_rot,
        no_rot, np.empty((5, 0, 0), dtype=np.complex128), True,
    )  # fmt: skip
    mag2 = c.real * c.real + c.imag * c.imag
    spread = 0.0
    for i in range(m_hops):
        spread += h[i].real * h[i].real + h[i].imag * h[i].imag
    rho = mag2 / (m_hops * spread) if spread > 0.0 else 0.0
    noise = (signal - 2.0 * mag2 / es) / es  # es = Σ a_i² N_i: the windows' samples
    noiseless = not noise > 0.0
    s_hop = 0.0 if noiseless else max(spread / (es * noise) - 1.0, 0.0)
    expected = 1.0 if noiseless else (m_hops * s_hop + 1.0) / (m_hops * (s_hop + 1.0))
    sk = np.zeros(n_tones, dtype=np.complex128)
    nk = np.zeros(n_tones)
    pk = np.zeros(n_tones)
    for i in range(m_hops):
        g = tones[i]
        sk[g] += h[i]
        nk[g] += 1.0
        pk[g] += h[i].real * h[i].real + h[i].imag * h[i].imag
    num = 0.0
    den = 0.0
    e_num = 0.0
    e_den = 0.0
    for g in range(n_tones):
        num += sk[g].real * sk[g].real + sk[g].imag * sk[g].imag
        den += nk[g] * pk[g]
        e_num += nk[g] * nk[g] * s_hop + nk[g]
        e_den += nk[g] * nk[g] * (s_hop + 1.0)
    a_hat = 2.0 * math.sqrt(mag2) / es
    en0 = math.inf if noiseless else a_hat * a_hat * es / (4.0 * noise)
    # Over runs of RUN_HOPS consecutive hops (a drifting phase: an accelerating echo).
    sub = RUN_HOPS
    s_num = 0.0
    s_den = 0.0
    e_snum = 0.0
    e_sden = 0.0
    for b in range(m_hops - sub + 1):
        z = complex(0.0, 0.0)
        p = 0.0
        for i in range(b, b + sub):
            z += h[i]
            p += h[i].real * h[i].real + h[i].imag * h[i].imag
        s_num += z.real * z.real + z.imag * z.imag
        s_den += sub * p
        e_snum += sub * sub * s_hop + sub
        e_sden += sub * sub * (s_hop + 1.0)
    rho_run = s_num / s_den if s_den > 0.0 else 0.0
    if noiseless:
        e_num, e_den, e_snum, e_sden = 1.0, 1.0, 1.0, 1.0
    return (
        en0, rho, expected, num / den if den > 0.0 else 0.0, e_num / e_den, rho_run,
        e_snum / e_sden, c, es,
    )  # fmt: skip


@numba.njit(**_JIT)
def echo_input(columns: Any, first_index: int, fs_hz: float, out: Any) -> None:
    """Add the echoes of the ``known`` ``columns`` (shape ``(5, Q)``:
    :mod:`hil.estimation.echo_model`) to ``out`` (shape ``(n,)``, input samples
    ``first_index …``): ``2|w| cos(2π (g (t − t_e) + arg(w)/2π))`` over each hop's
    ``[start, end)``, the phase a function of each sample's own index."""
    n = out.shape[0]
    for h in range(columns.shape[1]):
        lo = max(0, int(math.ceil(columns[2, h].real * fs_hz - first_index)))
        hi = min(n, int(math.ceil(columns[3, h].real * fs_hz - first_index)))
        if hi <= lo:
            continue
        w = columns[0, h]
        g, t_e = columns[1, h].real, columns[4, h].real
        amp = 2.0 * abs(w)
        arg = math.atan2(w.imag, w.real) / (2.0 * math.pi)
        for k in range(lo, hi):
            cyc = (g * ((first_index + k) / fs_hz - t_e) + arg) % 1.0
            out[k] += amp * math.cos(2.0 * math.pi * cyc)
