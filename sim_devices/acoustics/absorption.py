"""Absorption of sound in sea water, dB/km, by three published formulas.

Frequencies are in Hz at this API; each published formula works in kHz internally, and the
conversion is done here. Depths are in metres at the API (Ainslie-McColm uses km inside).

- :func:`francois_garrison_absorption`: Francois & Garrison (1982), JASA 72(6) 1879-1890.
  Boric acid + magnesium sulphate relaxations + pure-water viscosity, with temperature,
  salinity, depth and pH. The reference model for this project (arlpy's default).
- :func:`ainslie_mccolm_absorption`: Ainslie & McColm (1998), JASA 103(3) 1671-1672, the
  simplified formula (same three mechanisms, fewer terms). Also what MATLAB's
  ``range2tl``/``tl2range`` use (see :mod:`sim_devices.acoustics.propagation`).
- :func:`thorp_absorption`: Thorp (1967) with the commonly added pure-water and constant
  terms, a function of frequency only (about 4 °C, deep water). Thorp published it in
  dB/kyd; like Stojanovic (2007) and ns-3, this code uses it as dB/km.

All inputs broadcast (numpy rules); a scalar input gives a float.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from sim_devices.acoustics._physics_inputs import (
    FloatOrArray,
    as_float_array,
    check_range,
    checked_frequency,
    scalar_or_array,
)


def francois_garrison_absorption(
    frequency_hz: ArrayLike,
    temperature_c: ArrayLike = 27.0,
    salinity_ppt: ArrayLike = 35.0,
    depth_m: ArrayLike = 10.0,
    ph: ArrayLike = 8.1,
) -> FloatOrArray:
    """Absorption coefficient by Francois & Garrison (1982), dB/km.

    The fit covers about -2 to 22 °C and 30 to 35 ppt over 0.2 kHz to 1 MHz; it is widely
    used outside that (arlpy's default is 27 °C), with larger uncertainty. This function
    accepts -2 to 40 °C, 0 to 45 ppt, 0 to 11000 m and pH 7 to 9. The defaults are arlpy's.

    Parameters
    ----------
    frequency_hz:
        Frequency, Hz (> 0). Converted to kHz for the formula.
    temperature_c:
        Temperature, °C.
    salinity_ppt:
        Salinity, ppt.
    depth_m:
        Depth, m.
    ph:
        Acidity, pH units.

    Examples
    --------
    >>> round(francois_garrison_absorption(50e3), 2)
    10.71
    >>> round(3.0 * francois_garrison_absorption(50e3), 2)   # dB over 3 km
    32.13
    """
    f = checked_frequency(frequency_hz) / 1000.0
    t = as_float_array("temperature_c", temperature_c)
    s = as_float_array("salinity_ppt", salinity_ppt)
    d = as_float_array("depth_m", depth_m)
    acid = as_float_array("ph", ph)
    hint = "inputs beyond the sea-water range this formula is used for"
    check_range("temperature_c", t, -2.0, 40.0, "°C", hint, what="Francois-Garrison")
    check_range("salinity_ppt", s, 0.0, 45.0, "ppt", hint, what="Francois-Garrison")
    check_range("depth_m", d, 0.0, 11000.0, "m", hint, what="Francois-Garrison")
    check_range("ph", acid, 7.0, 9.0, "", hint, what="Francois-Garrison")

    c = 1412.0 + 3.21 * t + 1.19 * s + 0.0167 * d
    # Boric acid relaxation.
    a1 = 8.86 / c * 10.0 ** (0.78 * acid - 5.0)
    f1 = 2.8 * np.sqrt(s / 35.0) * 10.0 ** (4.0 - 1245.0 / (t + 273.0))
    # Magnesium sulphate relaxation.
    a2 = 21.44 * s / c * (1.0 + 0.025 * t)
    p2 = 1.0 - 1.37e-4 * d + 6.2e-9 * d**2
    f2 = 8.17 * 10.0 ** (8.0 - 1990.0 / (t + 273.0)) / (1.0 + 0.0018 * (s - 35.0))
    # Pure-water viscosity: the paper gives two temperature fits, split at 20 °C.
    p3 = 1.0 - 3.83e-5 * d + 4.9e-10 * d**2
    a3 = np.where(
        t <= 20.0,
        4.937e-4 - 2.59e-5 * t + 9.11e-7 * t**2 - 1.50e-8 * t**3,
        3.964e-4 - 1.146e-5 * t + 1.45e-7 * t**2 - 6.5e-10 * t**3,
    )
    f_sq = f**2
    alpha = a1 * f1 * f_sq / (f1**2 + f_sq) + a2 * p2 * f2 * f_sq / (f2**2 + f_sq) + a3 * p3 * f_sq
    return scalar_or_array(np.asarray(alpha, dtype=np.float64))


def ainslie_mccolm_absorption(
    frequency_hz: ArrayLike,
    temperature_c: ArrayLike = 10.0,
    salinity_ppt: ArrayLike = 35.0,
    depth_m: ArrayLike = 0.0,
    ph: ArrayLike = 8.0,
) -> FloatOrArray:
    """Absorption coefficient by Ainslie & McColm (1998), dB/km.

    The authors state the formula is valid for -6 to 35 °C, 5 to 50 ppt, pH 7.7 to 8.3 and
    0 to 7 km depth; inputs outside raise :class:`~hil.errors.ConfigError`.

    Parameters
    ----------
    frequency_hz:
        Frequency, Hz (> 0). Converted to kHz for the formula.
    temperature_c:
        Temperature, °C.
    salinity_ppt:
        Salinity, ppt.
    depth_m:
        Depth, m (the formula uses km: ``z = depth_m / 1000``).
    ph:
        Acidity, pH units.

    Examples
    --------
    >>> round(ainslie_mccolm_absorption(108e3, 11.0, 37.0, 100.0, 8.2), 8)
    39.06447169
    >>> round(ainslie_mccolm_absorption(77.2e3, 4.0, 8.0, 10.0, 7.9), 8)
    7.23171795
    """
    f = checked_frequency(frequency_hz) / 1000.0
    t = as_float_array("temperature_c", temperature_c)
    s = as_float_array("salinity_ppt", salinity_ppt)
    z_km = as_float_array("depth_m", depth_m) / 1000.0
    acid = as_float_array("ph", ph)
    hint = "outside the validity Ainslie & McColm state; use francois_garrison_absorption"
    check_range("temperature_c", t, -6.0, 35.0, "°C", hint, what="Ainslie-McColm 1998")
    check_range("salinity_ppt", s, 5.0, 50.0, "ppt", hint, what="Ainslie-McColm 1998")
    check_range("depth_m", z_km * 1000.0, 0.0, 7000.0, "m", hint, what="Ainslie-McColm 1998")
    check_range("ph", acid, 7.7, 8.3, "", hint, what="Ainslie-McColm 1998")

    f1 = 0.78 * np.sqrt(s / 35.0) * np.exp(t / 26.0)  # boric acid relaxation, kHz
    f2 = 42.0 * np.exp(t / 17.0)  # magnesium sulphate relaxation, kHz
    f_sq = f**2
    boric = 0.106 * f1 * f_sq / (f1**2 + f_sq) * np.exp((acid - 8.0) / 0.56)
    mgso4 = 0.52 * (1.0 + t / 43.0) * (s / 35.0) * f2 * f_sq / (f2**2 + f_sq) * np.exp(-z_km / 6.0)
    water = 0.00049 * f_sq * np.exp(-(t / 27.0 + z_km / 17.0))
    return scalar_or_array(np.asarray(boric + mgso4 + water, dtype=np.float64))


def thorp_absorption(frequency_hz: ArrayLike) -> FloatOrArray:
    """Absorption coefficient by Thorp's formula, dB/km (f in kHz inside).

    ``0.11 f²/(1+f²) + 44 f²/(4100+f²) + 2.75e-4 f² + 0.003`` with f in kHz.

    Examples
    --------
    >>> round(thorp_absorption(2000.0), 5)
    0.13498
    """
    f = checked_frequency(frequency_hz) / 1000.0
    f_sq = f**2
    alpha = 0.11 * f_sq / (1.0 + f_sq) + 44.0 * f_sq / (4100.0 + f_sq) + 2.75e-4 * f_sq + 0.003
    return scalar_or_array(np.asarray(alpha, dtype=np.float64))
