"""Parametric radiated-noise spectra of targets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hil.errors import ConfigError
from sim_devices.acoustics.radiated_noise import TARGET_PRESETS, RadiatedNoiseSpectrum


@pytest.mark.parametrize("name", ["submarine", "surface_ship", "torpedo"])
def test_preset_shape(name: str) -> None:
    target = TARGET_PRESETS[name]
    assert target.level_db(1000.0) == target.level_at_1khz_db
    # 20 dB per decade above the knee, flat below it.
    assert target.level_db(20e3) == pytest.approx(target.level_db(2e3) - 20.0)
    below = np.asarray(target.level_db(np.array([10.0, target.knee_hz / 2, target.knee_hz])))
    assert np.all(below == below[-1])


def test_speed_law_is_60_log_v() -> None:
    ship = TARGET_PRESETS["surface_ship"]
    double = ship.level_db(5e3, 2.0 * ship.reference_speed_mps)
    assert double == pytest.approx(ship.level_db(5e3) + 60.0 * math.log10(2.0))


def test_presets_are_ordered_quiet_to_loud_at_10_khz() -> None:
    levels = [TARGET_PRESETS[n](10e3) for n in ("submarine", "surface_ship", "torpedo")]
    assert levels == sorted(levels)


def test_negative_speed_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"speed_mps = -3\.0 is not allowed: must be > 0 m/s"):
        TARGET_PRESETS["torpedo"].level_db(1e3, -3.0)


def test_rising_spectrum_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"slope_db_per_decade = -6\.0 is not allowed"):
        RadiatedNoiseSpectrum("odd", 120.0, 100.0, -6.0, 5.0)
