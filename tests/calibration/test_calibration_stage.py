"""Stage scale and backlash against the injected mechanism, and the no-echo refusal."""

from __future__ import annotations

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.experiments.calibration.apply import StagePositionCorrection
from hil.experiments.calibration.device import CalibrationError
from hil.experiments.calibration.ranging import EchoRanger
from hil.experiments.calibration.simworld import EchoTank, MechanicalStage, SimTruth
from hil.experiments.calibration.stage import StageResult, calibrate_stage

#: Stated tolerances: scale within 300 ppm, backlash within 50 µm (noise 1e-3 FS, 4 pings).
SCALE_TOL, BACKLASH_TOL_M = 3e-4, 50e-6


@pytest.mark.slow
def test_scale_and_backlash_recovered(
    tank: tuple[MechanicalStage, EchoTank, EchoRanger], tank_truth: SimTruth
) -> None:
    stage, echo_tank, ranger = tank
    r = calibrate_stage(
        stage, ranger, np.linspace(-0.4, -0.05, 8), sound_speed_mps=echo_tank.sound_speed_mps,
        speed_mps=0.1,
    )  # fmt: skip
    assert r.scale == pytest.approx(tank_truth.stage_scale, abs=SCALE_TOL)
    assert r.backlash_m == pytest.approx(tank_truth.backlash_m, abs=BACKLASH_TOL_M)
    assert r.axis_sign == 1 and r.residual_rms_m < 50e-6
    assert StageResult.from_json(r.to_json()) == r
    # The correction predicts where the carriage really is after a move.
    corr = StagePositionCorrection.from_result(r)
    stage.move_to(-0.3, 0.1)
    stage.move_to(-0.2, 0.1)  # approached moving +x
    offset = corr.true_position(-0.2, +1) - stage.carriage_m
    stage.move_to(-0.1, 0.1)
    stage.move_to(-0.2, 0.1)  # approached moving -x
    assert corr.true_position(-0.2, -1) - stage.carriage_m == pytest.approx(offset, abs=40e-6)


def test_bad_inputs_and_no_echo(tank: tuple[MechanicalStage, EchoTank, EchoRanger]) -> None:
    stage, echo_tank, ranger = tank
    c = echo_tank.sound_speed_mps
    with pytest.raises(
        ConfigError, match=r"^positions_m = \[-0.2\] is not allowed: must be at least 2"
    ):
        calibrate_stage(stage, ranger, [-0.2], sound_speed_mps=c)
    with pytest.raises(ConfigError, match=r"^positions_m = -0.448 is not allowed: .*less 0.005 m"):
        calibrate_stage(stage, ranger, [-0.448, -0.2], sound_speed_mps=c)
    with pytest.raises(ConfigError, match=r"^sound_speed_mps = 340.0 is not allowed"):
        calibrate_stage(stage, ranger, [-0.3, -0.2], sound_speed_mps=340.0)
    late_gate = EchoRanger(echo_tank.device(), (4e-3, 6e-3), latency_samples=300)
    with pytest.raises(CalibrationError, match=r"no clear echo in the gate 4.000-6.000 ms"):
        calibrate_stage(stage, late_gate, [-0.3, -0.2], sound_speed_mps=c)
