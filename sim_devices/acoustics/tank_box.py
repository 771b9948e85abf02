"""The tank's box: a rectangular tank's size (m) and its boundaries' pressure reflection
coefficients (linear), with the checks every user of the geometry shares.

The water fills ``0 <= x <= L``, ``0 <= y <= W``, ``-D <= z <= 0``: four walls, the bottom
``z = -D`` and the water surface ``z = 0`` (pressure release, reflection coefficient −1).
Its image sources are :func:`sim_devices.acoustics.images.box_images`; the echo paths through
it, :mod:`sim_devices.acoustics.tank`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from hil.errors import ConfigError
from sim_devices.acoustics.trajectory import FloatArray, as_point


@dataclass(frozen=True)
class Tank:
    """A rectangular tank, metres; reflection coefficients (linear, |R| <= 1)."""

    length_m: float
    width_m: float
    depth_m: float
    wall_reflection: float = 0.9
    bottom_reflection: float = 0.9
    surface_reflection: float = -1.0

    def __post_init__(self) -> None:
        for name in ("length_m", "width_m", "depth_m"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"tank.{name}", v, "> 0 m")
        for name in ("wall_reflection", "bottom_reflection", "surface_reflection"):
            v = getattr(self, name)
            if not (np.isfinite(v) and -1 <= v <= 1):
                raise ConfigError(f"tank.{name}", v, "between -1 and 1")

    def planes(self) -> list[tuple[str, FloatArray, FloatArray, float]]:
        """(name, point on the plane, normal, reflection coefficient) of each boundary."""
        L, W, D = self.length_m, self.width_m, self.depth_m
        rw, rb, rs = self.wall_reflection, self.bottom_reflection, self.surface_reflection
        e = np.eye(3)
        return [
            ("wall x=0", np.zeros(3), e[0], rw),
            ("wall x=L", np.array([L, 0, 0.0]), e[0], rw),
            ("wall y=0", np.zeros(3), e[1], rw),
            ("wall y=W", np.array([0, W, 0.0]), e[1], rw),
            ("bottom", np.array([0, 0, -D]), e[2], rb),
            ("surface", np.zeros(3), e[2], rs),
        ]

    def contains(self, point: ArrayLike) -> bool:
        """True when ``point`` (m) is inside the water."""
        p = as_point(point, "point")
        return bool(
            0 <= p[0] <= self.length_m and 0 <= p[1] <= self.width_m and -self.depth_m <= p[2] <= 0
        )

    def check_inside(self, point: ArrayLike, field: str) -> None:
        """Raise :class:`ConfigError` naming ``field`` unless ``point`` is in the water."""
        p = as_point(point, field)
        if not self.contains(p):
            raise ConfigError(
                field,
                [float(v) for v in p],
                f"inside the tank: 0 <= x <= {self.length_m}, 0 <= y <= {self.width_m}, "
                f"-{self.depth_m} <= z <= 0 m",
                "move it into the water or enlarge [tank].size_m",
            )
