"""Compiled loops of the first-arrival readout (numba, ``nogil``): the next-tone channel, the
ramp model's residuals, the direct path's Doppler score (:mod:`hil.estimation.first_arrival`)
and the late taps' table (:mod:`hil.estimation.late_taps`).

Each kernel computes what the readout's NumPy expressions compute, with the same bits: every
output is the same sequence of floating-point operations NumPy's loops perform on x86-64 with
AVX2 and FMA (what NumPy dispatches to there), checked against them element by element in
``tests/estimation_gcas/test_first_arrival_kernels.py``:

- a complex product ``a · b`` is ``(fma(a_r, b_r, −a_i b_i), fma(a_r, b_i, a_i b_r))``
  (NumPy's SIMD complex multiply; a real operand is the complex ``(x, 0)``);
- ``|z|`` is ``√(fma(s/l, s/l, 1)) · l`` with ``l``, ``s`` the larger and the smaller of
  ``|z_r|``, ``|z_i|`` (``0/0`` read as 0; NumPy's SIMD complex absolute);
- a sum along an array's last axis (``np.add.reduce``, ``np.sum``, ``np.mean``) is NumPy's
  pairwise sum (:func:`pairwise_sum`); along any other axis, the rows added in order;
- ``e^{jy}`` of a purely imaginary argument is ``(cos y, sin y)`` from the C library, as
  NumPy's complex exponential (``exp(0) = 1`` times each);
- no other operation is fused or reordered: numba compiles without ``fastmath``, so LLVM
  contracts nothing into an FMA that the source does not call.

The FMA here is exact everywhere (``llvm.fma``), so the kernels give the same bits on any
machine; NumPy's loops fuse only where the CPU has FMA (x86-64 FMA3, AArch64), so on a CPU
without it NumPy's own expressions round twice and differ from these in the last bits.

Why compiled: the readout runs once per detection on arrays of ``M × L`` (10 × 1133 in the
built-in tank run) and ``C × M × L`` (33 × 10 × 60) elements, each NumPy expression a pass
over a temporary plus its call overhead; fused, the passes share one loop.

Arrays are C-contiguous, ``float64`` or ``complex128`` as stated, indices ``int64``.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

_JIT: dict[str, Any] = {"cache": True, "nogil": True}


def _fma_intrinsic(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
    """``a · b + c`` rounded once (LLVM's ``llvm.fma.f64``: the hardware's FMA, or the C
    library's ``fma`` where there is none; the same value either way)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        d = ir.DoubleType()
        fn = builder.module.declare_intrinsic("llvm.fma", [d], ir.FunctionType(d, [d, d, d]))
        return builder.call(fn, args)

    return sig, codegen


#: ``_fma(a, b, c)`` inside a kernel: ``a · b + c`` rounded once.
_fma: Any = intrinsic(_fma_intrinsic)


@numba.njit(**_JIT)
def _pairwise_block(a: Any, lo: int, n: int) -> float:
    """NumPy's pairwise sum of ``a[lo : lo + n]`` for ``n <= 128`` (one leaf of
    :func:`pairwise_sum`)."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0 = a[lo]
    r1 = a[lo + 1]
    r2 = a[lo + 2]
    r3 = a[lo + 3]
    r4 = a[lo + 4]
    r5 = a[lo + 5]
    r6 = a[lo + 6]
    r7 = a[lo + 7]
    i = 8
    stop = n - n % 8
    while i < stop:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@numba.njit(**_JIT)
def pairwise_sum(a: Any, lo: int, n: int) -> float:
    """NumPy's pairwise sum of ``a[lo : lo + n]`` (``a`` float, 1-D): up to 128 terms one
    leaf (:func:`_pairwise_block`: under 8 in order from 0, else eight interleaved partial
    sums combined as ``((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))``, then the terms
    left over in order); above, the two halves (the first a multiple of 8 terms) each summed
    so and added. The halves are walked with an explicit stack (a recursive function is
    not cached by numba). The sum starts from NumPy's identity ``+0.0`` (``−0.0`` terms sum
    to ``+0.0``)."""
    if n <= 128:
        return 0.0 + _pairwise_block(a, lo, n)
    # Post-order walk: a node is (lo, n, state); state 0: not yet split, 1: both halves
    # summed (their values the top two of ``values``).
    depth = 2 * (64 - 7) + 2
    node_lo = np.empty(depth, dtype=np.int64)
    node_n = np.empty(depth, dtype=np.int64)
    node_state = np.empty(depth, dtype=np.int64)
    values = np.empty(depth)
    top = 0
    nv = 0
    node_lo[0] = lo
    node_n[0] = n
    node_state[0] = 0
    top = 1
    while top > 0:
        top -= 1
        t_lo = node_lo[top]
        t_n = node_n[top]
        if t_n <= 128:
            values[nv] = _pairwise_block(a, t_lo, t_n)
            nv += 1
        elif node_state[top] == 1:
            nv -= 1
            values[nv - 1] = values[nv - 1] + values[nv]
        else:
            n2 = t_n // 2
            n2 -= n2 % 8
            node_state[top] = 1  # revisit once both halves are summed
            top += 1
            node_lo[top] = t_lo + n2  # second half, summed after the first
            node_n[top] = t_n - n2
            node_state[top] = 0
            top += 1
            node_lo[top] = t_lo
            node_n[top] = n2
            node_state[top] = 0
            top += 1
    return 0.0 + values[0]


@numba.njit(**_JIT)
def complex_abs(re: float, im: float) -> float:
    """``|re + j im|`` as NumPy's SIMD complex absolute computes it (see the module
    docstring; an infinite part gives inf, a NaN part NaN)."""
    re = abs(re)
    im = abs(im)
    if re == math.inf or im == math.inf:
        return math.inf
    if re != re or im != im:
        return math.nan
    larger = max(re, im)
    smaller = min(im, re)
    ratio = 0.0 if larger == 0.0 else smaller / larger
    return math.sqrt(_fma(ratio, ratio, 1.0)) * larger


@numba.njit(**_JIT)
def _channel_row(
    x: Any, index: Any, fs: float, br: float, w: int, inv_w: float, full: Any, box: Any,
    p_all: Any, cre: Any, cim: Any,
) -> None:  # fmt: skip
    """One boundary's row of :func:`next_tone_channel`: ``x`` (shape ``(N,)``) at absolute
    sample indices ``index`` (shape ``(N,)``, int64), ``br`` its ``b``; ``full``, ``box``,
    ``p_all`` the row's outputs; ``cre``, ``cim`` (shape ``(N,)``) scratch."""
    n = x.shape[0]
    sr = 0.0
    si = 0.0
    for k in range(n):
        # The phase b t: the complex product (0 + j b)(t + j0) has a real part of ±0,
        # and e^{±0} = 1 leaves (cos, sin) as they are.
        y = br * (index[k] / fs)
        c = math.cos(y)
        s = math.sin(y)
        xk = x[k]
        zr = _fma(xk, c, -(0.0 * s))
        zi = _fma(xk, s, 0.0 * c)
        if k == 0:
            sr = zr
            si = zi
        else:
            sr = sr + zr
            si = si + zi
        cre[k] = sr
        cim[k] = si
    for k in range(n - w):
        full[k] = complex(cre[k + w] - cre[k], cim[k + w] - cim[k])
    for k in range(n - 2 * w):
        fr = full[k + w].real - full[k].real
        fi = full[k + w].imag - full[k].imag
        box[k] = complex(fr, fi)
        a = complex_abs(_fma(fr, inv_w, -(fi * 0.0)), _fma(fr, 0.0, fi * inv_w))
        p_all[k] = a * a


