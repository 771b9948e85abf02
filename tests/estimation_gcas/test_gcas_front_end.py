"""Baseband front end and unit correlator bank: values, chunking, long-stream stability."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.estimation.baseband import ComplexBaseband, kaiser_lowpass, kaiser_order
from hil.estimation.bessel_i0 import bessel_i0
from hil.estimation.kernels import fir_decimate
from hil.estimation.unit_correlators import UnitCorrelatorBank


def _chunks(x: np.ndarray, cuts: list[int]) -> list[np.ndarray]:
    edges = sorted({0, x.shape[0], *(c % (x.shape[0] + 1) for c in cuts)})
    return [x[a:b] for a, b in itertools.pairwise(edges)]


def test_baseband_tone_has_the_envelope_and_time_of_the_input() -> None:
    fs, fc, f = 100_000.0, 30_000.0, 31_234.5
    bb = ComplexBaseband(fs, fc, decimation=12, passband_hz=3200.0)
    n = np.arange(30_000)
    y = bb.process(np.cos(2 * np.pi * f * n / fs + 0.3))
    k = np.arange(500, y.shape[0])
    t = bb.time_of(k)
    expected = 0.5 * np.exp(1j * (2 * np.pi * (f - fc) * t + 0.3))
    assert np.max(np.abs(y[k] - expected)) < 2e-3  # passband ripple and stop band < -54 dB


@settings(max_examples=40, deadline=None)
@given(
    attenuation=st.floats(8.0, 120.0),
    width=st.floats(0.005, 0.5),
    cutoff=st.floats(0.02, 0.98),
)
def test_the_kaiser_design_is_scipy_signals_bit_for_bit(
    attenuation: float, width: float, cutoff: float
) -> None:
    # The receiver designs its lowpass without importing scipy.signal (a second of start-up):
    # the same numbers as kaiserord and firwin, to the last bit.
    from scipy import signal

    numtaps, beta = kaiser_order(attenuation, width)
    assert (numtaps, beta) == signal.kaiserord(attenuation, width)
    numtaps |= 1
    taps = kaiser_lowpass(numtaps, cutoff, beta)
    assert np.array_equal(taps, signal.firwin(numtaps, cutoff, window=("kaiser", beta)))


@settings(max_examples=100, deadline=None)
@given(x=st.lists(st.floats(-760.0, 760.0), min_size=1, max_size=20))
def test_the_kaisers_bessel_i0_is_scipy_specials_bit_for_bit(x: list[float]) -> None:
    # The window's I0 without importing scipy.special: the same bits, so the taps and every
    # result downstream of the front end are unchanged.
    from scipy import special

    edges = [0.0, 8.0, math.nextafter(8.0, 9.0), 709.0, 713.0, float("nan")]
    values = np.array([*x, *edges])
    assert np.array_equal(bessel_i0(values), special.i0(values), equal_nan=True)


def test_a_kaiser_design_below_8_db_is_refused_naming_the_attenuation() -> None:
    with pytest.raises(ConfigError, match=r"attenuation_db = 5\.0.*at least 8 dB"):
        kaiser_order(5.0, 0.1)


def test_baseband_rejects_aliases() -> None:
    fs = 100_000.0
    bb = ComplexBaseband(fs, 30_000.0, decimation=12, passband_hz=3200.0)
    n = np.arange(30_000)
    # 30 kHz + 8.3 kHz would alias onto DC at fs/12 without the low-pass.
    y = bb.process(np.cos(2 * np.pi * (30_000.0 + fs / 12) * n / fs))
    assert np.max(np.abs(y[200:])) < 10 ** (-60 / 20)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, 5000), max_size=6))
def test_baseband_chunks_equal_whole(cuts: list[int]) -> None:
    x = np.random.default_rng(3).normal(size=5000)
    whole = ComplexBaseband(100_000.0, 30_000.0, decimation=7, passband_hz=3000.0).process(x)
    bb = ComplexBaseband(100_000.0, 30_000.0, decimation=7, passband_hz=3000.0)
    parts = np.concatenate([bb.process(c) for c in _chunks(x, cuts)])
    assert np.array_equal(parts, whole)


def test_baseband_of_a_long_block_equals_its_chunks() -> None:
    # 20 000 outputs in one call: NumPy reuses a temporary over 256 KiB in place, and its
    # in-place complex multiply rounds differently from its other loops; no output's bits
    # may depend on that.
    x = np.random.default_rng(4).normal(size=240_000)
    whole = ComplexBaseband(100_000.0, 30_000.0, decimation=12, passband_hz=3141.0).process(x)
    assert whole.shape == (20_000,)
    for block in (997, 10_000, 150_001):
        bb = ComplexBaseband(100_000.0, 30_000.0, decimation=12, passband_hz=3141.0)
        parts = np.concatenate([bb.process(x[i : i + block]) for i in range(0, x.size, block)])
        assert np.array_equal(parts, whole), block


def _direct_bank(x: np.ndarray, nu: np.ndarray, lengths: np.ndarray, fs: float) -> np.ndarray:
    n = np.arange(x.shape[0])
    out = np.zeros((x.shape[0], *nu.shape), dtype=np.complex128)
    for d in range(nu.shape[0]):
        for k in range(nu.shape[1]):
            y = x * np.exp(-2j * np.pi * nu[d, k] * n / fs)
            c = np.concatenate(([0.0], np.cumsum(y)))
            lo = np.maximum(n + 1 - lengths[d], 0)
            out[:, d, k] = c[n + 1] - c[lo]
    return out


def test_unit_correlators_match_the_direct_sum() -> None:
    rng = np.random.default_rng(5)
    x = rng.normal(size=3000) + 1j * rng.normal(size=3000)
    nu = np.array([[-1000.0, 150.0, 2000.0], [-990.0, 160.0, 2010.0]])
    lengths = np.array([37, 40])
    bank = UnitCorrelatorBank(8000.0, nu, lengths, cell=256, anchor=512)
    u = bank.process(x)
    ref = _direct_bank(x, nu, lengths, 8000.0)
    assert np.max(np.abs(u - ref)) < 2e-4 * np.max(np.abs(ref))


def test_unit_correlators_do_not_drift_on_long_streams() -> None:
    # A pure tone for 2e5 samples: the matched correlator must stay at N exactly.
    fs, f = 8000.0, 412.5
    n_total = 200_000
    bank = UnitCorrelatorBank(fs, [[f]], [80])
    tone = np.exp(2j * np.pi * f * np.arange(n_total) / fs)
    u = np.concatenate([bank.process(tone[i : i + 7919]) for i in range(0, n_total, 7919)])
    assert np.max(np.abs(np.abs(u[80:, 0, 0]) - 80.0)) < 1e-3


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, 3000), max_size=6))
def test_unit_correlators_chunks_equal_whole_bitwise(cuts: list[int]) -> None:
    rng = np.random.default_rng(7)
    x = rng.normal(size=3000) + 1j * rng.normal(size=3000)
    nu, lengths = np.array([[100.0, -300.0], [110.0, -290.0]]), np.array([30, 33])
    whole = UnitCorrelatorBank(8000.0, nu, lengths, cell=128, anchor=512).process(x)
    bank = UnitCorrelatorBank(8000.0, nu, lengths, cell=128, anchor=512)
    parts = np.concatenate([bank.process(c) for c in _chunks(x, cuts)])
    assert np.array_equal(parts, whole)


@settings(max_examples=60, deadline=None)
@given(
    pfa=st.floats(1e-9, 0.9),
    m_hops=st.integers(1, 60),
    n_codewords=st.integers(1, 40),
    coherent=st.booleans(),
)
def test_the_threshold_is_scipy_stats(
    pfa: float, m_hops: int, n_codewords: int, coherent: bool
) -> None:
    # lambda_for_pfa inverts the noise statistic in closed form (scipy.stats would add a
    # second of start-up): the thresholds scipy.stats' exponential and gamma give, to 1e-12
    # of the threshold (λ is the threshold less the mean, over the standard deviation).
    from scipy import stats

    from hil.estimation.detection import CELLS_PER_UPDATE, lambda_for_pfa

    p1 = min(pfa / (n_codewords * CELLS_PER_UPDATE), 0.5)
    if coherent:
        thr = float(stats.expon.isf(p1, scale=m_hops))
        expected = (thr - m_hops) / m_hops
    else:
        thr = float(stats.gamma.isf(p1, a=m_hops))
        expected = (thr - m_hops) / math.sqrt(m_hops)
    std = m_hops if coherent else math.sqrt(m_hops)
    got = lambda_for_pfa(pfa, m_hops, n_codewords, coherent)
    assert got == pytest.approx(expected, rel=0.0, abs=1e-12 * thr / std)


def test_a_pfa_whose_per_test_share_underflows_is_refused() -> None:
    from hil.estimation.detection import lambda_for_pfa

    with pytest.raises(ConfigError, match=r"pfa = 5e-324 is not allowed: must be > 4352 x 5e-324"):
        lambda_for_pfa(5e-324, 10, 17, False)


def test_the_compiled_rotation_is_the_numpy_formulation_bit_for_bit() -> None:
    # ComplexBaseband's output: the decimated complex-tap FIR rotated by
    # exp(−j2π frac(n·f_c·R/fs)) with real products and sums each rounded once, as NumPy
    # writes it; 0.2 s of noise at att's rate, from an absolute index far from 0.
    bb = ComplexBaseband(100_000.0, 30_000.0, decimation=12, passband_hz=3000.0)
    start = 987_654_321
    bb.reset(start)
    x = np.random.default_rng(27).normal(size=20_000)
    got = bb.process(x)
    taps = bb.n_taps
    buf = np.concatenate((np.zeros(taps - 1), x))
    first = -(-start // 12)
    n = np.arange(first, (start + x.size - 1) // 12 + 1, dtype=np.int64)
    acc_re, acc_im = np.empty(n.size), np.empty(n.size)
    fir_decimate(buf, first * 12 - start, n.size, 12, bb._g_re, bb._g_im, acc_re, acc_im)
    rot = np.exp(-2j * np.pi * np.mod(n.astype(np.float64) * bb._cycles_per_output, 1.0))
    want = np.empty(n.size, dtype=np.complex128)
    want.real = rot.real * acc_re - rot.imag * acc_im
    want.imag = rot.real * acc_im + rot.imag * acc_re
    assert got.shape == want.shape and np.array_equal(got.view(np.float64), want.view(np.float64))
