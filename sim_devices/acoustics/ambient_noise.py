"""Ambient-noise spectrum level of the sea, dB re 1 µPa²/Hz, and receiver self-noise.

The four-component empirical model of Coates (1989) as given by Stojanovic (2007, "On the
relationship between capacity and distance in an underwater acoustic communication
channel") and used by ns-3's ``UanNoiseModelDefault``. With f in kHz (the formulas' unit;
this API takes Hz and converts), wind speed w in m/s and shipping activity s in [0, 1]:

    turbulence  17 - 30 log10 f
    shipping    40 + 20 (s - 0.5) + 26 log10 f - 60 log10(f + 0.03)
    wind        50 + 7.5 sqrt(w) + 20 log10 f - 40 log10(f + 0.4)
    thermal     -15 + 20 log10 f

and the total is their power sum. Sea state maps to wind speed through
:data:`SEA_STATE_TABLE`. A receiver's self-noise (a flat spectrum level, dB re 1 µPa²/Hz)
adds in power.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from hil.errors import ConfigError
from sim_devices.acoustics._physics_inputs import (
    FloatArray,
    FloatOrArray,
    as_float_array,
    check_non_negative,
    check_range,
    checked_frequency,
    scalar_or_array,
)


def power_sum_db(*levels_db: ArrayLike) -> FloatOrArray:
    """Power sum of levels in dB: ``10 log10(sum 10**(L/10))`` (same reference in, out).

    Examples
    --------
    >>> round(power_sum_db(60.0, 60.0), 2)
    63.01
    """
    arrays = [as_float_array("levels_db", level) for level in levels_db]
    stacked = np.broadcast_arrays(*arrays)
    total = np.zeros(stacked[0].shape, dtype=np.float64)
    for level in stacked:
        total = total + 10.0 ** (level / 10.0)
    return scalar_or_array(np.asarray(10.0 * np.log10(total), dtype=np.float64))


def _khz(frequency_hz: ArrayLike) -> FloatArray:
    return checked_frequency(frequency_hz) / 1000.0


def turbulence_noise_level(frequency_hz: ArrayLike) -> FloatOrArray:
    """Turbulence component, dB re 1 µPa²/Hz: ``17 - 30 log10 f``.

    ``frequency_hz`` in Hz (> 0, any shape); the formula's f is in kHz.

    Examples
    --------
    >>> round(turbulence_noise_level(1000.0), 1)
    17.0
    """
    f = _khz(frequency_hz)
    return scalar_or_array(17.0 - 30.0 * np.log10(f))


def shipping_noise_level(frequency_hz: ArrayLike, shipping: float = 0.5) -> FloatOrArray:
    """Distant-shipping component, dB re 1 µPa²/Hz.

    ``frequency_hz`` in Hz (> 0, any shape); the formula's f is in kHz. ``shipping`` is the
    activity factor, 0 (none) to 1 (heavy).
    """
    f = _khz(frequency_hz)
    s = as_float_array("shipping", shipping)
    check_range("shipping", s, 0.0, 1.0, "", "the shipping activity factor is 0 (none) to 1")
    return scalar_or_array(40.0 + 20.0 * (s - 0.5) + 26.0 * np.log10(f) - 60.0 * np.log10(f + 0.03))


def wind_noise_level(frequency_hz: ArrayLike, wind_speed_mps: float) -> FloatOrArray:
    """Surface-agitation (wind) component, dB re 1 µPa²/Hz.

    ``frequency_hz`` in Hz (> 0, any shape; the formula's f is in kHz); ``wind_speed_mps``
    in m/s at 10 m height.
    """
    f = _khz(frequency_hz)
    w = as_float_array("wind_speed_mps", wind_speed_mps)
    check_non_negative("wind_speed_mps", w, "m/s", "wind speed at 10 m height, in m/s")
    return scalar_or_array(50.0 + 7.5 * np.sqrt(w) + 20.0 * np.log10(f) - 40.0 * np.log10(f + 0.4))


def thermal_noise_level(frequency_hz: ArrayLike) -> FloatOrArray:
    """Molecular-agitation (thermal) component, dB re 1 µPa²/Hz: ``-15 + 20 log10 f``.

    ``frequency_hz`` in Hz (> 0, any shape); the formula's f is in kHz.

    Examples
    --------
    >>> round(thermal_noise_level(100e3), 1)
    25.0
    """
    f = _khz(frequency_hz)
    return scalar_or_array(-15.0 + 20.0 * np.log10(f))


def ambient_noise_level(
    frequency_hz: ArrayLike,
    wind_speed_mps: float = 5.0,
    shipping: float = 0.5,
    self_noise_db: float | None = None,
) -> FloatOrArray:
    """Total ambient-noise spectrum level, dB re 1 µPa²/Hz: the power sum of the components.

    Parameters
    ----------
    frequency_hz:
        Frequency, Hz (> 0); any shape.
    wind_speed_mps:
        Wind speed at 10 m, m/s (see :func:`sea_state_wind_speed`).
    shipping:
        Shipping activity factor, 0 to 1.
    self_noise_db:
        Optional flat receiver self-noise spectrum level, dB re 1 µPa²/Hz, added in power.

    Examples
    --------
    >>> [round(ambient_noise_level(f), 1) for f in (1e3, 10e3, 30e3, 50e3, 100e3)]
    [61.0, 46.1, 37.0, 32.8, 28.9]
    """
    parts = [
        turbulence_noise_level(frequency_hz),
        shipping_noise_level(frequency_hz, shipping),
        wind_noise_level(frequency_hz, wind_speed_mps),
        thermal_noise_level(frequency_hz),
    ]
    if self_noise_db is not None:
        parts.append(flat_self_noise_level(frequency_hz, self_noise_db))
    return power_sum_db(*parts)


def flat_self_noise_level(frequency_hz: ArrayLike, self_noise_db: float) -> FloatOrArray:
    """Receiver self-noise: the same spectrum level at every frequency, dB re 1 µPa²/Hz.

    ``frequency_hz`` in Hz (> 0) sets the output shape; ``self_noise_db`` is the level.

    The level is the hydrophone-plus-preamplifier equivalent noise referred to the water
    (from the data sheet or a measurement in a quiet tank).
    """
    f = checked_frequency(frequency_hz)
    level = as_float_array("self_noise_db", self_noise_db)
    return scalar_or_array(np.asarray(np.broadcast_to(level, f.shape) + 0.0, dtype=np.float64))


@dataclass(frozen=True)
class SeaState:
    """One row of :data:`SEA_STATE_TABLE`.

    ``wave_height_m`` is the WMO code 3700 band (m, upper bound ``inf`` for code 9);
    ``wind_mps`` the matching wind-speed band (m/s at 10 m); ``nominal_wind_mps`` the value
    :func:`sea_state_wind_speed` returns (band centre, lower bound for code 9).
    """

    code: int
    description: str
    wave_height_m: tuple[float, float]
    beaufort: tuple[int, int]
    wind_mps: tuple[float, float]

    @property
    def nominal_wind_mps(self) -> float:
        low, high = self.wind_mps
        return low if high == float("inf") else 0.5 * (low + high)


_INF = float("inf")

#: WMO sea-state code (code table 3700, WMO-No. 306 Manual on Codes: wave-height bands and
#: descriptions) joined to wind speed through the WMO Beaufort scale (WMO-No. 8 / the
#: Manual on Marine Meteorological Services: wind-speed band and "probable wave height" of
#: each force). A sea state takes the Beaufort forces whose probable wave height falls in
#: its band (0 m -> force 0; 0.1 -> 1; 0.2 -> 2; 0.6, 1 -> 3-4; 2 -> 5; 3, 4 -> 6-7; 5.5 -> 8;
#: 7, 9 -> 9-10; 11.5 -> 11; 14 and over -> 12). [R] The join is this project's
#: reconstruction for a fully developed wind sea; the dissertation's Table 2.1 is not
#: available, and swell makes real wave height a poor proxy for wind.
SEA_STATE_TABLE: tuple[SeaState, ...] = (
    SeaState(0, "calm (glassy)", (0.0, 0.0), (0, 0), (0.0, 0.2)),
    SeaState(1, "calm (rippled)", (0.0, 0.1), (1, 1), (0.3, 1.5)),
    SeaState(2, "smooth (wavelets)", (0.1, 0.5), (2, 2), (1.6, 3.3)),
    SeaState(3, "slight", (0.5, 1.25), (3, 4), (3.4, 7.9)),
    SeaState(4, "moderate", (1.25, 2.5), (5, 5), (8.0, 10.7)),
    SeaState(5, "rough", (2.5, 4.0), (6, 7), (10.8, 17.1)),
    SeaState(6, "very rough", (4.0, 6.0), (8, 8), (17.2, 20.7)),
    SeaState(7, "high", (6.0, 9.0), (9, 10), (20.8, 28.4)),
    SeaState(8, "very high", (9.0, 14.0), (11, 11), (28.5, 32.6)),
    SeaState(9, "phenomenal", (14.0, _INF), (12, 12), (32.7, _INF)),
)


def sea_state(code: int) -> SeaState:
    """The :data:`SEA_STATE_TABLE` row of a WMO sea-state code (integer 0 to 9)."""
    if isinstance(code, bool) or not isinstance(code, int | np.integer) or not 0 <= code <= 9:
        raise ConfigError(
            "sea_state",
            code,
            "an integer WMO sea-state code 0 to 9",
            "0 is glassy calm, 3 slight, 6 very rough, 9 phenomenal",
        )
    return SEA_STATE_TABLE[int(code)]


def sea_state_wind_speed(code: int) -> float:
    """Nominal wind speed of a WMO sea state, m/s at 10 m (see :data:`SEA_STATE_TABLE`).

    Examples
    --------
    >>> sea_state_wind_speed(3)
    5.65
    """
    return sea_state(code).nominal_wind_mps


@dataclass(frozen=True)
class AmbientNoiseModel:
    """The total ambient noise of a place, callable as ``model(frequency_hz) -> dB``.

    Attributes
    ----------
    wind_speed_mps:
        Wind speed at 10 m, m/s.
    shipping:
        Shipping activity factor, 0 to 1.
    self_noise_db:
        Optional flat receiver self-noise, dB re 1 µPa²/Hz.

    Examples
    --------
    >>> model = AmbientNoiseModel.from_sea_state(2, shipping=0.5)
    >>> round(model.wind_speed_mps, 2)
    2.45
    """

    wind_speed_mps: float = 5.0
    shipping: float = 0.5
    self_noise_db: float | None = None

    def __post_init__(self) -> None:
        check_non_negative(
            "wind_speed_mps", as_float_array("wind_speed_mps", self.wind_speed_mps), "m/s"
        )
        s = as_float_array("shipping", self.shipping)
        check_range("shipping", s, 0.0, 1.0, "", "the shipping activity factor is 0 (none) to 1")
        if self.self_noise_db is not None:
            as_float_array("self_noise_db", self.self_noise_db)

    @classmethod
    def from_sea_state(
        cls, code: int, shipping: float = 0.5, self_noise_db: float | None = None
    ) -> AmbientNoiseModel:
        """The model for a WMO sea-state code (wind speed from :data:`SEA_STATE_TABLE`)."""
        return cls(sea_state_wind_speed(code), shipping, self_noise_db)

    def __call__(self, frequency_hz: ArrayLike) -> FloatOrArray:
        """Spectrum level at ``frequency_hz`` (Hz), dB re 1 µPa²/Hz."""
        return ambient_noise_level(
            frequency_hz, self.wind_speed_mps, self.shipping, self.self_noise_db
        )
