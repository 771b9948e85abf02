"""Compiled inner loops of the GCAS receiver (numba, ``nogil``): front end, coarse search,
exact unit-correlator windows.

Each kernel is a plain loop over samples whose every output is computed by the same sequence
of floating-point operations whatever the call it falls in, so streaming callers keep their
"any chunking gives the same bits" property. The kernels hold no state: callers pass their
state arrays in and the kernels update them in place. Shapes and units are given per kernel;
all arrays are C-contiguous, ``float64`` unless stated, indices ``int64``.

Why compiled: at the ``att`` rate the receiver touches ``D·K = 256`` correlator cells per
baseband sample; as NumPy expressions every stage costs several passes over temporaries plus
Python overhead per call, which held the receiver near 30x real time (target 100x).
Compiled with ``cache=True``: the first call in a fresh checkout compiles (a few seconds) and
writes ``__pycache__``; later processes load the machine code.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

_JIT: dict[str, Any] = {"cache": True, "nogil": True}


@numba.njit(**_JIT)
def fir_decimate(
    buf: Any, lo: int, n_out: int, r: int, g_re: Any, g_im: Any, out_re: Any, out_im: Any
) -> None:
    """Decimating complex-tap FIR on a real signal.

    ``out[n] = Σ_{i<T} buf[lo + n·r + i] · g[i]`` for ``n < n_out`` (``g = g_re + j g_im``,
    shape ``(T,)``; ``buf`` real, shape ``(>= lo + (n_out − 1) r + T,)``). Four interleaved
    partial sums per output (fixed order: the result of an output never depends on
    ``n_out``) break the add dependency chain.
    """
    t = g_re.shape[0]
    t4 = t - t % 4
    for n in range(n_out):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        q0 = 0.0
        q1 = 0.0
        q2 = 0.0
        q3 = 0.0
        base = lo + n * r
        for i in range(0, t4, 4):
            v0 = buf[base + i]
            v1 = buf[base + i + 1]
            v2 = buf[base + i + 2]
            v3 = buf[base + i + 3]
            s0 += v0 * g_re[i]
            s1 += v1 * g_re[i + 1]
            s2 += v2 * g_re[i + 2]
            s3 += v3 * g_re[i + 3]
            q0 += v0 * g_im[i]
            q1 += v1 * g_im[i + 1]
            q2 += v2 * g_im[i + 2]
            q3 += v3 * g_im[i + 3]
        for i in range(t4, t):
            v0 = buf[base + i]
            s0 += v0 * g_re[i]
            q0 += v0 * g_im[i]
        out_re[n] = (s0 + s1) + (s2 + s3)
        out_im[n] = (q0 + q1) + (q2 + q3)


@numba.njit(**_JIT)
def mix_down(
    buf: Any, lo: int, n_out: int, r: int, g_re: Any, g_im: Any, first: int,
    cycles_per_output: float, out: Any,
) -> None:  # fmt: skip
    """:func:`fir_decimate` then the output rotation of :mod:`hil.estimation.baseband`:
    ``out[n] = e^{−j2π frac((first + n)·c)} · acc[n]`` (``c = cycles_per_output``; ``out``
    complex, shape ``(n_out,)``), the product as real products and sums each rounded once.
    The phase is ``−2π·frac`` (the product NumPy's ``-2j * np.pi * phase`` gives as the
    imaginary part, its real part 0) and the phasor its cosine and sine (what ``np.exp`` of
    that imaginary number gives: the C library's complex exponential, ``e^0`` times them):
    the same bits as the NumPy formulation, checked over 10⁷ phases."""
    acc_re = np.empty(n_out)
    acc_im = np.empty(n_out)
    fir_decimate(buf, lo, n_out, r, g_re, g_im, acc_re, acc_im)
    for n in range(n_out):
        y = -2.0 * math.pi * ((float(first + n) * cycles_per_output) % 1.0)
        c = math.cos(y)
        s = math.sin(y)
        out[n] = complex(c * acc_re[n] - s * acc_im[n], c * acc_im[n] + s * acc_re[n])


@numba.njit(**_JIT)
def _peak_at(s: Any, i: int, half_width: int, known: int) -> bool:
    """Whether ``s[i]`` is finite, greater than every sample in the ``half_width`` before it
    and not smaller than any in the ``half_width`` after it that is below index ``known``."""
    v = s[i]
    if not v > -math.inf:
        return False
    for j in range(max(0, i - half_width), i):
        if s[j] >= v:
            return False
    for j in range(i + 1, min(known, i + half_width + 1)):  # noqa: SIM110 - numba: no all(genexpr)
        if s[j] > v:
            return False
    return True


@numba.njit(**_JIT)
def peak_indices(s: Any, half_width: int, lo: int, hi: int) -> Any:
    """Indices ``i`` in ``[lo, hi)`` that are the first maximum of ``s`` over ``±half_width``:
    greater than every sample in the ``half_width`` before it and not smaller than any in the
    ``half_width`` after it (samples outside ``s`` count as −inf; a plateau yields one peak).
    ``s`` shape ``(n,)``; returns int64 indices, ascending."""
    out = np.empty(max(hi - lo, 0), dtype=np.int64)
    count = 0
    for i in range(lo, hi):
        if _peak_at(s, i, half_width, s.shape[0]):
            out[count] = i
            count += 1
    return out[:count]


@numba.njit(**_JIT)
def _cell_peak_at(
    s: Any, i: int, d: int, half_rows: int, half_cols: int, known: int, leak: Any
) -> bool:  # fmt: skip
    """Whether ``s[i, d]`` is finite, the first maximum of ``s`` over rows ``±half_rows`` and
    columns ``±half_cols`` (greater than every cell before it in row-major order within that
    window, not smaller than any after it in rows below ``known``), and greater than the leak
    ``leak[|d − e|] · s[i, e]`` of every other cell ``e`` of its row."""
    v = s[i, d]
    if not v > -math.inf:
        return False
    n_cols = s.shape[1]
    c_lo = max(0, d - half_cols)
    c_hi = min(n_cols, d + half_cols + 1)
    for j in range(max(0, i - half_rows), min(known, i + half_rows + 1)):
        for e in range(c_lo, c_hi):
            if j < i or (j == i and e < d):
                if s[j, e] >= v:
                    return False
            elif s[j, e] > v:
                return False
    for e in range(n_cols):  # noqa: SIM110 - numba: no all(genexpr)
        if s[i, e] * leak[abs(d - e)] >= v:
            return False
    return True


@numba.njit(**_JIT)
def peak_cells(
    s: Any, half_rows: int, half_cols: int, lo: int, hi: int, leak: Any
) -> Any:  # fmt: skip
    """Cells ``(i, d)`` with ``i`` in ``[lo, hi)`` that are the first maximum of ``s`` over
    ``±half_rows`` rows and ``±half_cols`` columns (:func:`peak_indices` in two dimensions:
    rows are time, columns hypotheses; −inf cells are never one) and above the leak of the
    other cells of their row (``leak`` shape ``(D,)``, by column distance; 0 for none).
    ``s`` shape ``(n, D)``; returns row and column indices (int64, shape ``(P,)`` each),
    row-major order."""
    rows = np.empty((hi - lo) * s.shape[1] if hi > lo else 0, dtype=np.int64)
    cols = np.empty_like(rows)
    count = 0
    if half_cols >= s.shape[1] - 1 and hi > lo:
        return _full_width_peak_cells(s, half_rows, lo, hi, leak, rows, cols)
    for i in range(lo, hi):
        for d in range(s.shape[1]):
            if _cell_peak_at(s, i, d, half_rows, half_cols, s.shape[0], leak):
                rows[count] = i
                cols[count] = d
                count += 1
    return rows[:count], cols[:count]


@numba.njit(**_JIT)
def _full_width_peak_cells(
    s: Any, half_rows: int, lo: int, hi: int, leak: Any, rows: Any, cols: Any
) -> Any:  # fmt: skip
    """:func:`peak_cells` where the window spans every column: a cell is then the first
    maximum of its own row (the first of its row's largest values; NaN and −inf never one)
    greater than every value of the ``half_rows`` rows before it and not smaller than any of
    those after it, the test of :func:`_cell_peak_at` read from each row's maximum (each row's
    values are compared once instead of once per finite cell of the rows around it)."""
    n, n_cols = s.shape
    r_lo = max(0, lo - half_rows)
    r_hi = min(n, hi + half_rows)
    top = np.empty(r_hi - r_lo)
    first = np.empty(r_hi - r_lo, dtype=np.int64)
    for j in range(r_lo, r_hi):
        m = -math.inf
        at = -1
        for e in range(n_cols):
            if s[j, e] > m:  # NaN compares false: it fails no test in _cell_peak_at either
                m = s[j, e]
                at = e
        top[j - r_lo] = m
        first[j - r_lo] = at
    count = 0
    for i in range(lo, hi):
        d = first[i - r_lo]
        if d < 0:
            continue
        v = top[i - r_lo]
        ok = True
        for j in range(max(0, i - half_rows), i):
            if top[j - r_lo] >= v:
                ok = False
                break
        if ok:
            for j in range(i + 1, min(n, i + half_rows + 1)):
                if top[j - r_lo] > v:
                    ok = False
                    break
        if ok and _cell_peak_at(s, i, d, half_rows, n_cols, n, leak):
            rows[count] = i
            cols[count] = d
            count += 1
    return rows[:count], cols[:count]


@numba.njit(**_JIT)
def second_peak_cells(
    s: Any, half_rows: int, half_inner: int, half_cols: int, lo: int, hi: int, leak: Any,
    level: float,
) -> Any:  # fmt: skip
    """Cells ``(i, d)`` with ``i`` in ``[lo, hi)`` that :func:`peak_cells` gives over
    ``±half_inner`` rows but not over ``±half_rows`` (a second maximum within
    ``±half_rows`` rows of a greater one), at least ``level`` times the greatest cell of
    that window. Row and column indices (int64, shape ``(P,)`` each), row-major order."""
    rows = np.empty((hi - lo) * s.shape[1] if hi > lo else 0, dtype=np.int64)
    cols = np.empty_like(rows)
    n = s.shape[0]
    count = 0
    for i in range(lo, hi):
        for d in range(s.shape[1]):
            if not _cell_peak_at(s, i, d, half_inner, half_cols, n, leak):
                continue
            if _cell_peak_at(s, i, d, half_rows, half_cols, n, leak):
                continue
            top = -math.inf
            for j in range(max(0, i - half_rows), min(n, i + half_rows + 1)):
                for e in range(max(0, d - half_cols), min(s.shape[1], d + half_cols + 1)):
                    top = max(top, s[j, e])
            if s[i, d] >= level * top:
                rows[count] = i
                cols[count] = d
                count += 1
    return rows[:count], cols[:count]


@numba.njit(**_JIT)
def masked_peak_cells(
    s: Any, half_rows: int, half_cols: int, own_cols: int, apart: int, lo: int, hi: int,
    level: float, below: float,
) -> Any:  # fmt: skip
    """Cells ``(i, d)`` with ``i`` in ``[lo, hi)`` that are the first maximum of ``s`` over
    ``±half_rows`` rows and ``±own_cols`` columns but not over ``±half_cols`` columns: the
    greatest cell of that wider window (the first in row-major order) lies at least
    ``apart`` rows from row ``i`` and ``s[i, d]`` reaches ``level`` times it but not
    ``below`` times it. A peak of
    its own beside a greater one of another row (rows are time, columns hypotheses; −inf
    cells are never one). ``s`` shape ``(n, D)``; returns row and column indices (int64,
    shape ``(P,)`` each), row-major order."""
    rows = np.empty((hi - lo) * s.shape[1] if hi > lo else 0, dtype=np.int64)
    cols = np.empty_like(rows)
    n, n_cols = s.shape
    count = 0
    for i in range(lo, hi):
        r_lo, r_hi = max(0, i - half_rows), min(n, i + half_rows + 1)
        for d in range(n_cols):
            v = s[i, d]
            if not v > -math.inf:
                continue
            own = True
            for j in range(r_lo, r_hi):
                for e in range(max(0, d - own_cols), min(n_cols, d + own_cols + 1)):
                    if j < i or (j == i and e < d):
                        if s[j, e] >= v:
                            own = False
                    elif s[j, e] > v:
                        own = False
                if not own:
                    break
            if not own:
                continue
            top, top_row = v, i
            for j in range(r_lo, r_hi):
                for e in range(max(0, d - half_cols), min(n_cols, d + half_cols + 1)):
                    if s[j, e] > top:
                        top, top_row = s[j, e], j
            if abs(top_row - i) >= apart and level * top <= v < below * top:
                rows[count] = i
                cols[count] = d
                count += 1
    return rows[:count], cols[:count]


@numba.njit(**_JIT)
def first_possible_cells(
    s: Any, half_rows: int, half_cols: int, lo: int, hi: int, leak: Any
) -> Any:  # fmt: skip
    """The first row ``i`` in ``[lo, hi)`` holding a cell that can still become a
    :func:`peak_cells` peak once the rows from ``hi`` on arrive, and a mask of those cells
    (shape ``(D,)``); ``hi`` and an empty mask if none can (``s[:hi]`` is read)."""
    mask = np.zeros(s.shape[1], dtype=np.bool_)
    for i in range(lo, hi):
        found = False
        for d in range(s.shape[1]):
            if _cell_peak_at(s, i, d, half_rows, half_cols, hi, leak):
                mask[d] = True
                found = True
        if found:
            return i, mask
    return hi, mask


@numba.njit(**_JIT)
def _kth_smallest(a: Any, k: int, work: Any) -> float:
    """The ``k``-th smallest value of ``a`` (0-based; shape ``(n,)``, no NaN; ``work`` shape
    ``(2n,)``, scratch). Quickselect with a branch-free out-of-place partition: each pass
    writes every value at both ends of the other half of ``work`` and moves the end it
    belongs to (below the pivot: front, above: back; equal values fall between), so the
    loop has no data-dependent branch (a compare-and-swap partition mispredicts on about
    half of the values of noise-like input)."""
    n = a.shape[0]
    cur, nxt = 0, n
    for i in range(n):
        work[i] = a[i]
    m = n
    while True:
        x0, x1, x2 = work[cur], work[cur + m // 2], work[cur + m - 1]
        pivot = max(min(x0, x1), min(max(x0, x1), x2))  # the median of the three
        lo = nxt
        hi = nxt + m - 1
        for i in range(cur, cur + m):
            v = work[i]
            work[lo] = v
            work[hi] = v
            lo += v < pivot
            hi -= v > pivot
        n_lo = lo - nxt
        n_hi = nxt + m - 1 - hi
        if k < n_lo:
            cur, m = nxt, n_lo
        elif k >= m - n_hi:
            k -= m - n_hi
            cur, m = hi + 1, n_hi
        else:
            return pivot
        nxt = 0 if cur >= n else n  # the next pass writes into the half not read


@numba.njit(**_JIT)
def median(a: Any, work: Any) -> float:
    """``np.median(a)`` bit for bit (``a`` shape ``(n,)``, ``n >= 1``, no NaN; ``work`` shape
    ``(2n,)``, scratch): the middle order statistic, or for even ``n`` the two middle ones
    ``lo``, ``hi`` as ``(lo + hi) / 2`` (numpy's and numba's formula)."""
    n = a.shape[0]
    half = n >> 1
    if n & 1:
        return _kth_smallest(a, half, work)
    lo = _kth_smallest(a, half - 1, work)
    # The next order statistic: lo again if more than ``half - 1`` others are not above it,
    # else the least value above it.
    n_le = 0
    hi = math.inf
    for i in range(n):
        v = a[i]
        n_le += v <= lo
        hi = min(hi, v) if v > lo else hi
    if n_le > half:
        hi = lo
    return (lo + hi) / 2


@numba.njit(**_JIT)
def runner_up_pairs(rows: Any, cols: Any) -> Any:
    """``(d, d₂)`` per cell ``c`` (``d = cols[c]``; ``rows`` shape ``(C, D)``, ``cols`` shape
    ``(C,)``): ``d₂`` the first of the largest values of row ``c`` more than one hypothesis
    from ``d``, or ``d`` where that value is not finite (NaN anywhere there counts as not
    finite: ``np.argmax`` takes the first NaN). Shape ``(C, 2)``, int64."""
    n_cells, n_hyp = rows.shape
    pairs = np.empty((n_cells, 2), dtype=np.int64)
    for c in range(n_cells):
        d = cols[c]
        best = -1
        top = -math.inf
        bad = False
        for e in range(n_hyp):
            if abs(e - d) <= 1:
                continue
            v = rows[c, e]
            if v != v:
                bad = True
                break
            if best < 0 or v > top:
                best = e
                top = v
        pairs[c, 0] = d
        pairs[c, 1] = best if not bad and best >= 0 and math.isfinite(top) else d
    return pairs


@numba.njit(**_JIT)
def coarse_search(
    y: Any,
    b_first: int,
    block: int,
    within_re: Any,
    within_im: Any,
    step_re: Any,
    step_im: Any,
    cycles_per_block: Any,
    frame: int,
    q: Any,
    n_tones: int,
    comb_lags: Any,
    cell_w: Any,
    hyp_w: Any,
    noise_every: int,
    noise_scale: Any,
    cum: Any,
    cum_ring: Any,
    g_ring: Any,
    uacc_ring: Any,
    shortlist: int,
    peak_lobe: int,
    peak_count: int,
    frame_rot: Any,
    s_out: Any,
    d_out: Any,
    noise_out: Any,
    acc_out: Any,
) -> None:
    """Stage 1 of the two-stage search over whole blocks of ``block`` baseband samples.

    Input: ``y`` (complex128, shape ``(nb·block,)``), blocks ``b_first .. b_first + nb − 1``
    (absolute). Per block ``b`` and cell ``c = d·K + k`` (``D·K`` cells):

    - partial sum ``P = Σ_{r<block} y[bB + r] e^{−j2πν_c (bB + r)/fs}``: the within-block
      phasor ``within[r, c]`` times the block rotation ``frame_rot[c] · step[b mod F, c]``
      (``frame_rot`` recomputed from ``cycles_per_block[c] = ν_c B/fs`` at every frame of
      ``F = frame`` blocks; shape ``(2, D·K)``, re and im, carried state);
    - cumulative sum ``cum[c]`` (shape ``(2, D·K)``, state) and its history ``cum_ring``
      (shape ``(H, 2, D·K)``, row ``b mod H``, ``H > max Q`` a power of two); the coarse
      correlator
      ``v = cum[b] − cum[b − Q_d]`` (a window of ``Q_d`` blocks);
    - group ``G_d = Σ_k cell_w[c] |v|²``; the uniform comb ``Acc_d[b − Q_d] + G_d[b] −
      G_d[b − M Q_d]`` (O(1), history ``uacc_ring`` shape ``(D, Hu)``) picks the
      ``shortlist`` best hypotheses and up to ``peak_count`` of its peaks across hypotheses
      (the largest of those greater than the ``peak_lobe`` hypotheses on either side: the
      lobes of other echoes, below the shortlist of the strongest one's lobe), and for
      those only the comb with per-term rounded lags
      ``Acc_d[b] = Σ_m G_d[b − comb_lags[d, m]]`` (lags in blocks, shape ``(D, M)``; history
      ``g_ring`` shape ``(D, Hg)``, column ``b mod Hg``, ``Hg > max(M max Q, max lag)``; ring
      lengths are powers of two);
    - outputs ``s_out[i] = max hyp_w[d] Acc_d`` over the shortlist, ``d_out[i]`` its ``d``
      (shape ``(nb,)``), and every
      ``noise_every`` blocks (absolute) ``noise_out[i] = median_c(|v|² noise_scale[d]) / ln 2``
      (NaN otherwise);
    - ``acc_out[i, d] = hyp_w[d] Acc_d`` for the shortlisted hypotheses, −inf for the others
      (shape ``(nb, D)``: the candidates of several echoes, :func:`peak_cells`).
    """
    n_cells = cum.shape[1]
    n_hyp = n_cells // n_tones
    nb = y.shape[0] // block
    c_mask = cum_ring.shape[0] - 1
    g_mask = g_ring.shape[1] - 1
    n_terms = comb_lags.shape[1]
    p_re = np.empty(n_cells)
    p_im = np.empty(n_cells)
    pw = np.empty(n_cells)
    grp = np.empty(n_hyp)
    acc_row = np.empty(n_hyp)
    short_v = np.empty(shortlist)
    short_d = np.empty(shortlist, dtype=np.int64)
    u_all = np.empty(n_hyp)
    med_work = np.empty(2 * n_cells)
    peak_v = np.empty(max(peak_count, 1))
    peak_d = np.empty(max(peak_count, 1), dtype=np.int64)
    u_mask = uacc_ring.shape[1] - 1
    ln2 = math.log(2.0)
    for i in range(nb):
        b = b_first + i
        for c in range(n_cells):
            p_re[c] = 0.0
            p_im[c] = 0.0
        for r in range(block):
            yv = y[i * block + r]
            yr = yv.real
            yi = yv.imag
            w_re = within_re[r]
            w_im = within_im[r]
            # Two loops of one output each: the compiler vectorises these.
            for c in range(n_cells):
                p_re[c] += yr * w_re[c] - yi * w_im[c]
            for c in range(n_cells):
                p_im[c] += yr * w_im[c] + yi * w_re[c]
        f = b % frame
        if f == 0 or i == 0:
            start = float(b - f)
            for c in range(n_cells):
                ang = -2.0 * math.pi * ((start * cycles_per_block[c]) % 1.0)
                frame_rot[0, c] = math.cos(ang)
                frame_rot[1, c] = math.sin(ang)
        slot = b & c_mask
        for c in range(n_cells):
            rr = frame_rot[0, c] * step_re[f, c] - frame_rot[1, c] * step_im[f, c]
            ri = frame_rot[0, c] * step_im[f, c] + frame_rot[1, c] * step_re[f, c]
            cum[0, c] += p_re[c] * rr - p_im[c] * ri
            cum[1, c] += p_re[c] * ri + p_im[c] * rr
            cum_ring[slot, 0, c] = cum[0, c]
            cum_ring[slot, 1, c] = cum[1, c]
        for d in range(n_hyp):
            old = (b - q[d]) & c_mask
            acc = 0.0
            for k in range(n_tones):
                c = d * n_tones + k
                ur = cum[0, c] - cum_ring[old, 0, c]
                ui = cum[1, c] - cum_ring[old, 1, c]
                pv = ur * ur + ui * ui
                pw[c] = pv * noise_scale[d]
                acc += pv * cell_w[c]
            grp[d] = acc
        # Shortlist by the uniform comb Acc_d[b − Q_d] + G_d[b] − G_d[b − M Q_d] (O(1) per
        # hypothesis; its terms drift by up to (M − 1)·|Q_d − H_d| blocks), then the comb with
        # per-term rounded lags for the shortlisted hypotheses only.
        n_short = 0
        for d in range(n_hyp):
            hist = g_ring[d]
            hist[b & g_mask] = grp[d]
            u = uacc_ring[d, (b - q[d]) & u_mask] + grp[d] - hist[(b - n_terms * q[d]) & g_mask]
            uacc_ring[d, b & u_mask] = u
            u *= hyp_w[d]
            u_all[d] = u
            # Insert into the descending shortlist (ties keep the lower d first).
            if n_short < shortlist or u > short_v[n_short - 1]:
                pos = min(n_short, shortlist - 1)
                while pos > 0 and short_v[pos - 1] < u:
                    short_v[pos] = short_v[pos - 1]
                    short_d[pos] = short_d[pos - 1]
                    pos -= 1
                short_v[pos] = u
                short_d[pos] = d
                n_short = min(n_short + 1, shortlist)
        n_peak = 0
        for d in range(n_hyp):
            u = u_all[d]
            if not u > 0.0:
                continue
            top = True
            for e in range(max(0, d - peak_lobe), min(n_hyp, d + peak_lobe + 1)):
                if (e < d and u_all[e] >= u) or (e > d and u_all[e] > u):
                    top = False
                    break
            if top and (n_peak < peak_count or u > peak_v[n_peak - 1]):
                pos = min(n_peak, peak_count - 1)
                while pos > 0 and peak_v[pos - 1] < u:
                    peak_v[pos] = peak_v[pos - 1]
                    peak_d[pos] = peak_d[pos - 1]
                    pos -= 1
                peak_v[pos] = u
                peak_d[pos] = d
                n_peak = min(n_peak + 1, peak_count)
        for d in range(n_hyp):
            acc_row[d] = -math.inf
        for e in range(n_short + n_peak):
            d = short_d[e] if e < n_short else peak_d[e - n_short]
            if acc_row[d] > -math.inf:
                continue
            hist = g_ring[d]
            lag = comb_lags[d]
            a = 0.0
            for m in range(n_terms):
                a += hist[(b - lag[m]) & g_mask]
            acc_row[d] = a * hyp_w[d]
        best = -math.inf
        best_d = 0
        for d in range(n_hyp):
            if acc_row[d] > best:
                best = acc_row[d]
                best_d = d
            acc_out[i, d] = acc_row[d]
        s_out[i] = best
        d_out[i] = best_d
        noise_out[i] = median(pw, med_work) / ln2 if b % noise_every == 0 else np.nan


@numba.njit(**_JIT)
def _window_prefix(y: Any, origin: int, s0: int, span: int, d: int, table: Any, pre: Any) -> None:
    """Prefix sums ``pre[i, k, :] = Σ_{i' < i} y[s0 + i'] · table[d, i', k, :]`` (re, im in the
    last axis) for ``i <= span``; ``y`` sample ``n`` at position ``n − origin`` (zero outside)."""
    n_tones = table.shape[2]
    n_y = y.shape[0]
    for k in range(n_tones):
        pre[0, k, 0] = 0.0
        pre[0, k, 1] = 0.0
    if n_tones == 4:
        _window_prefix_4(y, origin, s0, span, d, table, pre)
        return
    for i in range(span):
        p = s0 + i - origin
        yr = 0.0
        yi = 0.0
        if 0 <= p < n_y:
            yv = y[p]
            yr = yv.real
            yi = yv.imag
        for k in range(n_tones):
            tr = table[d, i, k, 0]
            ti = table[d, i, k, 1]
            pre[i + 1, k, 0] = pre[i, k, 0] + (yr * tr - yi * ti)
            pre[i + 1, k, 1] = pre[i, k, 1] + (yr * ti + yi * tr)


@numba.njit(**_JIT)
def _window_prefix_4(
    y: Any, origin: int, s0: int, span: int, d: int, table: Any, pre: Any
) -> None:  # fmt: skip
    """:func:`_window_prefix` for four tones (the HFC-CW presets' K), rows ``1 … span``: the
    same sums, carried in eight scalars. Read back from ``pre`` at every sample, the sums
    put a store and a load on each step's dependency chain (1.4 times the time per window)."""
    n_y = y.shape[0]
    r0 = i0 = r1 = i1 = r2 = i2 = r3 = i3 = 0.0
    for i in range(span):
        p = s0 + i - origin
        yr = 0.0
        yi = 0.0
        if 0 <= p < n_y:
            yv = y[p]
            yr = yv.real
            yi = yv.imag
        t = table[d, i]
        r0 = r0 + (yr * t[0, 0] - yi * t[0, 1])
        i0 = i0 + (yr * t[0, 1] + yi * t[0, 0])
        r1 = r1 + (yr * t[1, 0] - yi * t[1, 1])
        i1 = i1 + (yr * t[1, 1] + yi * t[1, 0])
        r2 = r2 + (yr * t[2, 0] - yi * t[2, 1])
        i2 = i2 + (yr * t[2, 1] + yi * t[2, 0])
        r3 = r3 + (yr * t[3, 0] - yi * t[3, 1])
        i3 = i3 + (yr * t[3, 1] + yi * t[3, 0])
        row = pre[i + 1]
        row[0, 0] = r0
        row[0, 1] = i0
        row[1, 0] = r1
        row[1, 1] = i1
        row[2, 0] = r2
        row[2, 1] = i2
        row[3, 0] = r3
        row[3, 1] = i3


@numba.njit(**_JIT)
def exact_windows(
    y: Any,
    origin: int,
    first: Any,
    dd: Any,
    width: int,
    lengths: Any,
    nu_fs: Any,
    table: Any,
    out: Any,
) -> None:
    """Exact unit correlators over short runs of samples.

    ``u[n, d, k] = Σ_{i<N_d} y[n − i] e^{−j2π ν[d, k] (n − i)/fs}`` for ``n = first_r + t``,
    ``t < width``, ``d = dd_r`` (``first``, ``dd`` shape ``(R,)``; ``out`` shape
    ``(R, width, K, 2)``, re and im). ``y`` (complex128) holds baseband sample ``n`` at
    position ``n − origin`` (positions outside the array read as zero). ``lengths``: ``N_d``
    (shape ``(D,)``); ``nu_fs``: ``ν/fs`` (shape ``(D, K)``, cycles per sample); ``table``:
    the phasor ``e^{−j2π ν[d, k] i/fs}`` of offset ``i`` (shape ``(D, >= max N + width − 1,
    K, 2)``). Each run is a prefix sum over its span rotated by the phase of its first sample
    (float64 throughout).
    """
    pre = np.empty((table.shape[1] + 1, nu_fs.shape[1], 2))
    for row in range(first.shape[0]):
        _exact_run(y, origin, first[row], dd[row], width, lengths, nu_fs, table, pre, out[row])


@numba.njit(**_JIT)
def _exact_run(
    y: Any, origin: int, first: int, d: int, width: int, lengths: Any, nu_fs: Any, table: Any,
    pre: Any, out: Any,
) -> None:  # fmt: skip
    """One run of :func:`exact_windows`: ``u[first + t, d, k]`` for ``t < width`` into
    ``out`` (shape ``(width, K, 2)``), from one prefix sum over its span (``pre``: scratch of
    shape ``(>= N_d + width, K, 2)``) rotated by the phase of its first sample."""
    n_len = lengths[d]
    s0 = first - n_len + 1
    _window_prefix(y, origin, s0, n_len + width - 1, d, table, pre)
    for k in range(nu_fs.shape[1]):
        ang = -2.0 * math.pi * ((float(s0) * nu_fs[d, k]) % 1.0)
        br = math.cos(ang)
        bi = math.sin(ang)
        for t in range(width):
            ur = pre[n_len + t, k, 0] - pre[t, k, 0]
            ui = pre[n_len + t, k, 1] - pre[t, k, 1]
            out[t, k, 0] = ur * br - ui * bi
            out[t, k, 1] = ur * bi + ui * br


@numba.njit(**_JIT)
def exact_values(
    y: Any,
    origin: int,
    first: Any,
    dd: Any,
    lengths: Any,
    nu_fs: Any,
    table: Any,
    cache_u: Any,
    cache_n: Any,
    out: Any,
) -> None:
    """:func:`exact_windows` of width 1 (``u[first_r, dd_r, k]``, ``out`` shape
    ``(R, 1, K, 2)``), each value kept for the calls after.

    A window held whole by ``y`` (its ``N_d`` samples from ``first − N_d + 1`` to ``first``
    between ``origin`` and the newest) is kept in ``cache_u`` (shape ``(D, cap, K, 2)``,
    ``cap`` a power of two, slot ``first mod cap``), stamped with ``first`` in ``cache_n``
    (shape ``(D, cap)``), and read back while it is still held whole: its samples never
    change once arrived, so the value kept is the bits :func:`exact_windows` computes again
    (a caller whose history restarts clears ``cache_n``). A window not held whole is computed
    (its missing samples read as zero) and not kept. The time-codeword map asks for the M
    terms of every sample, ``u[n − ℓ_{d,m}, d]``: while ``d`` stays, each value comes back as
    the next term of the samples a hop later, so about one in M is computed (23 % of them in
    the built-in tank run, where ``d`` moves between hypotheses).
    """
    n_tones = nu_fs.shape[1]
    pre = np.empty((table.shape[1] + 1, n_tones, 2))
    mask = cache_n.shape[1] - 1
    stop = origin + y.shape[0]
    for row in range(first.shape[0]):
        d = dd[row]
        f = first[row]
        held = f - lengths[d] + 1 >= origin and f < stop
        slot = f & mask
        if held and cache_n[d, slot] == f:
            out[row, 0] = cache_u[d, slot]
            continue
        _exact_run(y, origin, f, d, 1, lengths, nu_fs, table, pre, out[row])
        if held:
            cache_u[d, slot] = out[row, 0]
            cache_n[d, slot] = f


@numba.njit(**_JIT)
def _anchored_powers(
    y: Any, origin: int, a: int, n_len: int, group: int, d: int, table: Any, pre: Any, out: Any
) -> None:
    """``|u[n, d, k]|²`` for the ``group`` samples ``n = a + N − 1 + r`` (``r < group``) whose
    windows start at ``a + r``: one prefix sum from ``a`` (``out`` shape ``(group, K)``).

    Every window start in ``[a, a + group)`` maps to the same anchor ``a``, so each value is a
    function of ``n`` and ``d`` alone whichever call computes it."""
    n_tones = table.shape[2]
    _window_prefix(y, origin, a, n_len + group - 1, d, table, pre)
    for r in range(group):
        for k in range(n_tones):
            ur = pre[r + n_len, k, 0] - pre[r, k, 0]
            ui = pre[r + n_len, k, 1] - pre[r, k, 1]
            out[r, k] = ur * ur + ui * ui


@numba.njit(**_JIT)
def _order_down(v: Any, order: Any) -> None:
    """Indices of ``v`` (shape ``(n,)``, no NaN) by decreasing value, equal values in index
    order, into ``order`` (shape ``(n,)``): ``np.argsort(-v, kind="stable")`` without its two
    arrays. Insertion sort: ``n`` is a fine window's width (tens)."""
    for t in range(v.shape[0]):
        x = v[t]
        j = t
        while j > 0 and v[order[j - 1]] < x:
            order[j] = order[j - 1]
            j -= 1
        order[j] = t


@numba.njit(**_JIT)
def codeword_sums(
    y: Any,
    origin: int,
    n_avail: int,
    centre: Any,
    dset: Any,
    half: int,
    lags: Any,
    lengths: Any,
    table: Any,
    term_tone: Any,
    cell_w: Any,
    anchor: int,
    cache_p: Any,
    cache_max: Any,
    cache_n: Any,
    hyp_w: Any,
    prune: bool,
    out: Any,
) -> None:
    """Exact noncoherent codeword sums around candidates (stage 2 of the two-stage search).

    ``out[c, i, t, j] = Σ_{m<M} w[d, k] |u[n − ℓ_{d,m}, d, k]|²`` with ``k = term_tone[m, j]``
    (the tone of term ``m`` of codeword ``j``), ``d = dset[c, i]``, ``n = centre[c, i] −
    half + t`` for ``t <= 2·half`` (``centre`` and ``dset`` shape ``(C, nd)``, ``out`` shape
    ``(C, nd, 2·half + 1, J)``); ``lags`` ``ℓ`` (shape ``(D, M)``), ``cell_w`` ``w``
    (shape ``(D, K)``). Terms are added in the order ``m = 0, 1, ..``.

    ``|u|²`` of sample ``n`` is computed from a prefix sum anchored at the multiple of
    ``anchor`` at or below its window start (so its bits depend on ``n`` and ``d`` only), for
    the whole anchor group at once, and kept, weighted by ``w``, in ``cache_p`` (shape
    ``(D, K, cap)``, ``cap`` a power of two, slot ``n mod cap``) with its maximum over ``k``
    in ``cache_max`` (shape ``(D, cap)``), stamped in ``cache_n`` (shape ``(D, cap)``) when
    sample ``n`` has arrived (``n < n_avail``); a run with a missing sample fills the groups
    of its samples not yet kept. Consecutive candidates share ``M − 1`` of their
    ``M`` terms (a few samples apart), so each computes about one new term per hypothesis.
    ``table`` holds the phasor ``e^{−j2π ν[d, k] i/fs}`` for ``i < max N + anchor − 1``
    (shape ``(D, ·, K, 2)``).

    With ``prune`` the sums of a sample ``t`` are formed only while its bound
    ``Σ_m max_k w|u|²`` (>= the sum of every codeword) could still hold this hypothesis's
    maximum or, weighted by ``hyp_w[d]`` (shape ``(D,)``), beat the weighted maximum of an
    earlier hypothesis of ``dset[c]``; the others are left at −inf. The weighted maximum over
    ``(i, t, j)``, every hypothesis's maximum that could be it, its sample and the neighbouring
    samples' rows are then exactly those of the unpruned sums.
    """
    n_cand, n_sets = dset.shape
    width = 2 * half + 1
    n_terms = term_tone.shape[0]
    n_tones = table.shape[2]
    mask = cache_p.shape[2] - 1
    pre = np.empty((table.shape[1] + 1, n_tones, 2))
    fresh = np.empty((anchor, n_tones))
    # Samples not yet arrived are computed for this call only, never cached.
    late_p = np.empty((n_terms, width, n_tones))
    late = np.zeros((n_terms, width), dtype=np.bool_)
    bound = np.empty(width)
    done = np.empty(width, dtype=np.bool_)
    order = np.empty(width, dtype=np.int64)
    vals = np.empty((n_terms, n_tones))
    for c in range(n_cand):
        best_c = -math.inf
        for i in range(n_sets):
            d = dset[c, i]
            n_len = lengths[d]
            stamps = cache_n[d]
            top = cache_max[d]
            bound[:] = 0.0
            late[:, :] = False
            for m in range(n_terms):
                s0 = centre[c, i] - half - lags[d, m]
                t = 0
                while t < width:
                    n = s0 + t
                    slot = n & mask
                    if stamps[slot] == n:
                        bound[t] += top[slot]
                        t += 1
                        continue
                    # Fill the anchor groups of the run's missing samples only: filling
                    # groups beyond the run ahead of the next candidates' runs (a few samples
                    # off this one's) computes more groups than it saves misses.
                    g = ((s0 - n_len + 1) // anchor) * anchor
                    g_end = s0 + width - 1 - n_len + 1
                    while g <= g_end:
                        first = g + n_len - 1
                        need = False
                        for r in range(anchor):
                            n_r = first + r
                            if stamps[n_r & mask] != n_r and (n_r < n_avail or s0 <= n_r):
                                need = True
                                break
                        if need:
                            _anchored_powers(y, origin, g, n_len, anchor, d, table, pre, fresh)
                            for r in range(anchor):
                                n_r = first + r
                                if n_r < n_avail:
                                    s_r = n_r & mask
                                    stamps[s_r] = n_r
                                    mx = -math.inf
                                    for k in range(n_tones):
                                        v = cell_w[d, k] * fresh[r, k]
                                        cache_p[d, k, s_r] = v
                                        mx = max(mx, v)
                                    top[s_r] = mx
                                elif s0 <= n_r < s0 + width:
                                    late[m, n_r - s0] = True
                                    for k in range(n_tones):
                                        late_p[m, n_r - s0, k] = cell_w[d, k] * fresh[r, k]
                        g += anchor
                    # Resume at n: now cached (or late) — the loop adds it to the bound.
                    if late[m, t]:
                        mx = -math.inf
                        for k in range(n_tones):
                            mx = max(mx, late_p[m, t, k])
                        bound[t] += mx
                        t += 1
            # Rows in decreasing order of their bound: with pruning, a row is summed only
            # while it could still hold this hypothesis's peak or beat an earlier hypothesis;
            # the others stay −inf (callers take maxima).
            out[c, i] = -math.inf
            done[:] = False
            best_i = -math.inf
            i_pk = -1
            _order_down(bound, order)
            for rank in range(width):
                t = int(order[rank])
                if prune and (bound[t] * hyp_w[d] < best_c or bound[t] < best_i):
                    break
                v = _codeword_row(c, i, t, half, d, centre, lags, term_tone, cache_p, mask,
                                  late, late_p, vals, out[c, i, t])  # fmt: skip
                done[t] = True
                if v > best_i or (v == best_i and t < i_pk):
                    best_i = v
                    i_pk = t
            # The readout interpolates the peak with its neighbours.
            for t in (i_pk - 1, i_pk + 1):
                if i_pk >= 0 and 0 <= t < width and not done[t]:
                    _codeword_row(c, i, t, half, d, centre, lags, term_tone, cache_p, mask,
                                  late, late_p, vals, out[c, i, t])  # fmt: skip
            best_c = max(best_c, best_i * hyp_w[d])


@numba.njit(**_JIT)
def _codeword_row(
    c: int, i: int, t: int, half: int, d: int, centre: Any, lags: Any, term_tone: Any,
    cache_p: Any, mask: int, late: Any, late_p: Any, vals: Any, row: Any,
) -> float:  # fmt: skip
    """``row[j] = Σ_m w|u|²`` of term ``m``'s tone ``term_tone[m, j]`` at sample ``t`` of the
    window (added in the order ``m = 0, 1, ..``); returns ``max_j row[j]``. ``vals`` (shape
    ``(M, K)``) receives each term's weighted powers first; the sums then run four codewords
    at a time in registers (the same additions in the same order: the same bits)."""
    n_terms, n_words = term_tone.shape
    n_tones = vals.shape[1]
    for m in range(n_terms):
        if late[m, t]:
            for k in range(n_tones):
                vals[m, k] = late_p[m, t, k]
        else:
            slot = (centre[c, i] - half - lags[d, m] + t) & mask
            for k in range(n_tones):
                vals[m, k] = cache_p[d, k, slot]
    j = 0
    while j + 4 <= n_words:
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        for m in range(n_terms):
            s0 += vals[m, term_tone[m, j]]
            s1 += vals[m, term_tone[m, j + 1]]
            s2 += vals[m, term_tone[m, j + 2]]
            s3 += vals[m, term_tone[m, j + 3]]
        row[j] = s0
        row[j + 1] = s1
        row[j + 2] = s2
        row[j + 3] = s3
        j += 4
    while j < n_words:
        s0 = 0.0
        for m in range(n_terms):
            s0 += vals[m, term_tone[m, j]]
        row[j] = s0
        j += 1
    top = -math.inf
    for j in range(n_words):
        top = max(top, row[j])
    return top


@numba.njit(**_JIT)
def parabolic_offset_scalar(y_minus: float, y0: float, y_plus: float) -> float:
    """:func:`hil.estimation.detection.parabolic_offset`, compiled (the same value, bit for
    bit): the vertex of the parabola through three equally spaced points, in samples from
    the middle one, within ±1; 0 unless the middle is a strict peak with a finite curvature."""
    den = y_minus - 2.0 * y0 + y_plus
    if not den < 0.0 or not math.isfinite(den):
        return 0.0
    return min(max(0.5 * (y_minus - y_plus) / den, -1.0), 1.0) + 0.0


@numba.njit(**_JIT)
def _row_peak(a: Any, s: Any) -> int:
    """``s[t] = max_j a[t, j]`` (``a`` shape ``(T, J)``); the first ``t`` of the largest."""
    ip = 0
    for t in range(a.shape[0]):
        top = -math.inf
        for j in range(a.shape[1]):
            top = max(top, a[t, j])
        s[t] = top
        if t > 0 and top > s[ip]:
            ip = t
    return ip


@numba.njit(**_JIT)
def _edges(
    rows: Any, a: Any, s_win: Any, i_pk: Any, centre: Any, half: int, last_edge: bool, out: Any
) -> int:
    """Peaks of candidates ``rows``: ``s_win``, ``i_pk``; the ones on the window's first
    sample (or, with ``last_edge``, its last) move their ``centre`` onto it and go to
    ``out``; returns how many did."""
    n_edge = 0
    for c in rows:
        ip = _row_peak(a[c], s_win[c])
        i_pk[c] = ip
        if ip == 0 or (last_edge and ip == 2 * half):
            centre[c] += ip - half
            out[n_edge] = c
            n_edge += 1
    return n_edge


@numba.njit(**_JIT)
def fine_pick(a2: Any, pair: Any, centres: Any, hyp_w: Any, half: int, find_edges: bool) -> Any:
    """The best hypothesis of each candidate's set, and its peak.

    ``a2``: exact codeword sums of the hypotheses ``pair`` (shape ``(C, H)``) within
    ``±half`` of ``centres`` (:func:`codeword_sums` with pruning, shape
    ``(C, H, 2·half + 1, J)``). The hypothesis is the best by its maximum weighted with
    ``hyp_w`` (one pruned whole, −inf, cannot win). Returns ``d0``, ``centre``
    (``(C,)``), its sums ``a`` (``(C, 2·half + 1, J)``), their maximum over codewords
    ``s_win``, its first maximum ``i_pk`` and, with ``find_edges``, the candidates whose
    peak lies on either edge of the window, their ``centre`` moved onto it (to be summed
    again there; see :func:`fine_recentre`). Every value equals the NumPy formulation's."""
    n_cand, _, width, n_words = a2.shape
    d0 = np.empty(n_cand, dtype=np.int64)
    centre = np.empty(n_cand, dtype=np.int64)
    a = np.empty((n_cand, width, n_words))
    for c in range(n_cand):
        pick = 0
        best = -math.inf
        for i in range(a2.shape[1]):
            top = -math.inf
            for t in range(width):
                for j in range(n_words):
                    top = max(top, a2[c, i, t, j])
            score = top * hyp_w[pair[c, i]] if math.isfinite(top) else -math.inf
            if i == 0 or score > best:
                best = score
                pick = i
        d0[c] = pair[c, pick]
        centre[c] = centres[c, pick]
        a[c] = a2[c, pick]
    s_win = np.empty((n_cand, width))
    i_pk = np.empty(n_cand, dtype=np.int64)
    edges = np.empty(n_cand, dtype=np.int64)
    if find_edges:
        n_edge = _edges(np.arange(n_cand), a, s_win, i_pk, centre, half, True, edges)
    else:
        n_edge = 0
        for c in range(n_cand):
            i_pk[c] = _row_peak(a[c], s_win[c])
    return d0, centre, a, s_win, i_pk, edges[:n_edge]


@numba.njit(**_JIT)
def fine_recentre(
    a: Any, sums: Any, edges: Any, s_win: Any, i_pk: Any, centre: Any, half: int,
    find_edges: bool,
) -> Any:  # fmt: skip
    """Put the sums of the recentred candidates ``edges`` (``sums`` shape
    ``(E, 1, 2·half + 1, J)``, at their new ``centre``) into ``a`` and update their peaks;
    with ``find_edges``, return the ones whose peak is again on the window's first sample,
    their ``centre`` moved onto it (the last edge is followed only once)."""
    for e in range(edges.shape[0]):
        a[edges[e]] = sums[e, 0]
    out = np.empty(edges.shape[0], dtype=np.int64)
    if not find_edges:
        for c in edges:
            i_pk[c] = _row_peak(a[c], s_win[c])
        return out[:0]
    n_edge = _edges(edges, a, s_win, i_pk, centre, half, False, out)
    return out[:n_edge]


@numba.njit(**_JIT)
def fine_keep(
    hit: Any, a: Any, s_win: Any, i_pk: Any, d0: Any, n_hyp: int, half: int,
    runner_up_ratio: float, pair_rows: Any,
) -> Any:  # fmt: skip
    """Readout of the candidates ``hit`` (indices into :func:`fine_pick`'s outputs) that
    passed the threshold: kept when the peak codeword beats the runner-up codeword by at
    least ``runner_up_ratio`` (any ratio when the runner-up is 0), or, at a hypothesis
    ``pair_rows`` marks (shape ``(n_hyp,)``, bool), beats the third codeword by it (two
    echoes of one speed at once: their codewords tie; the ratio is then to the third).

    Returns, for the kept ones in ``hit`` order: their position in ``hit``, peak value,
    codeword, ratio, time offset (parabolic, 0 on the window's edge), and the neighbouring
    hypotheses ``d0 ± 1`` clipped to ``0 .. n_hyp − 1`` (shape ``(K, 2)``) at which the
    Doppler offset is read (:func:`fine_doppler`). Equal to the NumPy formulation."""
    n_hit = hit.shape[0]
    n_words = a.shape[2]
    last = 2 * half
    keep = np.empty(n_hit, dtype=np.int64)
    peak = np.empty(n_hit)
    word = np.empty(n_hit, dtype=np.int64)
    ratio = np.empty(n_hit)
    dn = np.empty(n_hit)
    sides = np.empty((n_hit, 2), dtype=np.int64)
    n_keep = 0
    for h in range(n_hit):
        c = hit[h]
        ip = i_pk[c]
        p = s_win[c, ip]
        jh = 0
        first = -math.inf
        second = -math.inf
        third = -math.inf
        for j in range(n_words):
            v = a[c, ip, j]
            if v > a[c, ip, jh]:
                jh = j
            if v > first:
                third = second
                second = first
                first = v
            elif v > second:
                third = second
                second = v
            elif v > third:
                third = v
        runner = second if n_words > 1 else 0.0
        r = p / runner if runner > 0 else math.inf
        if not r >= runner_up_ratio:
            if not pair_rows[d0[c]] or n_words < 3:
                continue
            r = p / third if third > 0 else math.inf
            if not r >= runner_up_ratio:
                continue
        keep[n_keep] = h
        peak[n_keep] = p
        word[n_keep] = jh
        ratio[n_keep] = r
        if 0 < ip < last:
            dn[n_keep] = parabolic_offset_scalar(s_win[c, ip - 1], p, s_win[c, ip + 1])
        else:
            dn[n_keep] = 0.0
        sides[n_keep, 0] = min(max(d0[c] - 1, 0), n_hyp - 1)
        sides[n_keep, 1] = min(max(d0[c] + 1, 0), n_hyp - 1)
        n_keep += 1
    return (
        keep[:n_keep], peak[:n_keep], word[:n_keep], ratio[:n_keep], dn[:n_keep],
        sides[:n_keep],
    )  # fmt: skip


@numba.njit(**_JIT)
def fine_doppler(side: Any, a: Any, cand: Any, i_pk: Any, word: Any, d0: Any, sides: Any) -> Any:
    """Doppler offsets of the kept candidates ``cand`` (indices into :func:`fine_pick`'s
    outputs): parabolic through the sums of codeword ``word`` at the peak at hypotheses
    ``sides[:, 0]``, ``d0``, ``sides[:, 1]`` (``side`` from :func:`codeword_sums` at the
    peak sample, shape ``(K, 2, 1, J)``); 0 where a neighbour was clipped onto ``d0``."""
    out = np.zeros(cand.shape[0])
    for k in range(cand.shape[0]):
        c = cand[k]
        if sides[k, 0] != d0[c] and sides[k, 1] != d0[c]:
            j = word[k]
            out[k] = parabolic_offset_scalar(side[k, 0, 0, j], a[c, i_pk[c], j], side[k, 1, 0, j])
    return out


@numba.njit(**_JIT)
def second_codeword_rows(
    windows: Any, still: Any, pair: Any, word: Any, level: Any, above: Any, thr: Any,
    share: Any, runner_up_ratio: float, second_level: float,
) -> Any:  # fmt: skip
    """The second codewords of stage 2's kept peaks
    (:mod:`hil.estimation.gcas.still_codewords`), all at once.

    ``windows``: each peak's exact sums at its hypothesis (shape ``(P, 2w + 1, J)``, finite
    or −inf where pruned); per peak (shape ``(P,)``): ``still`` (a still hypothesis),
    ``pair`` (a moving hypothesis where a second echo of one speed is looked for), its
    codeword ``word``, ``level`` (its sum), ``above`` (``level`` less the noise mean) and its
    threshold ``thr``; ``share``: the codewords' shared terms over ``M`` (shape ``(J, J)``).
    A ``pair`` peak is read only where another codeword reaches ``second_level`` of
    ``level`` and its threshold less its leak ``above·share``; then every read peak as
    :func:`~hil.estimation.gcas.still_codewords.second_codeword` (leak ``above·share[word]``)
    and, at a ``pair`` peak, only a second codeword of ``second_level`` of ``level``.

    Returns, for the peaks that have one, in peak order: their index, the window sample,
    codeword, value, ratio and parabolic offset (the same values as ``second_codeword``, bit
    for bit: the same operations on the same numbers)."""
    n_peaks, width, n_words = windows.shape
    idx = np.empty(n_peaks, dtype=np.int64)
    sample = np.empty(n_peaks, dtype=np.int64)
    code = np.empty(n_peaks, dtype=np.int64)
    value = np.empty(n_peaks)
    ratio = np.empty(n_peaks)
    dn = np.empty(n_peaks)
    top = np.empty(n_words)
    n_found = 0
    if n_words < 2 or width < 3:
        return idx[:0], sample[:0], code[:0], value[:0], ratio[:0], dn[:0]
    for p in range(n_peaks):
        if not (still[p] or pair[p]):
            continue
        w = word[p]
        for j in range(n_words):
            mx = -math.inf
            for t in range(width):
                mx = max(mx, windows[p, t, j])
            top[j] = mx
        if pair[p]:
            clear = False
            for j in range(n_words):
                beyond = top[j] - above[p] * share[w, j] >= thr[p]
                if j != w and beyond and top[j] >= second_level * level[p]:
                    clear = True
            if not clear:
                continue
        # The largest other codeword, less its leak (the first of equals).
        jb = -1
        best = -math.inf
        for j in range(n_words):
            b = -math.inf if j == w else top[j] - above[p] * share[w, j]
            if jb < 0 or b > best:
                jb = j
                best = b
        ib = 0
        for t in range(1, width):
            if windows[p, t, jb] > windows[p, ib, jb]:
                ib = t
        v = windows[p, ib, jb]
        if not (0 < ib < width - 1) or not v >= thr[p] + above[p] * share[w, jb]:
            continue
        third = -math.inf
        for j in range(n_words):
            if j != w and j != jb:
                third = max(third, windows[p, ib, j])
        r = v / third if third > 0 else math.inf
        if not r >= runner_up_ratio:
            continue
        if pair[p] and v < second_level * level[p]:
            continue  # one echo's own codewords, not a second echo of its level
        idx[n_found] = p
        sample[n_found] = ib
        code[n_found] = jb
        value[n_found] = v
        ratio[n_found] = r
        dn[n_found] = parabolic_offset_scalar(windows[p, ib - 1, jb], v, windows[p, ib + 1, jb])
        n_found += 1
    return (
        idx[:n_found], sample[:n_found], code[:n_found], value[:n_found], ratio[:n_found],
        dn[:n_found],
    )  # fmt: skip
