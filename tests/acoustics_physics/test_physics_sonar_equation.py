"""Sonar-equation calculator: MATLAB's documented examples and identities."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from sim_devices.acoustics.sonar_equation import (
    active_snr_noise_limited,
    active_snr_reverberation_limited,
    active_source_level_required,
    active_transmission_loss_allowed,
    band_noise_level,
    passive_snr,
    signal_excess,
    sphere_target_strength,
)


def test_matlab_sonareqsnr_passive_example() -> None:
    assert passive_snr(200.0, 140.0, 75.0, 25.0) == 10.0


def test_matlab_sonareqsnr_active_example() -> None:
    assert active_snr_noise_limited(130.0, 60.0, 25.0, 45.0, 25.0) == 15.0


def test_matlab_sonareqsl_and_sonareqtl_active_examples() -> None:
    assert active_source_level_required(15.0, 60.0, 25.0, 45.0, 25.0) == 130.0
    assert active_transmission_loss_allowed(130.0, 15.0, 25.0, 45.0, 25.0) == 60.0


def test_reverberation_limited_and_signal_excess() -> None:
    snr = active_snr_reverberation_limited(210.0, 55.0, 5.0, 80.0)
    assert snr == 25.0
    assert signal_excess(snr, 25.0) == 0.0  # the 50 % detection point


def test_band_noise_level_adds_10_log_bandwidth() -> None:
    assert band_noise_level(46.1, 10e3) == pytest.approx(86.1)
    assert band_noise_level(50.0, 1.0) == 50.0


def test_sphere_target_strength() -> None:
    assert sphere_target_strength(2.0) == 0.0
    assert sphere_target_strength(1.0) == pytest.approx(-20.0 * math.log10(2.0))


@settings(max_examples=60, deadline=None)
@given(
    st.floats(150.0, 230.0),
    st.floats(0.0, 120.0),
    st.floats(-40.0, 30.0),
    st.floats(20.0, 100.0),
    st.floats(0.0, 30.0),
)
def test_inverses_undo_the_active_equation(
    sl: float, tl: float, ts: float, nl: float, di: float
) -> None:
    snr = active_snr_noise_limited(sl, tl, ts, nl, di)
    assert active_source_level_required(snr, tl, ts, nl, di) == pytest.approx(sl, abs=1e-9)
    assert active_transmission_loss_allowed(sl, snr, ts, nl, di) == pytest.approx(tl, abs=1e-9)


def test_zero_bandwidth_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"bandwidth_hz = 0\.0 is not allowed: must be > 0 Hz"):
        band_noise_level(50.0, 0.0)


def test_negative_radius_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"radius_m = -1\.0 is not allowed: must be > 0 m"):
        sphere_target_strength(-1.0)


def test_nan_level_is_refused() -> None:
    with pytest.raises(
        ConfigError, match=r"source_level_db = nan is not allowed: must be a finite"
    ):
        passive_snr(float("nan"), 60.0, 50.0)
