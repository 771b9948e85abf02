"""Sound speed of the tank water: from its temperature, or from echo time of flight.

From temperature (and optionally salinity): fresh water (no salinity, or 0) uses Marczak
(1997), :func:`sim_devices.acoustics.sound_speed.tank_sound_speed`, valid 0-95 °C; with a
salinity, Mackenzie (1981), valid 2-30 °C, 25-40 ppt. Each refuses inputs outside its range.
The uncertainty is ``|dc/dT|`` times the temperature uncertainty (about 3 m/s per °C at
20 °C: a 0.3 °C thermometer error is already 0.067 %).

From time of flight: a target on the stage carriage is echo-ranged at several stage
positions ``x_i`` visited in ascending order (so any backlash is the same constant offset at
every position). Along the beam axis the two-way time is ``t_i = a + b x_i`` with ``b = +-2/c``;
a least-squares line gives ``c = 2/|b|`` with ``sigma_c = 2 sigma_b / b^2`` and the fixed offset
``c a / 2`` (the range at ``x = 0`` plus any uncompensated latency, m). This assumes the
stage's scale is exact: the fit only sees ``c / scale``, so calibrate the stage scale
against a temperature-based c, or c against a stage of known scale, not both at once.
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

KIND = "sound-speed"


def sound_speed_from_temperature(
    temperature_c: float, salinity_ppt: float | None = None, depth_m: float = 0.0
) -> tuple[float, str]:
    """Sound speed (m/s) and the formula's name for the water temperature (°C).

    >>> c, formula = sound_speed_from_temperature(20.0)
    >>> round(c, 2), formula
    (1482.38, 'Marczak 1997 (fresh water)')
    >>> round(sound_speed_from_temperature(27.0, 35.0, 10.0)[0], 1)
    1539.1
    """
    from sim_devices.acoustics.sound_speed import mackenzie_sound_speed, tank_sound_speed

    if salinity_ppt is None or salinity_ppt == 0:
        return float(tank_sound_speed(temperature_c)), "Marczak 1997 (fresh water)"
    c = mackenzie_sound_speed(temperature_c, salinity_ppt, depth_m)
    return float(c), "Mackenzie 1981 (sea water)"


@dataclass(frozen=True)
class SoundSpeedResult:
    """A sound-speed calibration.

    Attributes
    ----------
    sound_speed_mps, uncertainty_mps:
        c and its standard uncertainty (1 sigma), m/s.
    method:
        ``"temperature"`` or ``"time-of-flight"``.
    formula:
        The formula used (temperature method, or the cross-check of the time-of-flight one).
    temperature_c, salinity_ppt:
        The water's temperature (°C) and salinity (ppt) when given.
    temperature_sound_speed_mps:
        c from the temperature, as a cross-check of a time-of-flight result, m/s.
    positions_m, time_of_flight_s:
        Stage positions (m) and measured two-way times (s) of the time-of-flight method.
    offset_m:
        Fixed offset of the fit: the range at stage position 0 plus uncompensated latency, m.
    residual_rms_s:
        RMS residual of the time-of-flight line, s.
    """

    sound_speed_mps: float
    uncertainty_mps: float
    method: str
    formula: str = ""
    temperature_c: float | None = None
    salinity_ppt: float | None = None
    temperature_sound_speed_mps: float | None = None
    positions_m: list[float] = field(default_factory=list)
    time_of_flight_s: list[float] = field(default_factory=list)
    offset_m: float | None = None
    residual_rms_s: float | None = None

    @property
    def relative_uncertainty(self) -> float:
        """``uncertainty / c`` (dimensionless)."""
        return self.uncertainty_mps / self.sound_speed_mps

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (see :meth:`from_json`)."""
        return dict(self.__dict__)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SoundSpeedResult:
        """Inverse of :meth:`to_json`."""
        return cls(**d)

    def summary(self) -> list[str]:
        """Human-readable lines for the command line."""
        lines = [
            f"sound speed: {self.sound_speed_mps:.3f} m/s +- {self.uncertainty_mps:.3f} m/s "
            f"({100 * self.relative_uncertainty:.4f} %, 1 sigma) by {self.method}"
        ]
        if self.temperature_c is not None:
            salt = "" if self.salinity_ppt is None else f", {self.salinity_ppt:g} ppt"
            lines.append(f"water: {self.temperature_c:g} °C{salt}; formula {self.formula}")
        if self.method == "time-of-flight":
            assert self.offset_m is not None and self.residual_rms_s is not None
            lines.append(
                f"fit over {len(self.positions_m)} stage positions: offset {self.offset_m:.5f}"
                f" m, residual {1e9 * self.residual_rms_s:.1f} ns RMS"
            )
            if self.temperature_sound_speed_mps is not None:
                diff = self.sound_speed_mps - self.temperature_sound_speed_mps
                lines.append(
                    f"cross-check: {self.temperature_sound_speed_mps:.3f} m/s from the "
                    f"temperature ({diff:+.3f} m/s, {100 * diff / self.sound_speed_mps:+.4f} %)"
                )
        return lines