@numba.njit(**_JIT)
def next_tone_channel(
    d: Any, idx: Any, fs: float, b: Any, w: int, inv_w: float, full: Any, box: Any, p_all: Any
) -> None:
    """The next-tone channel of the ``M`` boundaries and its change over a window.

    ``d`` (shape ``(M, N)``, real): the input at absolute sample indices ``idx`` (shape
    ``(M, N)``, int64); ``b`` (shape ``(M,)``): the imaginary part of each boundary's
    ``−j2π α f_next`` as NumPy holds it. With ``t = idx / fs`` and the phasor
    ``z = e^{j b t}``, the product ``d z`` is summed along each row; ``full`` (shape
    ``(M, N − w)``, complex) is that sum's change over ``w`` (the boxcar ending at columns
    ``w ..``), ``box`` (shape ``(M, N − 2w)``, complex) the boxcar's change over ``w``, and
    ``p_all`` (shape ``(M, N − 2w)``) ``|box · (1/w)|²``."""
    m, n = d.shape
    cre = np.empty(n)
    cim = np.empty(n)
    for r in range(m):
        _channel_row(d[r], idx[r], fs, b[r], w, inv_w, full[r], box[r], p_all[r], cre, cim)


@numba.njit(**_JIT)
def ring_channel(
    ring: Any, pos: Any, period: int, sign: int, first: Any, fs: float, b: Any, w: int,
    inv_w: float, full: Any, box: Any, p_all: Any,
) -> None:  # fmt: skip
    """:func:`next_tone_channel` of rows read from a history (the same bits): row ``r`` is
    ``ring[pos[r] : pos[r] + N]`` (``ring`` float, 1-D; ``pos`` shape ``(M,)``, int64), less
    (``sign`` > 0) or plus the row ``period`` samples before it where ``period`` > 0 (the
    clutter canceller), at absolute indices ``first[r] .. first[r] + N − 1`` (``N``:
    ``full``'s columns plus ``w``). No ``(M, N)`` index, gather or difference array."""
    m = pos.shape[0]
    n = full.shape[1] + w
    cre = np.empty(n)
    cim = np.empty(n)
    x = np.empty(n)
    index = np.empty(n, dtype=np.int64)
    for r in range(m):
        p = pos[r]
        for k in range(n):
            v = ring[p + k]
            if period > 0:
                u = ring[p - period + k]
                v = v - u if sign > 0 else v + u
            x[k] = v
            index[k] = first[r] + k
        _channel_row(x, index, fs, b[r], w, inv_w, full[r], box[r], p_all[r], cre, cim)


