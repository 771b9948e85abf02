"""Radiated-noise source spectrum levels of targets, dB re 1 µPa²/Hz at 1 m.

A parametric shape after Ross (1976, *Mechanics of Underwater Noise*) and Urick (1983,
*Principles of Underwater Sound*, ch. 10): above the propeller-cavitation peak the
continuous spectrum falls at about 20 dB per decade (6 dB/octave), below it the spectrum is
taken flat, and the level grows with speed as ``K log10(v / v_ref)`` (Ross's 50-60 log V
for cavitating propellers). Tonals (blade rate, machinery lines) are not modelled.

    L(f, v) = L_1k - slope log10(max(f, f_knee) / 1 kHz) + K log10(v / v_ref)

[R] The preset levels, knees and reference speeds are this project's round-number
reconstructions, within the ranges quoted in those textbooks for a quiet modern submarine,
a medium merchant ship and a high-speed torpedo. They are not published data for any
vessel and not the dissertation's values (its section 2.4 is unavailable); replace them
with measured spectra where they matter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from hil.errors import ConfigError
from sim_devices.acoustics._physics_inputs import (
    FloatOrArray,
    as_float_array,
    check_positive,
    checked_frequency,
    scalar_or_array,
)


@dataclass(frozen=True)
class RadiatedNoiseSpectrum:
    """A target's broadband radiated-noise source spectrum (see the module docstring).

    Attributes
    ----------
    name:
        Label.
    level_at_1khz_db:
        Source spectrum level at 1 kHz and the reference speed, dB re 1 µPa²/Hz at 1 m.
    knee_hz:
        Frequency below which the spectrum is flat, Hz (the cavitation peak).
    slope_db_per_decade:
        Fall-off above the knee, dB per decade of frequency (>= 0).
    reference_speed_mps:
        Speed at which ``level_at_1khz_db`` holds, m/s.
    speed_exponent_db:
        ``K`` in ``K log10(v / v_ref)``, dB per decade of speed.
    """

    name: str
    level_at_1khz_db: float
    knee_hz: float
    slope_db_per_decade: float
    reference_speed_mps: float
    speed_exponent_db: float = 60.0

    def __post_init__(self) -> None:
        check_positive("knee_hz", as_float_array("knee_hz", self.knee_hz), "Hz")
        check_positive(
            "reference_speed_mps",
            as_float_array("reference_speed_mps", self.reference_speed_mps),
            "m/s",
        )
        if not self.slope_db_per_decade >= 0.0:
            raise ConfigError(
                "slope_db_per_decade",
                self.slope_db_per_decade,
                ">= 0 dB/decade",
                "the continuous spectrum falls with frequency",
            )

    def level_db(self, frequency_hz: ArrayLike, speed_mps: float | None = None) -> FloatOrArray:
        """Source spectrum level at ``frequency_hz`` (Hz), dB re 1 µPa²/Hz at 1 m.

        ``speed_mps`` (m/s, > 0) defaults to the reference speed.

        Examples
        --------
        >>> ship = TARGET_PRESETS["surface_ship"]
        >>> round(ship.level_db(10e3), 1)
        125.0
        """
        f = checked_frequency(frequency_hz)
        speed = self.reference_speed_mps if speed_mps is None else speed_mps
        v = as_float_array("speed_mps", speed)
        check_positive("speed_mps", v, "m/s", "the target speed through the water")
        f_eff = np.maximum(f, self.knee_hz)
        level = (
            self.level_at_1khz_db
            - self.slope_db_per_decade * np.log10(f_eff / 1000.0)
            + self.speed_exponent_db * np.log10(v / self.reference_speed_mps)
        )
        return scalar_or_array(np.asarray(level, dtype=np.float64))

    def __call__(self, frequency_hz: ArrayLike) -> FloatOrArray:
        """Level at the reference speed, so a preset can drive a noise generator directly."""
        return self.level_db(frequency_hz)


#: [R] Reconstructed presets (see the module docstring): 1 kHz level at the reference speed.
TARGET_PRESETS: dict[str, RadiatedNoiseSpectrum] = {
    "submarine": RadiatedNoiseSpectrum("submarine", 115.0, 100.0, 20.0, 5.0),
    "surface_ship": RadiatedNoiseSpectrum("surface_ship", 145.0, 100.0, 20.0, 7.5),
    "torpedo": RadiatedNoiseSpectrum("torpedo", 150.0, 500.0, 20.0, 20.0),
}
