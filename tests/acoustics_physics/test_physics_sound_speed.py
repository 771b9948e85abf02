"""Sound speed: published check values, validity ranges, fresh water."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from sim_devices.acoustics.sound_speed import (
    fresh_water_sound_speed,
    mackenzie_sound_speed,
    tank_sound_speed,
    unesco_sound_speed,
)


def test_mackenzie_reproduces_the_published_values() -> None:
    # arlpy's documented Mackenzie values (REFERENCE-VALUES.md).
    assert round(float(mackenzie_sound_speed(27.0, 35.0, 10.0)), 1) == 1539.1
    assert round(float(mackenzie_sound_speed(25.0, 35.0, 20.0)), 1) == 1534.6


def test_unesco_reproduces_the_fofonoff_millard_check_value() -> None:
    c = unesco_sound_speed(40.0, 40.0, 10000.0)
    assert isinstance(c, float)
    assert abs(c - 1731.995) < 5e-4


def test_unesco_at_zero_salinity_and_pressure_is_del_grosso_mader_pure_water() -> None:
    # Del Grosso & Mader (1972) pure water at 20 °C: 1482.343 m/s (the S = 0, P = 0 term).
    assert abs(float(unesco_sound_speed(0.0, 20.0, 0.0)) - 1482.343) < 5e-4


def test_marczak_fresh_water_stays_within_5_cm_per_s_of_del_grosso_mader() -> None:
    t = np.linspace(0.0, 40.0, 401)
    diff = np.asarray(fresh_water_sound_speed(t)) - np.asarray(unesco_sound_speed(0.0, t, 0.0))
    assert np.max(np.abs(diff)) < 0.05


def test_fresh_water_sound_speed_peaks_near_74_celsius() -> None:
    # Pure water's sound speed has its maximum (about 1555 m/s) near 74 °C.
    t = np.linspace(0.0, 95.0, 9501)
    c = np.asarray(fresh_water_sound_speed(t))
    assert 73.0 < t[np.argmax(c)] < 75.0
    assert 1554.0 < c.max() < 1556.0


def test_tank_sound_speed_is_the_fresh_water_formula() -> None:
    assert tank_sound_speed(18.5) == fresh_water_sound_speed(18.5)
    assert round(float(tank_sound_speed(25.0)), 1) == 1496.7


def test_array_inputs_broadcast_and_keep_shape() -> None:
    t = np.array([[5.0, 10.0], [15.0, 20.0]])
    c = mackenzie_sound_speed(t, 35.0, np.array([0.0, 100.0]))
    assert isinstance(c, np.ndarray) and c.shape == (2, 2)
    assert c[1, 1] == mackenzie_sound_speed(20.0, 35.0, 100.0)


@settings(max_examples=50, deadline=None)
@given(st.floats(2.0, 29.0), st.floats(25.0, 40.0), st.floats(0.0, 8000.0), st.floats(0.01, 1.0))
def test_mackenzie_grows_with_temperature(t: float, s: float, d: float, dt: float) -> None:
    assert mackenzie_sound_speed(t + dt, s, d) > mackenzie_sound_speed(t, s, d)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"temperature_c": 20.0, "salinity_ppt": 0.0, "depth_m": 1.0},
            "salinity_ppt = 0.0 is not allowed: must be 25 to 40 ppt (Mackenzie 1981)",
        ),
        (
            {"temperature_c": 35.0, "salinity_ppt": 35.0, "depth_m": 1.0},
            "temperature_c = 35.0 is not allowed: must be 2 to 30 °C (Mackenzie 1981)",
        ),
        (
            {"temperature_c": 10.0, "salinity_ppt": 35.0, "depth_m": 9000.0},
            "depth_m = 9000.0 is not allowed: must be 0 to 8000 m (Mackenzie 1981)",
        ),
    ],
)
def test_mackenzie_refuses_out_of_range_and_points_elsewhere(
    kwargs: dict[str, float], message: str
) -> None:
    with pytest.raises(ConfigError) as err:
        mackenzie_sound_speed(**kwargs)
    assert str(err.value).startswith(message)
    assert "tank_sound_speed" in str(err.value) and "unesco_sound_speed" in str(err.value)


def test_mackenzie_names_the_first_bad_element_of_an_array() -> None:
    with pytest.raises(ConfigError, match=r"salinity_ppt = 10\.0 is not allowed"):
        mackenzie_sound_speed(20.0, np.array([35.0, 10.0, 5.0]), 0.0)


def test_unesco_refuses_pressure_beyond_10000_dbar() -> None:
    with pytest.raises(
        ConfigError,
        match=r"pressure_dbar = 12000\.0 is not allowed: must be 0 to 10000 dbar \(UNESCO 1983\)",
    ):
        unesco_sound_speed(35.0, 10.0, 12000.0)


def test_fresh_water_refuses_boiling_water() -> None:
    with pytest.raises(
        ConfigError,
        match=r"temperature_c = 100\.0 is not allowed: must be 0 to 95 °C \(Marczak 1997\)",
    ):
        tank_sound_speed(100.0)


def test_nan_temperature_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"temperature_c = nan is not allowed: must be a finite"):
        tank_sound_speed(float("nan"))