@numba.njit(**_JIT)
def window_start_phasors(theta: Any, n: Any, w: int, out: Any) -> None:
    """NumPy's ``exp(1j * outer(theta, n − w + 1))`` into ``out`` (shape ``(M, L)``, complex):
    each boundary's beat ``theta`` (shape ``(M,)``, rad per sample) at the first sample of the
    window ending at each index of ``n`` (shape ``(L,)``, int64). The product ``1j · v`` is
    NumPy's fused complex one: real part ±0 (so ``e^{±0} = 1``), imaginary ``fma(0, 0, v)``
    (``v``, or +0 for −0)."""
    m = theta.shape[0]
    length = n.shape[0]
    for mi in range(m):
        th = theta[mi]
        for j in range(length):
            y = _fma(0.0, 0.0, th * np.float64(n[j] - w + 1))
            out[mi, j] = complex(math.cos(y), math.sin(y))


@numba.njit(**_JIT)
def ramp_residuals(
    grid: Any,
    pre: int,
    frac: Any,
    theta: Any,
    jump: Any,
    n: Any,
    w: int,
    geometric: Any,
    start: Any,
    inv_w: float,
    excess: Any,
    level: bool,
    out: Any,
) -> None:
    """Least-squares residual of the ramp model for each onset (the body of
    ``FirstArrivalReadout._ramp_residuals``).

    ``grid`` (shape ``(C,)``): the onsets, samples after each boundary's predicted switch;
    ``pre``: the window index of boundary 0's sample; ``frac``, ``theta``, ``jump`` (shape
    ``(M,)`` each): each boundary's predicted switch (samples past its sample), beat (rad per
    sample) and phase jump (rad); each onset on each boundary is
    ``o = (pre + grid) + frac`` (window samples) and the beat's phasor there
    ``at_o = e^{−j(θ o + jump)}`` (NumPy's ``np.exp(-1j * (theta * o + jump))``: the product's
    real part ±0, its imaginary ``fma(−0, 0, −v)``); ``n`` (shape ``(L,)``, int64): the
    window indices; ``geometric`` (shape ``(M, w + 1)``, complex) and ``start`` (shape
    ``(M, L)``, complex): the ramp's table and the beat's phasor at each window's first
    sample; ``excess`` (shape ``(L,)``): the measured power less the noise. The model at
    onset ``c``, boundary ``m``, window ``l``: ``((start · at_o) · geometric[m, w − k] + k) ·
    (1/w)`` with ``k`` the window's samples at or after the onset (``n − ⌈o⌉ + 1`` within
    ``0 .. w``); its power's mean over ``M`` is scaled by least squares to ``excess`` (with
    ``level``, both less their means). ``out`` (shape ``(C,)``): the squared residual summed
    over ``L``."""
    c_count = grid.shape[0]
    m = frac.shape[0]
    length = n.shape[0]
    model = np.empty(length)
    prod = np.empty(length)
    ex = excess
    if level:
        ex = np.empty(length)
        mean_ex = pairwise_sum(excess, 0, length) / length
        for j in range(length):
            ex[j] = excess[j] - mean_ex
    for c in range(c_count):
        base = np.float64(pre) + grid[c]
        for mi in range(m):
            oc = base + frac[mi]
            shift = 1 - np.int64(math.ceil(oc))
            y = _fma(-0.0, 0.0, -(theta[mi] * oc + jump[mi]))
            ar = math.cos(y)
            ai = math.sin(y)
            for j in range(length):
                k = n[j] + shift
                if k < 0:
                    k = 0
                if k > w:
                    k = w
                sr = start[mi, j].real
                si = start[mi, j].imag
                pr = _fma(sr, ar, -(si * ai))
                pi = _fma(sr, ai, si * ar)
                g = geometric[mi, w - k]
                qr = _fma(pr, g.real, -(pi * g.imag))
                qi = _fma(pr, g.imag, pi * g.real)
                qr = qr + np.float64(k)
                qi = qi + 0.0
                a = complex_abs(_fma(qr, inv_w, -(qi * 0.0)), _fma(qr, 0.0, qi * inv_w))
                a = a * a
                if mi == 0:
                    model[j] = a
                else:
                    model[j] = model[j] + a
        for j in range(length):
            model[j] = model[j] / m
        if level:
            mean_model = pairwise_sum(model, 0, length) / length
            for j in range(length):
                model[j] = model[j] - mean_model
        for j in range(length):
            prod[j] = model[j] * model[j]
        mm = pairwise_sum(prod, 0, length)
        for j in range(length):
            prod[j] = model[j] * ex[j]
        num = pairwise_sum(prod, 0, length)
        scale = num / (mm if not mm < 1e-300 else 1e-300)
        for j in range(length):
            left = ex[j] - scale * model[j]
            prod[j] = left * left
        out[c] = pairwise_sum(prod, 0, length)


