"""Sound speed from temperature (published values) and from time of flight (injected c)."""

from __future__ import annotations

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.experiments.calibration.ranging import EchoRanger
from hil.experiments.calibration.simworld import EchoTank, MechanicalStage
from hil.experiments.calibration.sound_speed import (
    SoundSpeedResult,
    calibrate_sound_speed_temperature,
    calibrate_sound_speed_tof,
)
from sim_devices.acoustics.sound_speed import unesco_sound_speed


def test_fresh_water_from_temperature() -> None:
    r = calibrate_sound_speed_temperature(20.0, temperature_uncertainty_c=0.3)
    # Marczak agrees with the Del Grosso pure-water polynomial (UNESCO at S = 0) to 0.05 m/s.
    assert r.sound_speed_mps == pytest.approx(unesco_sound_speed(0.0, 20.0, 0.0), abs=0.05)
    assert r.uncertainty_mps == pytest.approx(3.0 * 0.3, rel=0.05)  # dc/dT ≈ 3 m/s/°C
    assert r.formula.startswith("Marczak") and r.method == "temperature"
    assert SoundSpeedResult.from_json(r.to_json()) == r


def test_salinity_selects_mackenzie_with_its_published_value() -> None:
    r = calibrate_sound_speed_temperature(25.0, salinity_ppt=35.0, depth_m=20.0)
    assert round(r.sound_speed_mps, 1) == 1534.6  # REFERENCE-VALUES.md, Mackenzie (1981)
    assert r.formula.startswith("Mackenzie")


def test_temperatures_outside_the_formulas_are_refused() -> None:
    with pytest.raises(
        ConfigError, match=r"^temperature_c = -2.0 is not allowed: must be 0 to 95 °C"
    ):
        calibrate_sound_speed_temperature(-2.0)
    with pytest.raises(ConfigError, match=r"^salinity_ppt = 10.0 is not allowed: must be 25 to 40"):
        calibrate_sound_speed_temperature(15.0, salinity_ppt=10.0)


@pytest.mark.slow
def test_time_of_flight_within_0_1_percent_of_the_injected_c(
    tank: tuple[MechanicalStage, EchoTank, EchoRanger],
) -> None:
    stage, echo_tank, ranger = tank
    stage.scale = 1.0  # the fit sees c / scale: a true stage here (see the module docstring)
    r = calibrate_sound_speed_tof(stage, ranger, np.linspace(-0.4, -0.05, 8), speed_mps=0.1)
    c = echo_tank.sound_speed_mps
    assert abs(r.sound_speed_mps - c) / c < 1e-3  # the requirement, with noise
    assert abs(r.sound_speed_mps - c) < 4 * r.uncertainty_mps + 0.05
    assert r.offset_m == pytest.approx(echo_tank.standoff_m, abs=1e-3)
    assert r.residual_rms_s is not None and r.residual_rms_s < 2e-7
    assert len(r.positions_m) == 8


def test_no_stage_positions_is_refused(tank: tuple[MechanicalStage, EchoTank, EchoRanger]) -> None:
    stage, _, ranger = tank
    with pytest.raises(
        ConfigError, match=r"^positions_m = \[\] is not allowed: must be at least 3"
    ):
        calibrate_sound_speed_tof(stage, ranger, [])
    with pytest.raises(ConfigError, match=r"^positions_m = 0.1 is not allowed: must be within"):
        calibrate_sound_speed_tof(stage, ranger, [-0.2, -0.1, 0.1])
