"""Tank model: first-order image sources of a rectangular tank, and the direct blast.

The tank occupies ``0 <= x <= L``, ``0 <= y <= W``, ``-D <= z <= 0``: four walls, the bottom
``z = -D`` and the water surface ``z = 0`` (pressure release, reflection coefficient −1).
Order 1 adds, for each of the six planes, the three echo paths that meet it once per leg or
once in total, built from :class:`~sim_devices.acoustics.trajectory.Mirrored` trajectories
(a moving target's images move with it):

- ``tx → target → image(rx)`` and ``image(tx) → target → rx`` (one reflection, gain R);
- ``tx → image(target) → rx`` (the target seen in the mirror: both legs reflect, gain R²).

Order 0 is the direct echo only. The direct blast is the transmitter-to-receiver leakage: a
one-way path from a transmitter ``separation_m`` away from the receiver with spherical
spreading and a coupling gain (dB).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from hil.errors import ConfigError
from sim_devices.acoustics.trajectory import FloatArray, Mirrored, Trajectory, as_point


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


@dataclass(frozen=True)
class EchoPath:
    """One echo path: transmitter, target, receiver trajectories and a linear gain."""

    name: str
    tx: Trajectory
    target: Trajectory
    rx: Trajectory
    gain: float


def echo_paths(
    sonar: Trajectory, target: Trajectory, tank: Tank | None, order: int
) -> Iterator[EchoPath]:
    """The direct echo and, for ``order >= 1`` in a tank, the first-order image paths.

    >>> from sim_devices.acoustics.trajectory import Fixed
    >>> t = Tank(10.0, 4.0, 3.0)
    >>> [p.name for p in echo_paths(Fixed((1, 2, -1)), Fixed((5, 2, -1)), t, 1)][:4]
    ['direct', 'wall x=0: rx image', 'wall x=0: tx image', 'wall x=0: target image']
    """
    if order not in (0, 1):
        raise ConfigError("tank.image_order", order, "0 or 1", "second order is not implemented")
    yield EchoPath("direct", sonar, target, sonar, 1.0)
    if tank is None or order == 0:
        return
    for name, q, n, r in tank.planes():
        yield EchoPath(f"{name}: rx image", sonar, target, Mirrored(sonar, q, n), r)
        yield EchoPath(f"{name}: tx image", Mirrored(sonar, q, n), target, sonar, r)
        yield EchoPath(f"{name}: target image", sonar, Mirrored(target, q, n), sonar, r * r)


class Offset:
    """A trajectory displaced by a constant vector (m): the transmitter next to a receiver."""

    def __init__(self, inner: Trajectory, offset_m: ArrayLike) -> None:
        self._inner = inner
        self._d = as_point(offset_m, "direct_blast.offset_m")

    @property
    def max_speed_mps(self) -> float | None:
        return self._inner.max_speed_mps

    def position(self, t: ArrayLike) -> FloatArray:
        return self._inner.position(t) + self._d

    def velocity(self, t: ArrayLike) -> FloatArray:
        return self._inner.velocity(t)