@numba.njit(**_JIT)
def doppler_score(b: Any, ft: Any, q: Any, cols: Any, col_start: Any, out: Any) -> None:
    """The direct path's Doppler score over speeds (the body of
    ``FirstArrivalReadout._direct_alpha``).

    ``b`` (shape ``(G,)``): the imaginary part of ``−j2π Δα`` per speed as NumPy holds it;
    ``ft`` (shape ``(M,)``): each boundary's ``f_m t_m``; ``q`` (shape ``(M,)``, complex):
    its amplitude with the known phase removed; ``cols`` (shape ``(M,)``, int64) the
    boundaries grouped by tone (ascending tone, ascending boundary within), tone ``k``'s at
    ``cols[col_start[k] : col_start[k + 1]]``. For
    each speed ``g``: ``Σ_k |Σ_{m ∈ tone k} e^{j b_g ft_m} q_m|²`` into ``out[g]``."""
    g_count = b.shape[0]
    k_count = col_start.shape[0] - 1
    power = np.empty(k_count)
    for g in range(g_count):
        bg = b[g]
        for k in range(k_count):
            # NumPy gathers a tone's columns (``rot[:, cols]``) in column-major order: its
            # sum along them adds the columns in order, from +0.
            sr = 0.0
            si = 0.0
            for i in range(col_start[k], col_start[k + 1]):
                mi = cols[i]
                # The phase b ft: the complex product (0 + j b)(ft + j0), its real part ±0.
                y = bg * ft[mi]
                c = math.cos(y)
                s = math.sin(y)
                qr = q[mi].real
                qi = q[mi].imag
                sr = sr + _fma(c, qr, -(s * qi))
                si = si + _fma(c, qi, s * qr)
            a = complex_abs(sr, si)
            power[k] = a * a
        out[g] = pairwise_sum(power, 0, k_count)


