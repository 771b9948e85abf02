"""Directivity of one transducer (projector or hydrophone), applied per path direction.

A transducer is a :class:`~sim_devices.acoustics.beam.BeamPattern` (axially symmetric
intensity ``b(θ)``, 1 on the axis) pointed along an axis. Its *pressure* response to a path
leaving (projector) or arriving from (hydrophone) direction ``u`` is ``sqrt(b(θ))`` with
``cos θ = u · axis / |u|``. Three kinds of pattern: omni, the baffled circular piston of
radius ``a`` at frequency ``f`` (:class:`~sim_devices.acoustics.beam.PistonBeam`), or a
measured table (:class:`TableBeam`).

>>> from sim_devices.acoustics.beam import PistonBeam
>>> t = Transducer(PistonBeam(ka=3.0), (1.0, 0.0, 0.0))
>>> t.response(np.array([[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])).round(4)
array([1.   , 0.226, 0.   ])
>>> round(float(TableBeam([0, 90, 180], [0, -20, -40]).intensity(np.pi / 4)), 4)  # -10 dB
0.1
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from hil.errors import ConfigError
from sim_devices.acoustics.beam import (
    BeamPattern,
    OmniBeam,
    TwoWayAmplitudeTable,
    equivalent_two_way_beam_angle,
)
from sim_devices.acoustics.trajectory import FloatArray, as_point


class TableBeam:
    """A measured pattern: levels (dB re the axis, intensity) at angles from the axis (deg,
    0 … 180, increasing), interpolated linearly in dB; 0 dB on the axis is not required.

    >>> float(TableBeam([0, 180], [0, -30]).intensity(np.pi / 2))
    0.03162277660168379
    """

    name = "table"

    def __init__(self, angles_deg: ArrayLike, levels_db: ArrayLike) -> None:
        a = np.asarray(angles_deg, dtype=np.float64).reshape(-1)
        g = np.asarray(levels_db, dtype=np.float64).reshape(-1)
        if a.size < 2 or a.size != g.size:
            raise ConfigError(
                "beam.angles_deg", a.tolist(), "at least 2 angles, one per level in levels_db"
            )
        if not (np.all(np.isfinite(a)) and a[0] == 0.0 and a[-1] == 180.0):
            raise ConfigError("beam.angles_deg", a.tolist(), "from 0 to 180 degrees inclusive")
        if not np.all(np.diff(a) > 0):
            raise ConfigError("beam.angles_deg", a.tolist(), "strictly increasing")
        if not np.all(np.isfinite(g)) or np.any(g > 40.0):
            raise ConfigError("beam.levels_db", g.tolist(), "finite dB values <= 40 dB")
        self.angles_rad = np.deg2rad(a)
        self.levels_db = g

    def intensity(self, theta_rad: ArrayLike) -> FloatArray:
        theta = np.abs(np.asarray(theta_rad, dtype=np.float64))
        return np.asarray(10.0 ** (np.interp(theta, self.angles_rad, self.levels_db) / 10.0))


class Transducer:
    """A pattern pointed along ``axis`` (any length, normalised): :meth:`response` gives the
    pressure response for direction vectors (shape ``(n, 3)``)."""

    def __init__(self, pattern: BeamPattern, axis: ArrayLike) -> None:
        a = as_point(axis, "beam.axis")
        norm = float(np.sqrt(a @ a))
        if norm == 0:
            raise ConfigError("beam.axis", a.tolist(), "a non-zero vector", "e.g. [1, 0, 0]")
        self.pattern = pattern
        self.axis = a / norm
        self.omni = isinstance(pattern, OmniBeam)
        self._table = TwoWayAmplitudeTable(pattern, OmniBeam())

    def response(self, direction: FloatArray) -> FloatArray:
        """``sqrt(b(θ))`` for each row of ``direction`` (shape ``(n, 3)``, any length > 0)."""
        if self.omni:
            return np.ones(direction.shape[0])
        # Per coordinate, not direction @ axis: a BLAS product may round differently for
        # different array lengths, and the echo grid solves nodes in batches.
        dx, dy, dz = direction[:, 0], direction[:, 1], direction[:, 2]
        ax = self.axis
        cos_t = (dx * ax[0] + dy * ax[1] + dz * ax[2]) / np.sqrt(dx * dx + dy * dy + dz * dz)
        return np.asarray(self._table(cos_t), dtype=np.float64)

    def mean_intensity(self) -> float:
        """``(1/4π) ∫ b dΩ``: the mean intensity response over all directions (1 for omni),
        the factor a diffuse field sees."""
        if self.omni:
            return 1.0
        return equivalent_two_way_beam_angle(self.pattern, OmniBeam()) / (4.0 * np.pi)
