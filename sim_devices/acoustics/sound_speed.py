"""Speed of sound in sea water and in fresh (tank) water, m/s.

Three published formulas, each refusing inputs outside the range it was fitted on:

- :func:`mackenzie_sound_speed`: Mackenzie (1981), JASA 70(3) 807-812. Sea water only:
  2-30 °C, 25-40 ppt, 0-8000 m depth. Standard error about 0.07 m/s.
- :func:`unesco_sound_speed`: Chen & Millero (1977) as coded in the UNESCO algorithm
  (Fofonoff & Millard 1983, UNESCO Tech. Pap. Mar. Sci. 44, function SVEL): 0-40 °C
  (IPTS-68), 0-40 practical salinity, 0-10000 dbar sea pressure. Covers fresh water (S = 0).
- :func:`fresh_water_sound_speed` / :func:`tank_sound_speed`: Marczak (1997), pure water at
  atmospheric pressure, 0-95 °C (ITS-90).

A 1 m/s error in c biases range by 0.067 %, more than the Cramér-Rao bound at 20 dB E/N0, so a
tank run must log the water temperature and use the fresh-water formula, not Mackenzie.

All inputs broadcast (numpy rules); a scalar input gives a float, an array input an array of
the broadcast shape.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from sim_devices.acoustics._physics_inputs import (
    FloatOrArray,
    as_float_array,
    check_range,
    scalar_or_array,
)

_MACKENZIE_HINT = (
    "Mackenzie (1981) is fitted to sea water only; use unesco_sound_speed (0-40 °C, 0-40 psu, "
    "0-10000 dbar) or, for a fresh-water tank, tank_sound_speed / fresh_water_sound_speed"
)


def mackenzie_sound_speed(
    temperature_c: ArrayLike, salinity_ppt: ArrayLike, depth_m: ArrayLike
) -> FloatOrArray:
    """Sound speed in sea water by Mackenzie's nine-term equation (1981), m/s.

    Parameters
    ----------
    temperature_c:
        Temperature, °C, valid 2 to 30.
    salinity_ppt:
        Salinity, ppt (parts per thousand), valid 25 to 40.
    depth_m:
        Depth below the surface, m, valid 0 to 8000.

    Raises
    ------
    ConfigError
        Any input outside its validity range; the hint names the formula to use instead.

    Examples
    --------
    >>> round(mackenzie_sound_speed(27.0, 35.0, 10.0), 1)
    1539.1
    >>> round(mackenzie_sound_speed(25.0, 35.0, 20.0), 1)
    1534.6
    """
    t = as_float_array("temperature_c", temperature_c)
    s = as_float_array("salinity_ppt", salinity_ppt)
    d = as_float_array("depth_m", depth_m)
    check_range("temperature_c", t, 2.0, 30.0, "°C", _MACKENZIE_HINT, what="Mackenzie 1981")
    check_range("salinity_ppt", s, 25.0, 40.0, "ppt", _MACKENZIE_HINT, what="Mackenzie 1981")
    check_range("depth_m", d, 0.0, 8000.0, "m", _MACKENZIE_HINT, what="Mackenzie 1981")
    c = (
        1448.96
        + 4.591 * t
        - 5.304e-2 * t**2
        + 2.374e-4 * t**3
        + 1.340 * (s - 35.0)
        + 1.630e-2 * d
        + 1.675e-7 * d**2
        - 1.025e-2 * t * (s - 35.0)
        - 7.139e-13 * t * d**3
    )
    return scalar_or_array(np.asarray(c, dtype=np.float64))


def unesco_sound_speed(
    salinity_psu: ArrayLike, temperature_c68: ArrayLike, pressure_dbar: ArrayLike
) -> FloatOrArray:
    """Sound speed in sea water by Chen & Millero (1977), UNESCO algorithm SVEL, m/s.

    Coded from the FORTRAN listing of Fofonoff & Millard (1983), whose check value is
    1731.995 m/s at S = 40, T = 40 °C (IPTS-68), P = 10000 dbar. Note the S² coefficient
    ``-7.9836e-6``: a common transcription slip (``-7.8936e-6``) gives 1732.139 instead.

    Parameters
    ----------
    salinity_psu:
        Practical salinity (PSS-78), valid 0 to 40. S = 0 gives pure water.
    temperature_c68:
        Temperature on the IPTS-68 scale, °C, valid 0 to 40. (ITS-90 reads about 0.024 %
        lower: T68 = 1.00024 T90.)
    pressure_dbar:
        Sea pressure (gauge, zero at the surface), dbar, valid 0 to 10000. Roughly 1 dbar
        per metre of depth.

    Examples
    --------
    >>> round(unesco_sound_speed(40.0, 40.0, 10000.0), 3)
    1731.995
    """
    s = as_float_array("salinity_psu", salinity_psu)
    t = as_float_array("temperature_c68", temperature_c68)
    p0 = as_float_array("pressure_dbar", pressure_dbar)
    hint = "Chen-Millero/UNESCO is fitted to this range only"
    check_range("salinity_psu", s, 0.0, 40.0, "psu", hint, what="UNESCO 1983")
    check_range("temperature_c68", t, 0.0, 40.0, "°C", hint, what="UNESCO 1983")
    check_range("pressure_dbar", p0, 0.0, 10000.0, "dbar", hint, what="UNESCO 1983")
    p = p0 / 10.0  # the fit is in bars
    sr = np.sqrt(s)
    d = 1.727e-3 - 7.9836e-6 * p
    b1 = 7.3637e-5 + 1.7945e-7 * t
    b0 = -1.922e-2 - 4.42e-5 * t
    b = b0 + b1 * p
    a3 = (-3.389e-13 * t + 6.649e-12) * t + 1.100e-10
    a2 = ((7.988e-12 * t - 1.6002e-10) * t + 9.1041e-9) * t - 3.9064e-7
    a1 = (((-2.0122e-10 * t + 1.0507e-8) * t - 6.4885e-8) * t - 1.2580e-5) * t + 9.4742e-5
    a0 = (((-3.21e-8 * t + 2.006e-6) * t + 7.164e-5) * t - 1.262e-2) * t + 1.389
    a = ((a3 * p + a2) * p + a1) * p + a0
    c3 = (-2.3643e-12 * t + 3.8504e-10) * t - 9.7729e-9
    c2 = (((1.0405e-12 * t - 2.5335e-10) * t + 2.5974e-8) * t - 1.7107e-6) * t + 3.1260e-5
    c1 = (((-6.1185e-10 * t + 1.3621e-7) * t - 8.1788e-6) * t + 6.8982e-4) * t + 0.153563
    c0 = (
        (((3.1464e-9 * t - 1.47800e-6) * t + 3.3420e-4) * t - 5.80852e-2) * t + 5.03711
    ) * t + 1402.388
    c = ((c3 * p + c2) * p + c1) * p + c0
    return scalar_or_array(np.asarray(c + (a + b * sr + d * s) * s, dtype=np.float64))


def fresh_water_sound_speed(temperature_c: ArrayLike) -> FloatOrArray:
    """Sound speed in pure water at atmospheric pressure by Marczak (1997), m/s.

    Marczak, W. (1997), "Water as a standard in the measurements of speed of sound in
    liquids", JASA 102(5) 2776-2779: a fifth-order polynomial in temperature fitted to the
    combined measurements of Del Grosso & Mader (1972), Kroebel & Mahrt (1976) and Fujii &
    Masui (1993). Valid 0-95 °C (ITS-90) at 1 atm. Between 0 and 40 °C it stays within
    0.05 m/s of the Del Grosso & Mader pure-water polynomial (the UNESCO formula at S = 0,
    P = 0), which the tests check; dissolved air and tap-water salts (S of a few 0.1 psu add
    about 1.3 m/s per psu) are larger errors in a real tank than the fit itself.

    Parameters
    ----------
    temperature_c:
        Water temperature, °C, valid 0 to 95.

    Examples
    --------
    >>> round(fresh_water_sound_speed(20.0), 2)
    1482.38
    """
    t = as_float_array("temperature_c", temperature_c)
    check_range(
        "temperature_c",
        t,
        0.0,
        95.0,
        "°C",
        "Marczak (1997) covers liquid water at 1 atm; for sea water use unesco_sound_speed",
        what="Marczak 1997",
    )
    c = (
        1.402385e3
        + 5.038813 * t
        - 5.799136e-2 * t**2
        + 3.287156e-4 * t**3
        - 1.398845e-6 * t**4
        + 2.787860e-9 * t**5
    )
    return scalar_or_array(np.asarray(c, dtype=np.float64))


def tank_sound_speed(temperature_c: ArrayLike) -> FloatOrArray:
    """Sound speed in a fresh-water tank at the logged temperature, m/s (Marczak 1997).

    The convenience the tank experiments call: ``temperature_c`` in °C, 0 to 95.

    Examples
    --------
    >>> round(tank_sound_speed(25.0), 1)
    1496.7
    """
    return fresh_water_sound_speed(temperature_c)
