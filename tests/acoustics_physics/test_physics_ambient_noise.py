"""Ambient noise: the four-component model's published values, sea states, self-noise."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from sim_devices.acoustics.ambient_noise import (
    SEA_STATE_TABLE,
    AmbientNoiseModel,
    ambient_noise_level,
    flat_self_noise_level,
    power_sum_db,
    sea_state,
    sea_state_wind_speed,
    shipping_noise_level,
    thermal_noise_level,
    turbulence_noise_level,
    wind_noise_level,
)


@pytest.mark.parametrize(
    ("frequency_hz", "level_db"),
    [(1e3, 61.0), (10e3, 46.1), (30e3, 37.0), (50e3, 32.8), (100e3, 28.9)],
)
def test_total_matches_the_published_values(frequency_hz: float, level_db: float) -> None:
    # w = 5 m/s, s = 0.5 (REFERENCE-VALUES.md, Coates/Stojanovic as in ns-3).
    assert round(float(ambient_noise_level(frequency_hz, 5.0, 0.5)), 1) == level_db


def test_thermal_alone_at_100_khz() -> None:
    assert round(float(thermal_noise_level(100e3)), 1) == 25.0


def test_components_at_1_khz_follow_the_formulas() -> None:
    # f = 1 kHz makes every log10 f term vanish; the rest by hand.
    assert turbulence_noise_level(1e3) == pytest.approx(17.0)
    assert shipping_noise_level(1e3, 0.5) == pytest.approx(40.0 - 60.0 * math.log10(1.03))
    assert shipping_noise_level(1e3, 1.0) == pytest.approx(50.0 - 60.0 * math.log10(1.03))
    assert wind_noise_level(1e3, 4.0) == pytest.approx(65.0 - 40.0 * math.log10(1.4))
    assert thermal_noise_level(1e3) == pytest.approx(-15.0)


@settings(max_examples=60, deadline=None)
@given(st.floats(10.0, 1e6), st.floats(0.0, 30.0), st.floats(0.0, 1.0))
def test_total_is_the_power_sum_and_above_every_component(f: float, w: float, s: float) -> None:
    parts = [
        turbulence_noise_level(f),
        shipping_noise_level(f, s),
        wind_noise_level(f, w),
        thermal_noise_level(f),
    ]
    total = ambient_noise_level(f, w, s)
    assert total == pytest.approx(10.0 * math.log10(sum(10.0 ** (p / 10.0) for p in parts)))
    assert total >= max(parts)


def test_power_sum_of_equal_levels_adds_3_db() -> None:
    assert power_sum_db(50.0, 50.0) == pytest.approx(50.0 + 10.0 * math.log10(2.0))


def test_self_noise_adds_in_power() -> None:
    f = np.array([1e3, 10e3, 100e3])
    sea = np.asarray(ambient_noise_level(f))
    with_self = np.asarray(ambient_noise_level(f, self_noise_db=45.0))
    assert np.allclose(with_self, 10.0 * np.log10(10.0 ** (sea / 10.0) + 10.0**4.5))
    assert np.all(np.asarray(flat_self_noise_level(f, 45.0)) == 45.0)


def test_sea_state_table_is_wmo_code_0_to_9_with_growing_wind() -> None:
    assert [row.code for row in SEA_STATE_TABLE] == list(range(10))
    winds = [sea_state_wind_speed(code) for code in range(10)]
    assert winds == sorted(winds) and winds[0] == 0.1
    heights = [row.wave_height_m for row in SEA_STATE_TABLE]
    assert heights[3] == (0.5, 1.25) and heights[6] == (4.0, 6.0)  # WMO code 3700
    assert sea_state(4).description == "moderate"


def test_noise_rises_with_sea_state_at_10_khz() -> None:
    levels = [AmbientNoiseModel.from_sea_state(code)(10e3) for code in range(10)]
    assert levels == sorted(levels)


def test_model_object_equals_the_function() -> None:
    model = AmbientNoiseModel(7.0, 0.2, 40.0)
    f = np.geomspace(100.0, 1e5, 7)
    assert np.array_equal(model(f), ambient_noise_level(f, 7.0, 0.2, 40.0))


@pytest.mark.parametrize("bad", [-1, 10, 3.5, True])
def test_sea_state_outside_0_to_9_is_refused(bad: object) -> None:
    with pytest.raises(
        ConfigError, match=r"sea_state = .* is not allowed: must be an integer WMO sea-state code"
    ):
        sea_state(bad)  # type: ignore[arg-type]


def test_negative_frequency_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"frequency_hz = -10\.0 is not allowed: must be > 0 Hz"):
        ambient_noise_level(np.array([100.0, -10.0]))


def test_shipping_above_one_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"shipping = 1\.5 is not allowed: must be 0 to 1"):
        AmbientNoiseModel(5.0, 1.5)


def test_negative_wind_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"wind_speed_mps = -2\.0 is not allowed: must be >= 0"):
        wind_noise_level(1e3, -2.0)
