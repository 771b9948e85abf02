"""Cramér–Rao bounds (REFERENCE-VALUES golden numbers) and the cost model (seed Fig 5.15)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.estimation import cost, crlb
from hil.signals.waveforms import WaveformSpec, build_schedule

ROOT12 = math.sqrt(12.0)


def test_reference_example_flat_band() -> None:
    b = crlb.crlb(10_000 / ROOT12, 0.1 / ROOT12, 50_000.0, 20.0, 1500.0)
    assert round(b.sigma_range_m * 1e3, 2) == 2.92
    assert round(b.sigma_speed_mps * 1e3, 2) == 5.85
    assert b.valid


def test_bounds_scale_with_snr_and_validity_flag() -> None:
    hi = crlb.crlb(1000.0, 0.01, 30_000.0, 30.0, 1500.0)
    lo = crlb.crlb(1000.0, 0.01, 30_000.0, 10.0 - 1e-9, 1500.0)
    assert lo.sigma_range_m / hi.sigma_range_m == pytest.approx(10.0)
    assert not lo.valid


def test_bounds_from_a_sampled_lfm_match_the_flat_band_example() -> None:
    """A 10 kHz, 0.1 s LFM at 50 kHz has a nearly flat band: the measured B_rms and T_rms
    reproduce the published example within 2 %."""
    sch = build_schedule(
        WaveformSpec(family="fmcw-saw", center_hz=50e3, bandwidth_hz=10e3, sweep_s=0.1)
    )
    b = crlb.schedule_crlb(sch, 200_000.0, 0.0, 0.1, 20.0, 1500.0)
    assert b.sigma_range_m == pytest.approx(2.92e-3, rel=0.02)
    assert b.sigma_speed_mps == pytest.approx(5.85e-3, rel=0.02)
    assert b.f0_hz == pytest.approx(50_000.0, rel=1e-3)


def test_rms_duration_of_a_rectangle_and_bandwidth_of_a_tone() -> None:
    fs = 10_000.0
    assert crlb.rms_duration(np.ones(1000), fs) == pytest.approx(0.1 / ROOT12, rel=1e-9)
    tone = np.exp(2j * np.pi * 1000.0 * np.arange(4000) / fs)
    b_rms, f_mean = crlb.rms_bandwidth(tone, fs)
    assert f_mean == pytest.approx(1000.0, abs=1.0)
    # Only the sinc of the 0.4 s window (its slow sidelobes dominate the second moment),
    # and it narrows as the window grows.
    b_long, _ = crlb.rms_bandwidth(np.exp(2j * np.pi * 1000.0 * np.arange(16000) / fs), fs)
    assert b_rms < 100.0
    assert b_long < 0.6 * b_rms


def test_e_over_n0_helpers_agree() -> None:
    fs, t, a, sigma = 100_000.0, 0.05, 1.0, 3.0
    snr_db = 10 * math.log10(a * a / 2 / sigma**2)
    assert crlb.sampled_e_over_n0(a, sigma, fs, t) == pytest.approx(
        crlb.e_over_n0(snr_db, fs / 2, t)
    )
    assert crlb.e_over_n0_db(0.0, 1000.0, 0.1) == pytest.approx(20.0)


@pytest.mark.parametrize(
    ("call", "text"),
    [
        (lambda: crlb.crlb(0.0, 0.1, 5e4, 20.0, 1500.0), "b_rms_hz = 0.0 is not allowed"),
        (lambda: crlb.e_over_n0(math.nan, 1e3, 0.1), "snr_db = nan is not allowed"),
        (lambda: crlb.rms_bandwidth(np.zeros(8), 1e3), "samples = 'all zero'"),
        (lambda: crlb.rms_bandwidth([1.0, math.nan], 1e3), "finite samples"),
        (lambda: cost.direct_bank_mults_per_sample(17, 0, 5, 100), "n_doppler = 0"),
        (lambda: cost.cost_table([], 4, 8, 17, 100), "m_values = [] is not allowed"),
    ],
)
def test_bad_inputs_name_the_field(call: object, text: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(text)):
        call()  # type: ignore[operator]


def test_cost_table_values() -> None:
    t = cost.cost_table([5, 10, 15], n_tones=4, n_doppler=64, n_codewords=17, hop_samples=1000)
    assert t["gcas"].tolist() == [512.0, 512.0, 512.0]
    assert t["direct_bank"].tolist() == [5_440_000.0, 10_880_000.0, 16_320_000.0]
    assert t["gcas_adds"].tolist() == [4864.0, 10304.0, 15744.0]
    # N = 16384 for L = 5000: (8192·14 + 1088·(16384 + 8192·14)) / 11385
    expect5 = (8192 * 14 + 1088 * (16384 + 8192 * 14)) / 11385
    assert t["fft_bank"][0] == pytest.approx(expect5)
    # FFT bank grows slowly with M, the direct bank linearly, GCAS not at all.
    assert t["fft_bank"][0] < t["fft_bank"][2] < 2 * t["fft_bank"][0]
    assert np.all(t["gcas"] < t["fft_bank"])
