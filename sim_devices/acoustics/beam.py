"""Transducer beam patterns and the equivalent two-way beam solid angle Ψ.

A pattern is axially symmetric about the beam axis and given as the *intensity* response
``b(θ)`` (dimensionless, 1 on the axis) against the angle ``θ`` (rad) from the axis; the
pressure (amplitude) response is ``sqrt(b)``. Two shapes:

- :class:`OmniBeam`: ``b = 1`` everywhere (``Ψ = 4π`` sr for a pair of them).
- :class:`PistonBeam`: baffled circular piston of radius ``a`` at wavenumber ``k``:
  ``b(θ) = [2 J1(ka sinθ) / (ka sinθ)]²`` for ``θ < 90°`` and 0 behind the baffle.

The equivalent two-way beam solid angle is ``Ψ = ∫ b_tx(θ) b_rx(θ) dΩ`` (sr), computed here
by numerical integration over ``θ`` (``dΩ = 2π sinθ dθ``); for a piston with ``ka ≫ 1`` it
approaches Urick's ``5.78 / (ka)²``. Volume reverberation uses it in
``V = (cτ/2) Ψ r²``.

Examples
--------
>>> round(equivalent_two_way_beam_angle(OmniBeam(), OmniBeam()) / np.pi, 6)
4.0
>>> piston = PistonBeam(ka=40.0)
>>> round(equivalent_two_way_beam_angle(piston, piston) * 40.0**2, 2)
5.78
"""

from __future__ import annotations

import itertools
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import quad
from scipy.special import j1

from hil.errors import ConfigError
from sim_devices.acoustics.trajectory import FloatArray

#: Points of the amplitude table in cos θ used on the hot path (linear interpolation).
TABLE_POINTS = 8193


@runtime_checkable
class BeamPattern(Protocol):
    """Axially symmetric intensity pattern ``b(θ)`` (1 on the axis), θ in rad."""

    def intensity(self, theta_rad: ArrayLike) -> FloatArray: ...

    @property
    def name(self) -> str: ...


class OmniBeam:
    """Omnidirectional: ``b(θ) = 1``."""

    name = "omni"

    def intensity(self, theta_rad: ArrayLike) -> FloatArray:
        return np.ones(np.shape(theta_rad))


class PistonBeam:
    """Baffled circular piston, ``ka`` = 2π a / λ (> 0); zero response for θ >= 90°.

    >>> round(float(PistonBeam(ka=10.0).intensity(0.0)), 12)
    1.0
    """

    name = "piston"

    def __init__(self, ka: float) -> None:
        if not (np.isfinite(ka) and ka > 0):
            raise ConfigError("beam.ka", ka, "> 0 (ka = 2π·radius/wavelength)")
        self.ka = float(ka)

    @classmethod
    def from_radius(
        cls, radius_m: float, frequency_hz: float, sound_speed_mps: float
    ) -> PistonBeam:
        """Piston of radius ``radius_m`` (m) at ``frequency_hz`` (Hz) in water of speed c (m/s)."""
        if not (np.isfinite(radius_m) and radius_m > 0):
            raise ConfigError("beam.radius_m", radius_m, "> 0 m")
        return cls(2.0 * np.pi * radius_m * frequency_hz / sound_speed_mps)

    def intensity(self, theta_rad: ArrayLike) -> FloatArray:
        theta = np.asarray(theta_rad, dtype=np.float64)
        x = self.ka * np.sin(theta)
        with np.errstate(invalid="ignore", divide="ignore"):
            d = np.where(np.abs(x) < 1e-8, 1.0, 2.0 * j1(x) / x)
        return np.where(np.cos(theta) > 0, d * d, 0.0)


def _pattern_key(pattern: BeamPattern) -> tuple[str, float] | None:
    """What fixes a built-in pattern's response (None for any other pattern)."""
    if type(pattern) is OmniBeam:
        return ("omni", 0.0)
    if type(pattern) is PistonBeam:
        return ("piston", pattern.ka)
    return None


#: Ψ per pair of built-in patterns: the quadrature costs tens of milliseconds, and every
#: simulated tank (the run's, its background's, its level plan's) asks for the same pairs.
_BEAM_ANGLES: dict[tuple[tuple[str, float], tuple[str, float]], float] = {}


def equivalent_two_way_beam_angle(tx: BeamPattern, rx: BeamPattern) -> float:
    """``Ψ = 2π ∫₀^π b_tx(θ) b_rx(θ) sinθ dθ`` in steradians (adaptive quadrature; kept per
    pair of built-in patterns, the same value)."""
    tx_key, rx_key = _pattern_key(tx), _pattern_key(rx)
    if tx_key is None or rx_key is None:
        return _beam_angle(tx, rx)
    key = (tx_key, rx_key)
    if key not in _BEAM_ANGLES:
        _BEAM_ANGLES[key] = _beam_angle(tx, rx)
    return _BEAM_ANGLES[key]


def _beam_angle(tx: BeamPattern, rx: BeamPattern) -> float:
    def integrand(theta: float) -> float:
        return float(tx.intensity(theta) * rx.intensity(theta) * np.sin(theta))

    # Split at the baffle plane and use many sub-intervals: piston side lobes oscillate.
    total = 0.0
    edges = np.linspace(0.0, np.pi, 65)
    for lo, hi in itertools.pairwise(edges):
        part, _ = quad(integrand, float(lo), float(hi), limit=200, epsabs=1e-13, epsrel=1e-10)
        total += part
    return 2.0 * np.pi * total


class TwoWayAmplitudeTable:
    """Two-way *pressure* response ``sqrt(b_tx b_rx)`` tabulated against ``cos θ``.

    ``__call__(cos_theta)`` (shape ``(n,)``) interpolates linearly in a table of
    :data:`TABLE_POINTS` points: cheap enough for 10^5 scatterers per frame.
    """

    def __init__(self, tx: BeamPattern, rx: BeamPattern, points: int = TABLE_POINTS) -> None:
        self._cos = np.linspace(-1.0, 1.0, points)
        theta = np.arccos(self._cos)
        self._amp = np.sqrt(tx.intensity(theta) * rx.intensity(theta))
        self._slope = np.append(np.diff(self._amp), 0.0)
        self._scale = (points - 1) / 2.0
        #: The table's values as bytes: equal keys, equal responses.
        self.key = self._amp.tobytes()

    def __call__(self, cos_theta: FloatArray) -> FloatArray:
        # Uniform grid: the index is arithmetic (np.interp's binary search is 5x slower).
        pos = (np.clip(cos_theta, -1.0, 1.0) + 1.0) * self._scale
        i = np.minimum(pos.astype(np.int64), self._amp.shape[0] - 2)
        frac = pos - i
        return self._amp[i] + frac * self._slope[i]

    def cutoff_cos(self, floor_db: float) -> float:
        """Smallest ``cos θ`` beyond which the two-way response stays below ``floor_db`` (dB)."""
        level = 20.0 * np.log10(np.maximum(self._amp, 1e-300))
        above = np.flatnonzero(level > floor_db)
        return float(self._cos[above[0]]) if above.size else 1.0
