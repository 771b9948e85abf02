"""Symmetric alpha-stable (SαS) random numbers: impulsive noise such as snapping shrimp.

Chambers, Mallows & Stuck (1976), JASA 71(354) 340-344, for skewness beta = 0: with
``V ~ U(-pi/2, pi/2)`` and ``W ~ Exp(1)`` independent,

    X = sin(alpha V) / cos(V)^(1/alpha) * (cos((1 - alpha) V) / W)^((1 - alpha)/alpha)

(``X = tan V`` at alpha = 1) has characteristic function ``exp(-|t|^alpha)``; ``scale * X``
has ``exp(-|scale t|^alpha)``, the parametrisation of ``scipy.stats.levy_stable`` with
beta = 0. alpha = 2 is Gaussian with variance ``2 scale²``; alpha = 1 is Cauchy; smaller
alpha means heavier tails (variance is infinite for alpha < 2).
"""

from __future__ import annotations

import numpy as np

from hil.errors import ConfigError
from sim_devices.acoustics._physics_inputs import FloatArray


def check_alpha(alpha: float) -> float:
    """Validate the characteristic exponent (0 < alpha <= 2) and return it as a float."""
    value = float(alpha)
    if not 0.0 < value <= 2.0:
        raise ConfigError(
            "alpha",
            alpha,
            "0 < alpha <= 2",
            "alpha = 2 is Gaussian; snapping-shrimp noise fits about 1.5 to 1.9",
        )
    return value


def symmetric_alpha_stable(
    alpha: float, size: int | tuple[int, ...], rng: np.random.Generator, scale: float = 1.0
) -> FloatArray:
    """Draw SαS samples (Chambers-Mallows-Stuck), shape ``size``, in the unit of ``scale``.

    Parameters
    ----------
    alpha:
        Characteristic exponent, 0 < alpha <= 2.
    size:
        Output shape.
    rng:
        A seeded :class:`numpy.random.Generator`; the draw is a pure function of its state.
    scale:
        Dispersion ``gamma`` (> 0), in the output unit (e.g. µPa).

    Examples
    --------
    >>> x = symmetric_alpha_stable(2.0, 200_000, np.random.default_rng(1))
    >>> round(float(np.var(x)), 1)   # alpha = 2 is N(0, 2 scale²)
    2.0
    """
    a = check_alpha(alpha)
    if not scale > 0.0:
        raise ConfigError("scale", scale, "> 0", "the dispersion of the noise, in its unit")
    v = rng.uniform(-np.pi / 2.0, np.pi / 2.0, size)
    w = rng.exponential(1.0, size)
    if a == 1.0:
        x = np.tan(v)
    else:
        x = np.sin(a * v) / np.cos(v) ** (1.0 / a) * (np.cos((1.0 - a) * v) / w) ** ((1.0 - a) / a)
    return np.asarray(scale * x, dtype=np.float64)
