"""Kaiser-windowed sinc interpolator: the documented error table, exactness and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from hil.errors import ConfigError
from sim_devices.acoustics.fractional_delay import KaiserSincInterpolator, kaiser_sinc

N_SAMPLES = 4000


def _tone_error_db(freq_per_fs: float, interp: KaiserSincInterpolator) -> float:
    """Error power / signal power (dB) of a unit tone read at slowly wandering positions."""
    rng = np.random.default_rng(int(freq_per_fs * 1e4))
    phase = rng.uniform(0, 2 * np.pi)
    x = np.cos(2 * np.pi * freq_per_fs * np.arange(N_SAMPLES) + phase)
    # Time-varying fractional delay: a ramp plus a ±0.37-sample wobble.
    pos = np.linspace(100.0, N_SAMPLES - 100.0, 3000) + 0.37 * np.sin(np.arange(3000) / 300)
    ref = np.cos(2 * np.pi * freq_per_fs * pos + phase)
    err = interp.interpolate_array(x, pos) - ref
    return float(10 * np.log10(np.mean(err**2) / np.mean(ref**2)))


def test_error_table_of_the_default_design() -> None:
    interp = KaiserSincInterpolator()
    assert (interp.taps, interp.beta, interp.phases) == (32, 9.0, 1024)
    in_band = [_tone_error_db(f, interp) for f in np.linspace(0.01, 0.40, 40)]
    assert max(in_band) < -85.0
    assert _tone_error_db(0.41, interp) < -85.0
    # Beyond the documented band the error grows as the module docstring says.
    assert -62.0 < _tone_error_db(0.42, interp) < -52.0
    assert _tone_error_db(0.45, interp) > -30.0


def test_integer_positions_return_the_samples() -> None:
    rng = np.random.default_rng(3)
    x = rng.standard_normal(300)
    k = np.arange(20, 280)
    np.testing.assert_allclose(KaiserSincInterpolator().interpolate_array(x, k), x[k], atol=1e-12)


def test_tabulated_kernel_matches_the_exact_kernel() -> None:
    interp = KaiserSincInterpolator(half_length=8, beta=7.0)
    rng = np.random.default_rng(11)
    x = rng.standard_normal(200)
    pos = rng.uniform(20, 180, 500)
    exact = np.zeros(pos.size)
    for k in range(x.size):
        exact += x[k] * kaiser_sinc(pos - k, 8, 7.0)
    np.testing.assert_allclose(interp.interpolate_array(x, pos), exact, atol=2e-5)


def test_samples_outside_the_array_read_as_zero_and_first_index_shifts() -> None:
    interp = KaiserSincInterpolator(half_length=4)
    x = np.ones(10)
    assert interp.interpolate_array(x, np.array([-10.0, 30.5])).tolist() == [0.0, 0.0]
    shifted = interp.interpolate_array(x, np.array([105.5]), first_index=100)
    plain = interp.interpolate_array(x, np.array([5.5]))
    assert shifted.tolist() == plain.tolist()
    assert interp.span(np.array([10.5, 12.0])) == (7, 16)


def test_chunks_equal_whole_bit_for_bit() -> None:
    interp = KaiserSincInterpolator()
    rng = np.random.default_rng(5)
    x = rng.standard_normal(5000)
    pos = np.cumsum(rng.uniform(0.9, 1.1, 4000)) + 30
    whole = interp.interpolate_array(x, pos)
    parts = [interp.interpolate_array(x, p) for p in np.array_split(pos, [1, 17, 900, 2500])]
    assert np.array_equal(np.concatenate(parts), whole)


def test_bad_settings_and_inputs_are_refused() -> None:
    with pytest.raises(
        ConfigError, match=r"half_length = 1 is not allowed: must be an integer >= 2"
    ):
        KaiserSincInterpolator(half_length=1)
    with pytest.raises(ConfigError, match=r"beta = -1\.0 is not allowed: must be >= 0 and finite"):
        KaiserSincInterpolator(beta=-1.0)
    with pytest.raises(ConfigError, match=r"phases = 8 is not allowed: must be an integer >= 16"):
        KaiserSincInterpolator(phases=8)
    interp = KaiserSincInterpolator()
    with pytest.raises(ConfigError, match=r"positions = 'NaN/inf' .* finite sample positions"):
        interp.interpolate_array(np.ones(100), np.array([np.nan]))
    with pytest.raises(ConfigError, match=r"x = 'shape \(2, 50\)' .* a 1-D array of samples"):
        interp.interpolate_array(np.ones((2, 50)), np.array([3.0]))
