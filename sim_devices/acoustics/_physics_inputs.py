"""Input checks shared by the physics modules: finite numbers, ranges, scalar-or-array output.

Every failed check raises :class:`hil.errors.ConfigError` naming the field, the first offending
value, the allowed range with its unit, and what to do instead.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError

FloatArray = NDArray[np.float64]
FloatOrArray = float | FloatArray


def as_float_array(field: str, value: ArrayLike, hint: str = "") -> FloatArray:
    """``value`` as a float64 array (any shape), rejecting NaN and infinity."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(field, value, "a real number or an array of real numbers", hint) from exc
    if not np.all(np.isfinite(arr)):
        bad = arr[~np.isfinite(arr)].flat[0]
        raise ConfigError(field, float(bad), "a finite number", hint)
    return arr


def _first(arr: FloatArray, mask: NDArray[np.bool_]) -> float:
    return float(arr[mask].flat[0])


def check_range(
    field: str,
    arr: FloatArray,
    low: float,
    high: float,
    unit: str,
    hint: str = "",
    *,
    what: str = "",
) -> None:
    """Raise unless ``low <= arr <= high`` everywhere (``what`` names the model's validity)."""
    bad = (arr < low) | (arr > high)
    if np.any(bad):
        allowed = f"{low:g} to {high:g} {unit}".rstrip()
        if what:
            allowed += f" ({what})"
        raise ConfigError(field, _first(arr, bad), allowed, hint)


def check_positive(field: str, arr: FloatArray, unit: str, hint: str = "") -> None:
    """Raise unless ``arr > 0`` everywhere."""
    bad = ~(arr > 0)
    if np.any(bad):
        raise ConfigError(field, _first(arr, bad), f"> 0 {unit}".rstrip(), hint)


def check_non_negative(field: str, arr: FloatArray, unit: str, hint: str = "") -> None:
    """Raise unless ``arr >= 0`` everywhere."""
    bad = ~(arr >= 0)
    if np.any(bad):
        raise ConfigError(field, _first(arr, bad), f">= 0 {unit}".rstrip(), hint)


def checked_frequency(value: ArrayLike, field: str = "frequency_hz") -> FloatArray:
    """A frequency argument in Hz, which must be finite and > 0 (the models use log f)."""
    arr = as_float_array(field, value, "give frequencies in Hz")
    check_positive(field, arr, "Hz", "frequencies are in Hz and the models use log10(f)")
    return arr


def scalar_or_array(arr: FloatArray) -> FloatOrArray:
    """A Python float for a 0-d result, else the array itself (shape kept)."""
    if arr.ndim == 0:
        return float(arr)
    return arr
