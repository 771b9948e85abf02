"""Rayleigh plane-wave reflection coefficient at a fluid-fluid interface (e.g. the tank floor).

Brekhovskikh & Lysanov, *Fundamentals of Ocean Acoustics*: for a wave in water (density
``rho``, sound speed ``c``) meeting a second fluid (``rho1``, ``c1``) at angle ``theta`` from
the normal,

    n = (c / c1)(1 + i alpha),   m = rho1 / rho,
    V = (m cos theta - sqrt(n² - sin² theta)) / (m cos theta + sqrt(n² - sin² theta)),

with the principal square root, so ``|V| = 1`` beyond the critical angle. ``alpha`` is the
loss tangent of the second medium (dimensionless, the imaginary part of its relative
wavenumber). The signature and argument order follow ``arlpy.uwa.reflection_coeff``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_devices.acoustics._physics_inputs import as_float_array, check_positive, check_range

ComplexOrArray = complex | NDArray[np.complex128]


def reflection_coeff(
    angle_rad: ArrayLike,
    rho1: ArrayLike,
    c1: ArrayLike,
    alpha: ArrayLike = 0.0,
    rho: ArrayLike = 1023.0,
    c: ArrayLike = 1540.0,
) -> ComplexOrArray:
    """Complex pressure reflection coefficient (dimensionless), Rayleigh fluid-fluid model.

    Parameters
    ----------
    angle_rad:
        Angle of incidence from the normal, rad, 0 to pi/2.
    rho1, c1:
        Density (kg/m³) and sound speed (m/s) of the second medium (bottom).
    alpha:
        Loss tangent of the second medium (>= 0, dimensionless).
    rho, c:
        Density (kg/m³) and sound speed (m/s) of the water.

    Returns
    -------
    complex, or a complex array of the broadcast shape. Its modulus is the amplitude ratio,
    its argument the phase shift on reflection.

    Examples
    --------
    >>> v = reflection_coeff(0.0, 1200.0, 1600.0, 0.0, 1023.0, 1540.0)
    >>> round(v.real, 4), round(v.imag, 4)
    (0.0986, 0.0)
    >>> v = reflection_coeff(0.5, 1200.0, 1600.0, 0.2, 1023.0, 1540.0)
    >>> round(v.real, 4), round(v.imag, 4)
    (0.0855, -0.1278)
    """
    theta = as_float_array("angle_rad", angle_rad)
    check_range(
        "angle_rad", theta, 0.0, np.pi / 2.0, "rad", "the angle is measured from the normal"
    )
    densities = [as_float_array(name, v) for name, v in (("rho1", rho1), ("rho", rho))]
    speeds = [as_float_array(name, v) for name, v in (("c1", c1), ("c", c))]
    for name, arr in zip(("rho1", "rho"), densities, strict=True):
        check_positive(name, arr, "kg/m³", "densities are in kg/m³")
    for name, arr in zip(("c1", "c"), speeds, strict=True):
        check_positive(name, arr, "m/s", "sound speeds are in m/s")
    loss = as_float_array("alpha", alpha)
    check_range("alpha", loss, 0.0, np.inf, "", "alpha is a loss tangent (>= 0)")
    n = speeds[1] / speeds[0] * (1.0 + 1j * loss)
    m = densities[0] / densities[1]
    t1 = m * np.cos(theta)
    t2 = np.sqrt(n**2 - np.sin(theta) ** 2 + 0j)
    v = np.asarray((t1 - t2) / (t1 + t2), dtype=np.complex128)
    if v.ndim == 0:
        return complex(v)
    return v
