"""The first-arrival readout's compiled loops give NumPy's bits
(:mod:`hil.estimation.first_arrival_kernels`).

Each kernel is checked against the NumPy expressions it stands for, element by element on the
bytes: random inputs over the ranges the readout sees, the edge cases (zeros, a steady
boundary, a level fitted beside the ramp), sizes on either side of the pairwise sum's blocks.
"""

from __future__ import annotations

import numpy as np
import pytest

from hil.estimation import first_arrival as fa
from hil.estimation import first_arrival_kernels as k

try:
    from numpy._core._multiarray_umath import __cpu_features__ as _CPU
except ImportError:  # NumPy's private feature table moved: assume no FMA
    _CPU = {}
#: NumPy's complex product and absolute fuse a multiply-add where the CPU has FMA (x86-64
#: FMA3, AArch64 ASIMD): the kernels' operations. Without it NumPy's round twice.
needs_fma = pytest.mark.skipif(
    not (_CPU.get("FMA3") or _CPU.get("ASIMD")), reason="NumPy's loops here have no FMA"
)


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 15, 16, 17, 127, 128, 129, 130, 257, 1133, 5000])
def test_pairwise_sum_is_numpys_add_reduce(n: int) -> None:
    rng = np.random.default_rng(n)
    a = rng.normal(size=n + 3) * 10.0 ** rng.uniform(-6, 6, n + 3)
    assert k.pairwise_sum(a, 0, n) == np.add.reduce(a[:n])
    assert k.pairwise_sum(a, 3, n) == np.add.reduce(a[3:])
    assert k.pairwise_sum(a, 0, n) == np.sum(a[:n])
    if n == 5000:  # the order matters at this size: an in-order sum has other bits
        assert k.pairwise_sum(a, 0, n) != float(np.cumsum(a[:n])[-1])


@needs_fma
def test_complex_abs_is_numpys_absolute() -> None:
    rng = np.random.default_rng(1)
    z = (rng.normal(size=4000) + 1j * rng.normal(size=4000)) * 10.0 ** rng.uniform(-8, 8, 4000)
    z[:5] = [0.0, -0.0, 3.0, 4.0j, -2.5]
    z[5:8] = [complex(np.inf, 1.0), complex(1.0, -np.inf), complex(np.nan, 2.0)]
    want = np.abs(z)
    got = np.array([k.complex_abs(v.real, v.imag) for v in z])
    assert got[:7].tobytes() == want[:7].tobytes()
    assert np.isnan(got[7]) and np.isnan(want[7])
    assert got[8:].tobytes() == want[8:].tobytes()


