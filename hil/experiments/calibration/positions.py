"""The stage side of the echo-ranging calibrations: the stage protocol and position checks."""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
import numpy.typing as npt

from hil.devices.stage import StageStatus
from hil.errors import ConfigError
from hil.experiments.calibration.device import FloatArray


class PositioningStage(Protocol):
    """What the routines need of a stage (:class:`~hil.devices.grbl.GrblStage` has it).

    Positions are metres in the controller's machine frame (GRBL: ``[-travel, 0]``).
    """

    @property
    def limits(self) -> tuple[float, float]:
        """Soft limits (low, high), m."""
        ...

    def move_to(
        self, x: float, v: float, a: float | None = None, *, wait: bool = True
    ) -> StageStatus:
        """Move to ``x`` (m) at up to ``v`` (m/s) and return when there."""
        ...


def check_positions(
    positions_m: npt.ArrayLike,
    limits: tuple[float, float],
    *,
    minimum: int,
    margin_m: float = 0.0,
    command: str,
) -> FloatArray:
    """The positions (m), sorted ascending, after checking count, spread and limits.

    ``margin_m`` must stay free between every position and the limits (room to approach it
    from either side). Raises :class:`ConfigError` naming the problem and ``command``.

    >>> check_positions([-0.1, -0.3, -0.2], (-0.5, 0.0), minimum=3, command="x")
    array([-0.3, -0.2, -0.1])
    >>> check_positions([], (-0.5, 0.0), minimum=3, command="hil calibrate stage")
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: positions_m = [] is not allowed: must be at least 3 distinct \
stage positions in m; give positions along the travel, e.g. hil calibrate stage \
--positions=-0.4:-0.05:8
    """
    x = np.asarray(positions_m, dtype=np.float64).ravel()
    if np.unique(x).size < minimum:
        raise ConfigError(
            "positions_m",
            x.tolist(),
            f"at least {minimum} distinct stage positions in m",
            f"give positions along the travel, e.g. {command} --positions=-0.4:-0.05:8",
        )
    if not np.all(np.isfinite(x)):
        raise ConfigError("positions_m", x.tolist(), "finite positions in m")
    low, high = limits[0] + margin_m, limits[1] - margin_m
    bad = x[(x < low) | (x > high)]
    if bad.size:
        raise ConfigError(
            "positions_m",
            float(bad[0]),
            f"within [{low:g}, {high:g}] m (the stage's soft limits {limits[0]:g} to "
            f"{limits[1]:g} m, less {margin_m:g} m of overtravel)",
            "GRBL positions are negative: the machine range is [-travel, 0]",
        )
    return np.sort(x)


def check_speed(speed_mps: float) -> float:
    """The move speed (m/s), checked > 0."""
    if not (math.isfinite(speed_mps) and speed_mps > 0):
        raise ConfigError("speed_mps", speed_mps, "a speed > 0 m/s")
    return float(speed_mps)