def calibrate_sound_speed_temperature(
    temperature_c: float,
    *,
    salinity_ppt: float | None = None,
    depth_m: float = 0.0,
    temperature_uncertainty_c: float = 0.1,
) -> SoundSpeedResult:
    """Sound speed from the water temperature (see the module docstring).

    Examples
    --------
    >>> r = calibrate_sound_speed_temperature(20.0)
    >>> round(r.sound_speed_mps, 2), round(r.uncertainty_mps, 3)
    (1482.38, 0.307)
    >>> calibrate_sound_speed_temperature(-5.0)
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: temperature_c = -5.0 is not allowed: must be 0 to 95 °C \
(Marczak 1997); Marczak (1997) covers liquid water at 1 atm; for sea water use \
unesco_sound_speed
    """
    if not (math.isfinite(temperature_uncertainty_c) and temperature_uncertainty_c >= 0):
        raise ConfigError("temperature_uncertainty_c", temperature_uncertainty_c, ">= 0 °C")
    c, formula = sound_speed_from_temperature(temperature_c, salinity_ppt, depth_m)
    # Central difference inside the formula's range (one-sided at its edges).
    step = 0.05
    try:
        up = sound_speed_from_temperature(temperature_c + step, salinity_ppt, depth_m)[0]
    except ConfigError:
        up, step_up = c, 0.0
    else:
        step_up = step
    try:
        down = sound_speed_from_temperature(temperature_c - step, salinity_ppt, depth_m)[0]
    except ConfigError:
        down, step_down = c, 0.0
    else:
        step_down = step
    slope = (up - down) / (step_up + step_down)
    return SoundSpeedResult(
        sound_speed_mps=c,
        uncertainty_mps=abs(slope) * temperature_uncertainty_c,
        method="temperature",
        formula=formula,
        temperature_c=float(temperature_c),
        salinity_ppt=None if salinity_ppt is None else float(salinity_ppt),
    )


def fit_line(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float, float, float]:
    """Least-squares ``y = a + b x``: (a, b, sigma_a, sigma_b, rms residual).

    >>> a, b, sa, sb, rms = fit_line(np.array([0.0, 1, 2, 3]), np.array([1.0, 3, 5, 7]))
    >>> round(a, 9), round(b, 9), round(rms, 9)
    (1.0, 2.0, 0.0)
    """
    design = np.stack([np.ones_like(x), x], axis=1)
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    resid = y - design @ coef
    dof = max(x.size - 2, 1)
    cov = float(resid @ resid) / dof * np.linalg.inv(design.T @ design)
    rms = float(np.sqrt(np.mean(resid**2)))
    return float(coef[0]), float(coef[1]), float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1])), rms


def calibrate_sound_speed_tof(
    stage: PositioningStage,
    ranger: EchoRanger,
    positions_m: npt.ArrayLike,
    *,
    speed_mps: float = 0.02,
    temperature_c: float | None = None,
    salinity_ppt: float | None = None,
) -> SoundSpeedResult:
    """Sound speed from echo times of flight at stage positions (see the module docstring).

    Parameters
    ----------
    stage:
        Tows the target along the beam axis.
    ranger:
        Times the target's echo.
    positions_m:
        At least 3 distinct stage positions within the soft limits, m; visited ascending.
        Spread them over the travel: the slope's uncertainty falls with their spread.
    speed_mps:
        Move speed, m/s.
    temperature_c, salinity_ppt:
        When given, c from the temperature is reported as a cross-check.
    """
    x = check_positions(
        positions_m, stage.limits, minimum=3, command="hil calibrate sound-speed --method tof"
    )
    v = check_speed(speed_mps)
    tof = np.empty_like(x)
    for i, xi in enumerate(x):
        stage.move_to(float(xi), v)
        tof[i] = ranger.measure().time_of_flight_s
    a, b, _, sb, rms = fit_line(x, tof)
    if b == 0:
        raise ConfigError("positions_m", x.tolist(), "positions where the echo moves")
    c = 2.0 / abs(b)
    cross = None
    formula = ""
    if temperature_c is not None:
        cross, formula = sound_speed_from_temperature(temperature_c, salinity_ppt)
    return SoundSpeedResult(
        sound_speed_mps=c,
        uncertainty_mps=2.0 * sb / (b * b),
        method="time-of-flight",
        formula=formula,
        temperature_c=temperature_c,
        salinity_ppt=salinity_ppt,
        temperature_sound_speed_mps=cross,
        positions_m=x.tolist(),
        time_of_flight_s=tof.tolist(),
        offset_m=c * a / 2.0,
        residual_rms_s=rms,
    )
