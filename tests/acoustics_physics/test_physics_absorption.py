"""Absorption: Francois-Garrison, Ainslie-McColm and Thorp against published numbers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from sim_devices.acoustics.absorption import (
    ainslie_mccolm_absorption,
    francois_garrison_absorption,
    thorp_absorption,
)


def test_francois_garrison_reproduces_arlpy_documentation() -> None:
    # 50 kHz, 27 °C, 35 ppt, 10 m, pH 8.1: 10.71 dB/km, 32.13 dB over 3 km.
    alpha = float(francois_garrison_absorption(50e3, 27.0, 35.0, 10.0, 8.1))
    assert round(alpha, 2) == 10.71
    assert round(3.0 * alpha, 2) == 32.13


@pytest.mark.parametrize(
    ("frequency_hz", "kwargs", "db_per_km"),
    [
        # arlpy's test suite (rounded to whole dB): arlpy defaults are 27 °C, 35 ppt, 10 m, pH 8.1.
        (10e3, {"temperature_c": 15.0}, 1),
        (50e3, {}, 11),
        (100e3, {}, 36),
        (100e3, {"temperature_c": 14.0, "salinity_ppt": 38.5, "depth_m": 0.0}, 40),
        (100e3, {"temperature_c": 14.0, "salinity_ppt": 38.5, "depth_m": 2000.0}, 30),
        (100e3, {"temperature_c": 14.0, "salinity_ppt": 38.5, "depth_m": 6000.0}, 16),
    ],
)
def test_francois_garrison_matches_arlpy_tests(
    frequency_hz: float, kwargs: dict[str, float], db_per_km: int
) -> None:
    assert round(float(francois_garrison_absorption(frequency_hz, **kwargs))) == db_per_km


def test_ainslie_mccolm_reproduces_the_published_values() -> None:
    a = ainslie_mccolm_absorption(108e3, 11.0, 37.0, 100.0, 8.2)
    b = ainslie_mccolm_absorption(77.2e3, 4.0, 8.0, 10.0, 7.9)
    # (f, T °C, S ppt, depth m = 0.1 km and 0.01 km, pH) as listed.
    assert round(float(a), 8) == 39.06447169
    assert round(float(b), 8) == 7.23171795


def test_thorp_is_the_stated_formula_at_1_and_10_khz() -> None:
    # 0.11 f²/(1+f²) + 44 f²/(4100+f²) + 2.75e-4 f² + 0.003 with f in kHz, by hand:
    assert thorp_absorption(1000.0) == pytest.approx(0.055 + 44.0 / 4101.0 + 2.75e-4 + 0.003)
    assert thorp_absorption(10e3) == pytest.approx(
        11.0 / 101.0 + 4400.0 / 4200.0 + 2.75e-2 + 0.003, rel=1e-12
    )


def test_vector_input_gives_vector_output() -> None:
    f = np.array([1e3, 1e4, 1e5])
    out = francois_garrison_absorption(f)
    assert isinstance(out, np.ndarray) and out.shape == (3,)
    assert out[1] == francois_garrison_absorption(1e4)


@settings(max_examples=60, deadline=None)
@given(st.floats(100.0, 5e5), st.floats(1.01, 3.0), st.floats(0.0, 30.0))
def test_absorption_grows_with_frequency(f: float, ratio: float, t: float) -> None:
    assert francois_garrison_absorption(f * ratio, t) > francois_garrison_absorption(f, t)
    assert ainslie_mccolm_absorption(f * ratio, t) > ainslie_mccolm_absorption(f, t)
    assert thorp_absorption(f * ratio) > thorp_absorption(f)


def test_negative_frequency_is_refused_with_the_unit() -> None:
    with pytest.raises(
        ConfigError, match=r"frequency_hz = -1000\.0 is not allowed: must be > 0 Hz; frequencies"
    ):
        francois_garrison_absorption(-1000.0)


def test_zero_frequency_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"frequency_hz = 0\.0 is not allowed: must be > 0 Hz"):
        thorp_absorption(np.array([10.0, 0.0]))


def test_ainslie_mccolm_refuses_ph_outside_its_validity() -> None:
    with pytest.raises(
        ConfigError,
        match=r"ph = 9\.0 is not allowed: must be 7\.7 to 8\.3 \(Ainslie-McColm 1998\); .*francois",
    ):
        ainslie_mccolm_absorption(10e3, ph=9.0)