@numba.njit(**_JIT)
def late_tap_table(e_cur: Any, e_prev: Any, at_switch: Any, taps: Any) -> None:
    """The late taps' table of :func:`hil.estimation.late_taps.direct_amplitudes`: each tap
    ``g`` of each boundary ``m`` sounds ``e_prev[m, i] · at_switch[m, g]`` before its switch
    at sample ``g + 1`` and ``e_cur[m, i]`` from it on, into ``taps[m, g, i]``.

    ``e_cur``, ``e_prev`` (shape ``(M, N)``, complex): the steady tones; ``at_switch`` (shape
    ``(M, G)``, complex): each tap's phase at its switch; ``taps`` (shape ``(M, G, N)``,
    complex). NumPy's ``np.where(i >= g + 1, e_cur, e_prev · at_switch)`` without its
    ``(M, G, N)`` product and mask: the product is NumPy's fused complex multiply."""
    m_count, g_count, n = taps.shape
    for m in range(m_count):
        for g in range(g_count):
            ar = at_switch[m, g].real
            ai = at_switch[m, g].imag
            for i in range(min(g + 1, n)):
                br = e_prev[m, i].real
                bi = e_prev[m, i].imag
                taps[m, g, i] = complex(_fma(br, ar, -(bi * ai)), _fma(br, ai, bi * ar))
            for i in range(g + 1, n):
                taps[m, g, i] = e_cur[m, i]


def warm_up() -> None:
    """Call every kernel once on a few zeros, with the argument types the readout passes:
    the first call in a process loads the machine code from numba's cache (or, in a fresh
    checkout, compiles it: seconds), which must not happen at a live run's first detection."""
    w = 2
    full = np.zeros((1, 4), dtype=np.complex128)
    box = np.zeros((1, 2), dtype=np.complex128)
    p_all = np.zeros((1, 2))
    idx = np.arange(6, dtype=np.int64).reshape(1, 6)
    next_tone_channel(np.zeros((1, 6)), idx, 1.0, np.zeros(1), w, 0.5, full, box, p_all)
    first = np.zeros(1, dtype=np.int64)
    for period in (0, 1):
        ring_channel(np.zeros(8), first + 1, period, 1, first, 1.0, np.zeros(1), w, 0.5, full,
                     box, p_all)  # fmt: skip
    out = np.zeros(1)
    geometric = np.zeros((1, w + 1), dtype=np.complex128)
    start = np.zeros((1, 3), dtype=np.complex128)
    n = np.arange(3, dtype=np.int64)
    window_start_phasors(np.zeros(1), n, w, start)
    one = np.zeros(1)
    for level in (False, True):
        ramp_residuals(one, 1, one, one, one, n, w, geometric, start, 0.5, np.zeros(3), level, out)
    cols = np.zeros(1, dtype=np.int64)
    starts = np.array([0, 1], dtype=np.int64)
    doppler_score(np.zeros(1), np.zeros(1), np.zeros(1, dtype=np.complex128), cols, starts, out)
    e = np.zeros((1, 3), dtype=np.complex128)
    late_tap_table(e, e, np.zeros((1, 2), dtype=np.complex128), np.zeros((1, 2, 3), np.complex128))
