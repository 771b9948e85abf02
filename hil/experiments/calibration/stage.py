"""Stage scale and backlash from echo ranging at stage positions, approached both ways.

At every position ``x`` the carriage is first driven ``overtravel_m`` below ``x`` and then to
``x`` (approach moving +x, "up"), the target is ranged, then driven ``overtravel_m`` above
and back to ``x`` ("down"), ranged again. Ranges are ``R = c t / 2`` with the calibrated
sound speed. The model, with one common slope and one intercept per direction, is fitted by
least squares::

    R = s x + a_up    (approached moving +x)
    R = s x + a_down  (approached moving -x)

``scale = |s|`` (metres of carriage travel per commanded metre; exactly as good as c: a c
error of 0.1 % is a scale error of 0.1 %), and ``backlash = sign(s) (a_down - a_up)``: the
carriage position approached from above minus from below, i.e. the mean range difference
between directions, in metres (> 0 for ordinary lost motion). Uncertainties (1 sigma) come
from the fit's residuals.

Applied as :class:`~hil.experiments.calibration.apply.StagePositionCorrection`: the true
carriage position for a command ``x`` reached moving in direction ``d`` (+1 or -1) is
``x_ref + scale (x - x_ref) - d backlash / 2`` around the mean calibrated position ``x_ref``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from hil.errors import ConfigError
from hil.experiments.calibration.positions import (
    PositioningStage,
    check_positions,
    check_speed,
)
from hil.experiments.calibration.ranging import EchoRanger

KIND = "stage"


@dataclass(frozen=True)
class StageResult:
    """Stage scale and backlash.

    Attributes
    ----------
    scale, scale_uncertainty:
        Carriage metres per commanded metre and its 1-sigma uncertainty.
    backlash_m, backlash_uncertainty_m:
        Carriage position approached from above minus from below (m), 1 sigma.
    reference_m:
        Mean commanded position (m): the pivot of the scale correction.
    axis_sign:
        +1 if the range grows with the stage position, -1 otherwise.
    sound_speed_mps:
        c used to turn times of flight into ranges, m/s.
    positions_m, range_up_m, range_down_m:
        Commanded positions and the ranges measured after approaching from below / above.
    residual_rms_m:
        RMS residual of the fit, m.
    overtravel_m:
        How far past each position the stage went before approaching it, m.
    """

    scale: float
    scale_uncertainty: float
    backlash_m: float
    backlash_uncertainty_m: float
    reference_m: float
    axis_sign: int
    sound_speed_mps: float
    positions_m: list[float] = field(default_factory=list)
    range_up_m: list[float] = field(default_factory=list)
    range_down_m: list[float] = field(default_factory=list)
    residual_rms_m: float = 0.0
    overtravel_m: float = 0.0

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (see :meth:`from_json`)."""
        return dict(self.__dict__)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> StageResult:
        """Inverse of :meth:`to_json`."""
        return cls(**d)

    def summary(self) -> list[str]:
        """Human-readable lines for the command line."""
        return [
            f"stage scale: {self.scale:.6f} +- {self.scale_uncertainty:.6f} "
            f"({1e6 * (self.scale - 1):+.0f} ppm) about {self.reference_m:g} m",
            f"backlash: {1e6 * self.backlash_m:.1f} +- {1e6 * self.backlash_uncertainty_m:.1f} "
            f"µm (from above minus from below)",
            f"fit over {len(self.positions_m)} positions x 2 directions: residual "
            f"{1e6 * self.residual_rms_m:.1f} µm RMS; c = {self.sound_speed_mps:.3f} m/s",
        ]


def calibrate_stage(
    stage: PositioningStage,
    ranger: EchoRanger,
    positions_m: npt.ArrayLike,
    *,
    sound_speed_mps: float,
    overtravel_m: float = 0.005,
    speed_mps: float = 0.02,
) -> StageResult:
    """Measure the stage's scale and backlash (see the module docstring).

    Parameters
    ----------
    stage, ranger:
        The stage towing the target along the beam axis and the echo ranger.
    positions_m:
        At least 2 distinct positions (m), each with ``overtravel_m`` of room to the limits.
    sound_speed_mps:
        Calibrated c, m/s (from the temperature: see :mod:`.sound_speed`).
    overtravel_m:
        Distance past each position before approaching it (m); larger than the backlash.
    """
    if not (math.isfinite(overtravel_m) and overtravel_m > 0):
        raise ConfigError("overtravel_m", overtravel_m, "a distance > 0 m", "larger than backlash")
    if not (math.isfinite(sound_speed_mps) and 1000.0 <= sound_speed_mps <= 2000.0):
        raise ConfigError(
            "sound_speed_mps", sound_speed_mps, "in [1000, 2000] m/s", "calibrate it first"
        )
    x = check_positions(
        positions_m, stage.limits, minimum=2, margin_m=overtravel_m,
        command="hil calibrate stage",
    )  # fmt: skip
    v = check_speed(speed_mps)
    up = np.empty_like(x)
    down = np.empty_like(x)
    for i, xi in enumerate(x):
        for sign, out in ((-1.0, up), (1.0, down)):
            stage.move_to(float(xi + sign * overtravel_m), v)
            stage.move_to(float(xi), v)
            out[i] = 0.5 * sound_speed_mps * ranger.measure().time_of_flight_s
    n = x.size
    design = np.zeros((2 * n, 3))
    design[:, 0] = np.concatenate([x, x])
    design[:n, 1] = 1.0
    design[n:, 2] = 1.0
    ranges = np.concatenate([up, down])
    coef, *_ = np.linalg.lstsq(design, ranges, rcond=None)
    resid = ranges - design @ coef
    dof = max(2 * n - 3, 1)
    cov = float(resid @ resid) / dof * np.linalg.inv(design.T @ design)
    slope, a_up, a_down = (float(c) for c in coef)
    sign = 1 if slope >= 0 else -1
    return StageResult(
        scale=abs(slope),
        scale_uncertainty=float(np.sqrt(cov[0, 0])),
        backlash_m=sign * (a_down - a_up),
        backlash_uncertainty_m=float(np.sqrt(max(cov[1, 1] + cov[2, 2] - 2 * cov[1, 2], 0.0))),
        reference_m=float(x.mean()),
        axis_sign=sign,
        sound_speed_mps=float(sound_speed_mps),
        positions_m=x.tolist(),
        range_up_m=up.tolist(),
        range_down_m=down.tolist(),
        residual_rms_m=float(np.sqrt(np.mean(resid**2))),
        overtravel_m=float(overtravel_m),
    )
