"""Transmission loss and its inverse, including MATLAB's range2tl / tl2range examples."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from sim_devices.acoustics.absorption import ainslie_mccolm_absorption, francois_garrison_absorption
from sim_devices.acoustics.propagation import (
    channel_absorption,
    channel_transmission_loss,
    range_for_channel_transmission_loss,
    range_for_spherical_transmission_loss,
    spherical_transmission_loss,
)


def test_spherical_tl_is_20_log_r_plus_alpha_r() -> None:
    alpha = francois_garrison_absorption(50e3)  # 10.71 dB/km
    assert spherical_transmission_loss(3000.0, alpha) == pytest.approx(
        20.0 * math.log10(3000.0) + 3.0 * alpha, rel=1e-14
    )
    assert round(float(spherical_transmission_loss(1000.0, alpha)), 2) == 70.71


def test_matlab_range2tl_example() -> None:
    # MATLAB: range2tl(1000, 2000, 200) = 50.1261 dB.
    assert round(float(channel_transmission_loss(1000.0, 2000.0, 200.0)), 4) == 50.1261


def test_matlab_tl2range_example() -> None:
    # MATLAB: tl2range(50, 2000, 200) = 972.1666 m.
    assert round(float(range_for_channel_transmission_loss(50.0, 2000.0, 200.0)), 4) == 972.1666


def test_channel_absorption_is_ainslie_mccolm_at_the_transition_depth() -> None:
    # The environment that reproduces both MATLAB examples (see channel_absorption).
    assert channel_absorption(2000.0, 200.0) == ainslie_mccolm_absorption(
        2000.0, 10.0, 35.0, 100.0, 8.0
    )


def test_channel_tl_is_spherical_inside_half_the_depth_and_continuous_at_it() -> None:
    alpha = channel_absorption(2000.0, 200.0)
    assert channel_transmission_loss(50.0, 2000.0, 200.0) == pytest.approx(
        spherical_transmission_loss(50.0, alpha), rel=1e-14
    )
    below = channel_transmission_loss(100.0 - 1e-9, 2000.0, 200.0)
    above = channel_transmission_loss(100.0 + 1e-9, 2000.0, 200.0)
    assert abs(float(above) - float(below)) < 1e-6


@settings(max_examples=60, deadline=None)
@given(st.floats(0.01, 1e5), st.floats(0.0, 50.0))
def test_spherical_inverse_round_trip(range_m: float, alpha: float) -> None:
    tl = spherical_transmission_loss(range_m, alpha)
    assert range_for_spherical_transmission_loss(tl, alpha) == pytest.approx(range_m, rel=1e-10)


@settings(max_examples=60, deadline=None)
@given(st.floats(1.0, 5e4), st.floats(100.0, 1e5), st.floats(5.0, 5000.0))
def test_channel_inverse_round_trip(range_m: float, frequency: float, depth: float) -> None:
    tl = channel_transmission_loss(range_m, frequency, depth)
    back = range_for_channel_transmission_loss(tl, frequency, depth)
    assert back == pytest.approx(range_m, rel=1e-10)


def test_inverse_accepts_arrays() -> None:
    tl = np.array([40.0, 60.0, 80.0])
    r = range_for_spherical_transmission_loss(tl, 1.0)
    assert isinstance(r, np.ndarray) and r.shape == (3,)
    assert np.allclose(spherical_transmission_loss(r, 1.0), tl, rtol=0, atol=1e-9)


def test_negative_range_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"range_m = -5\.0 is not allowed: must be > 0 m"):
        spherical_transmission_loss(-5.0)


def test_negative_absorption_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"alpha_db_per_km = -1\.0 is not allowed: must be >= 0"):
        range_for_spherical_transmission_loss(60.0, -1.0)


def test_zero_channel_depth_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"channel_depth_m = 0\.0 is not allowed: must be > 0 m"):
        channel_transmission_loss(100.0, 2000.0, 0.0)
