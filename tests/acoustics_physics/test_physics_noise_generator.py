"""The shaped-noise generator: spectrum level, streaming determinism, impulsive option."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import welch
from scipy.stats import kurtosis

from hil.errors import ConfigError
from sim_devices.acoustics.ambient_noise import AmbientNoiseModel
from sim_devices.acoustics.noise_generator import (
    ShapedNoiseGenerator,
    design_shaping_filter,
    filter_level_db,
)

FS = 96_000.0
BAND = (2_000.0, 40_000.0)
SEA = AmbientNoiseModel.from_sea_state(3)


def _welch_error_db(
    x: np.ndarray, model: AmbientNoiseModel, margin_hz: float = 1000.0
) -> np.ndarray:
    f, p = welch(x, FS, nperseg=2048)
    inside = (f > BAND[0] + margin_hz) & (f < BAND[1] - margin_hz)
    return np.asarray(10.0 * np.log10(p[inside]) - np.asarray(model(f[inside])))


def test_welch_psd_follows_the_model_within_1_db() -> None:
    x = ShapedNoiseGenerator(SEA, FS, BAND, seed=3).generate(2**20)
    err = _welch_error_db(x, SEA)
    assert np.max(np.abs(err)) < 1.0
    assert abs(np.mean(err)) < 0.1  # no overall level bias


def test_out_of_band_power_is_far_below_the_band() -> None:
    x = ShapedNoiseGenerator(SEA, FS, BAND, seed=4).generate(2**18)
    f, p = welch(x, FS, nperseg=2048)
    level = 10.0 * np.log10(p)
    above = f > BAND[1] + 3000.0
    in_band_min = float(np.min(np.asarray(SEA(f[(f > BAND[0]) & (f < BAND[1])]))))
    assert np.max(level[above]) < in_band_min - 20.0


def test_designed_filter_response_matches_the_model_away_from_edges() -> None:
    taps = design_shaping_filter(SEA, FS, BAND, 1025)
    f = np.linspace(BAND[0] + 600.0, BAND[1] - 600.0, 400)
    assert np.max(np.abs(filter_level_db(taps, FS, f) - np.asarray(SEA(f)))) < 0.05


def torpedo(frequency_hz: np.ndarray) -> np.ndarray:
    """A target's radiated noise, dB re 1 µPa²/Hz: 150 dB at 1 kHz, flat below a 500 Hz
    knee, falling 20 dB a decade above it."""
    return 150.0 - 20.0 * np.log10(np.maximum(frequency_hz, 500.0) / 1000.0)


def test_a_sloped_radiated_noise_spectrum_drives_the_generator() -> None:
    x = ShapedNoiseGenerator(torpedo, FS, BAND, seed=9).generate(2**18)
    f, p = welch(x, FS, nperseg=1024)
    inside = (f > 4000.0) & (f < 38000.0)
    err = 10.0 * np.log10(p[inside]) - np.asarray(torpedo(f[inside]))
    assert np.max(np.abs(err)) < 1.5 and abs(np.mean(err)) < 0.2


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, 40_000), min_size=1, max_size=8))
def test_any_chunking_gives_exactly_the_whole(chunks: list[int]) -> None:
    whole = ShapedNoiseGenerator(SEA, FS, BAND, seed=11, block_size=4096).generate(sum(chunks))
    gen = ShapedNoiseGenerator(SEA, FS, BAND, seed=11, block_size=4096)
    parts = np.concatenate([gen.generate(n) for n in chunks])
    assert np.array_equal(parts, whole)
    assert gen.samples_generated == sum(chunks)


def test_reset_replays_and_seeds_differ() -> None:
    gen = ShapedNoiseGenerator(SEA, FS, BAND, seed=5)
    first = gen.generate(5000)
    gen.reset()
    assert np.array_equal(gen.generate(5000), first)
    other = ShapedNoiseGenerator(SEA, FS, BAND, seed=6).generate(5000)
    assert abs(np.corrcoef(first, other)[0, 1]) < 0.1


def test_stream_is_stationary_from_sample_zero() -> None:
    # No filter start-up transient: the first block has the same power as a later one.
    x = ShapedNoiseGenerator(SEA, FS, BAND, seed=8, block_size=2048).generate(40 * 2048)
    head = np.var(x[:1024])
    later = np.var(x[20 * 2048 : 20 * 2048 + 1024])
    assert 0.7 < head / later < 1.4


def test_alpha_two_behaves_gaussian() -> None:
    gaussian = ShapedNoiseGenerator(SEA, FS, BAND, seed=21).generate(2**19)
    stable = ShapedNoiseGenerator(SEA, FS, BAND, seed=21, alpha=2.0).generate(2**19)
    assert abs(float(kurtosis(stable))) < 0.1  # excess kurtosis of a Gaussian is 0
    assert np.var(stable) / np.var(gaussian) == pytest.approx(1.0, abs=0.03)
    assert np.max(np.abs(_welch_error_db(stable, SEA))) < 1.0


def test_alpha_below_two_is_impulsive() -> None:
    x = ShapedNoiseGenerator(SEA, FS, BAND, seed=22, alpha=1.5).generate(2**17)
    assert float(kurtosis(x)) > 5.0


def test_alpha_stable_chunks_equal_whole() -> None:
    whole = ShapedNoiseGenerator(SEA, FS, BAND, seed=2, alpha=1.7).generate(50_000)
    gen = ShapedNoiseGenerator(SEA, FS, BAND, seed=2, alpha=1.7)
    parts = np.concatenate([gen.generate(n) for n in (17, 30_000, 19_983)])
    assert np.array_equal(parts, whole)


@pytest.mark.parametrize("fs", [0.0, -48_000.0])
def test_non_positive_sample_rate_is_refused(fs: float) -> None:
    with pytest.raises(ConfigError, match=r"fs_hz = -?[0-9.]+ is not allowed: must be > 0 Hz"):
        ShapedNoiseGenerator(SEA, fs, BAND)


def test_band_beyond_nyquist_is_refused() -> None:
    with pytest.raises(
        ConfigError,
        match=r"band_hz = \(2000\.0, 60000\.0\) is not allowed: must be .*fs/2 = 48000 Hz",
    ):
        ShapedNoiseGenerator(SEA, FS, (2000.0, 60000.0))


def test_even_filter_length_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"n_taps = 1024 is not allowed: must be an odd integer"):
        ShapedNoiseGenerator(SEA, FS, BAND, n_taps=1024)


def test_alpha_outside_0_2_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"alpha = 2\.5 is not allowed: must be 0 < alpha <= 2"):
        ShapedNoiseGenerator(SEA, FS, BAND, alpha=2.5)


def test_negative_seed_and_sample_count_are_refused() -> None:
    with pytest.raises(ConfigError, match=r"seed = -1 is not allowed: must be an integer >= 0"):
        ShapedNoiseGenerator(SEA, FS, BAND, seed=-1)
    gen = ShapedNoiseGenerator(SEA, FS, BAND)
    with pytest.raises(ConfigError, match=r"n_samples = -3 is not allowed"):
        gen.generate(-3)


def test_negative_frequency_band_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"band_hz = \(-100\.0, 1000\.0\) is not allowed"):
        ShapedNoiseGenerator(SEA, FS, (-100.0, 1000.0))