def _channel_numpy(
    d: np.ndarray, idx: np.ndarray, fs: float, alpha: float, f_next: np.ndarray, w: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The readout's next-tone channel as NumPy expressions."""
    t = idx / fs
    z = np.multiply(-2j * np.pi * alpha * f_next[:, None], t)
    np.exp(z, out=z)
    np.multiply(d, z, out=z)
    c = np.cumsum(z, axis=1, out=z)
    full = c[:, w:] - c[:, :-w]
    box = full[:, w:] - full[:, :-w]
    p_all = np.abs(box * (1.0 / w))
    np.square(p_all, out=p_all)
    return full, box, p_all


@needs_fma
@pytest.mark.parametrize("seed", range(6))
def test_next_tone_channel_is_the_numpy_expressions(seed: int) -> None:
    rng = np.random.default_rng(seed)
    fs, w, m, n = 192_000.0, 96, 10, 1133
    alpha = 1.0 + rng.normal(0.0, 2e-3)
    f_next = rng.choice(np.arange(20_000.0, 60_000.0, 2000.0), m)[::-1]  # reversed: a view
    idx = rng.integers(0, 192_000 * 60, m)[:, None] + np.arange(n)[None, :]
    d = rng.normal(size=(m, n)) * 10.0 ** rng.uniform(-6, 1)
    d[:, :40] = 0.0  # a silent start: the sums' zeros
    full, box, p_all = (
        np.empty((m, n - w), complex), np.empty((m, n - 2 * w), complex), np.empty((m, n - 2 * w))
    )  # fmt: skip
    b = np.ascontiguousarray((-2j * np.pi * alpha * f_next).imag)
    k.next_tone_channel(d, idx, fs, b, w, 1.0 / w, full, box, p_all)
    want = _channel_numpy(d, idx, fs, alpha, f_next, w)
    for got, exp in zip((full, box, p_all), want, strict=True):
        assert got.tobytes() == exp.tobytes()


@pytest.mark.parametrize(("period", "sign"), [(0, 1), (1920, 1), (1920, -1), (7, 1)])
def test_ring_channel_is_the_channel_of_the_rows_it_reads(period: int, sign: int) -> None:
    """The readout's rows read from its history (less or plus the period before behind the
    canceller) and passed to next_tone_channel, against the kernel reading them itself."""
    rng = np.random.default_rng(period + sign)
    fs, w, m, n = 192_000.0, 96, 10, 1325
    ring = rng.normal(size=40_000) * 10.0 ** rng.uniform(-6, 1)
    ring[5000:5100] = 0.0  # zeros: the history before the stream started
    pos = rng.integers(period, ring.size - n, m)
    pos[0] = 5000 - 20
    first = pos + 3_000_000  # absolute indices: the history's positions shifted
    b = np.ascontiguousarray((-2j * np.pi * 1.001 * rng.uniform(2e4, 6e4, m)).imag)
    idx = first[:, None] + np.arange(n)[None, :]
    rows = ring[pos[:, None] + np.arange(n)[None, :]]
    if period:
        before = ring[pos[:, None] - period + np.arange(n)[None, :]]
        rows = rows - before if sign > 0 else rows + before
    outs = []
    for _ in range(2):
        outs.append(
            (np.empty((m, n - w), complex), np.empty((m, n - 2 * w), complex),
             np.empty((m, n - 2 * w)))
        )  # fmt: skip
    k.next_tone_channel(rows, idx, fs, b, w, 1.0 / w, *outs[0])
    k.ring_channel(ring, pos, period, sign, first, fs, b, w, 1.0 / w, *outs[1])
    for want, got in zip(*outs, strict=True):
        assert got.tobytes() == want.tobytes()


def _residuals_numpy(
    o: np.ndarray, n: np.ndarray, w: int, geometric: np.ndarray, start: np.ndarray,
    theta: np.ndarray, jump: np.ndarray, excess: np.ndarray, level: bool,
) -> np.ndarray:  # fmt: skip
    """The ramp model's residuals as the readout's NumPy expressions (its shape's window
    sums times 1/w, their power's mean over the boundaries, scale and residual)."""
    m = theta.size
    o3 = o[:, :, None]
    n_next = n[None, None, :] + (1 - np.ceil(o3).astype(np.int64))
    np.maximum(n_next, 0, out=n_next)
    np.minimum(n_next, w, out=n_next)
    row_ends = (np.arange(m, dtype=np.int64) * (w + 1) + w)[None, :, None]
    sums = geometric.take(row_ends - n_next)
    at_o = np.exp(-1j * (theta[None, :, None] * o3 + jump[None, :, None]))
    shape = np.multiply(start[None, :, :], at_o)
    shape *= sums
    shape += n_next
    shape *= 1.0 / w
    power = np.abs(shape)
    np.square(power, out=power)
    model = np.add.reduce(power, axis=1) / m
    if level:
        model -= (np.add.reduce(model, axis=1) / model.shape[1])[:, None]
        excess = excess - float(np.add.reduce(excess, axis=None) / excess.size)
    mm = np.add.reduce(model * model, axis=1)
    scale = np.add.reduce(model * excess[None, :], axis=1) / np.maximum(mm, 1e-300)
    left = excess[None, :] - scale[:, None] * model
    np.square(left, out=left)
    return np.asarray(np.add.reduce(left, axis=1), dtype=np.float64)


@needs_fma
@pytest.mark.parametrize(("seed", "length", "level"), [(0, 12, False), (1, 60, False),
    (2, 60, True), (3, 7, True), (4, 150, False), (5, 33, True)])  # fmt: skip
def test_ramp_residuals_are_the_numpy_expressions(seed: int, length: int, level: bool) -> None:
    rng = np.random.default_rng(seed)
    w, m, pre = 96, 8, 749
    theta = 2.0 * np.pi * rng.choice([-4000.0, 2000.0, 6000.0], m) / 192_000.0
    theta[3] = 0.0  # a steady boundary: its table is the sample count
    jump = rng.normal(0.0, 1.0, m)
    ratio = np.exp(1j * theta)
    steady = np.abs(1.0 - ratio) < 1e-12
    powers = ratio[:, None] ** np.arange(w + 1)[None, :]
    denom = np.where(steady, 1.0, 1.0 - ratio)[:, None]
    geometric = np.asarray(
        np.where(steady[:, None], np.arange(w + 1)[None, :], (1.0 - powers) / denom), complex
    )
    n = pre - 30 + np.arange(length)
    start = np.exp(1j * np.outer(theta, n - w + 1))
    got_start = np.empty_like(start)
    k.window_start_phasors(theta, n, w, got_start)
    assert got_start.tobytes() == start.tobytes()
    grid = rng.uniform(-20.0, 20.0, 33)
    grid[:3] = [0.0, -0.0, 5.0]  # whole samples: the coarse grid
    frac = rng.uniform(-0.5, 0.5, m)
    o = (pre + grid)[:, None] + frac[None, :]
    excess = rng.normal(1.0, 1.0, length) ** 2
    got = np.empty(grid.size)
    k.ramp_residuals(
        grid, pre, frac, theta, jump, n, w, geometric, start, 1.0 / w, excess, level, got
    )
    want = _residuals_numpy(o, n, w, geometric, start, theta, jump, excess, level)
    assert got.tobytes() == want.tobytes()


def test_sums_of_negative_zeros_are_numpys() -> None:
    """NumPy's sums start from +0.0: ``−0.0`` terms sum to ``+0.0``, in a leaf and above."""
    for n in (3, 9, 300):
        a = np.full(n, -0.0)
        assert k.pairwise_sum(a, 0, n).hex() == float(np.add.reduce(a)).hex() == "0x0.0p+0"


@needs_fma
@pytest.mark.parametrize("seed", range(8))
def test_doppler_score_is_the_numpy_expressions(seed: int) -> None:
    """The compiled Doppler score against the readout's NumPy expressions, over tone
    patterns of 10 boundaries (a tone on 1 to 10 of them)."""
    rng = np.random.default_rng(seed)
    m = 10
    tones = rng.integers(0, 1 + seed % 6, m) if seed < 7 else np.zeros(m, dtype=np.int64)
    distinct, group = np.unique(tones, return_inverse=True)
    columns = tuple(np.flatnonzero(group == j) for j in range(distinct.size))
    order = np.concatenate(columns).astype(np.int64)
    starts = np.cumsum([0] + [c.size for c in columns]).astype(np.int64)
    d_alpha = (np.arange(-140, 170) * 0.002 + rng.normal(0.0, 1.0)) / 1482.0
    f = 24_000.0 + 2000.0 * tones
    t_m = (np.arange(m)[::-1] * 1920 + rng.integers(-3, 3, m)) / 192_000.0
    q = (rng.normal(size=m) + 1j * rng.normal(size=m)) * 10.0 ** rng.uniform(-4, 2)
    want = fa._doppler_score_numpy(d_alpha, f * t_m, q, columns)
    got = np.empty(d_alpha.size)
    b = np.ascontiguousarray((-2j * np.pi * d_alpha).imag)
    k.doppler_score(b, np.ascontiguousarray(f * t_m), q, order, starts, got)
    assert got.tobytes() == want.tobytes()


@needs_fma
@pytest.mark.parametrize(("seed", "lead", "n"), [(1, 1, 3), (2, 40, 61), (3, 200, 201), (4, 5, 4)])
def test_late_tap_table_is_the_numpy_where(seed: int, lead: int, n: int) -> None:
    """The late taps' table (``hil.estimation.late_taps``) as NumPy builds it: each tap the
    previous tone times its phase at the switch before sample ``g + 1``, the current tone
    from it on (a tap switching past the stretch's end, ``lead >= n``, too)."""
    rng = np.random.default_rng(seed)
    m = 3
    ii = np.arange(n, dtype=np.float64)[None, None, :]
    w_cur, w_prev = rng.uniform(-1.0, 1.0, (2, m))[:, :, None, None]
    grid = np.arange(1, lead + 1, dtype=np.float64)[None, :, None]
    at_switch = np.exp(1j * ((w_cur - w_prev) * grid - rng.uniform(-np.pi, np.pi, (m, 1, 1))))
    want = np.where(ii >= grid, np.exp(1j * w_cur * ii), np.exp(1j * w_prev * ii) * at_switch)
    got = np.empty((m, lead, n), dtype=np.complex128)
    k.late_tap_table(
        np.exp(1j * w_cur * ii)[:, 0, :], np.exp(1j * w_prev * ii)[:, 0, :],
        np.ascontiguousarray(at_switch[:, :, 0]), got,
    )  # fmt: skip
    assert got.tobytes() == want.tobytes()
