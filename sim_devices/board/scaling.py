"""Sample formats <-> full-scale floats on the board side (+-1.0 is full scale)."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from firmware_protocol import SampleFormat

_FULL_SCALE = {SampleFormat.INT16: 32768.0, SampleFormat.INT24: 8388608.0}


def to_full_scale(samples: npt.NDArray[Any], fmt: SampleFormat) -> npt.NDArray[np.float64]:
    """Wire samples (int16, int32 or float32) as float64 full-scale values.

    >>> to_full_scale(np.array([[16384, -32768]], dtype=np.int16), SampleFormat.INT16).tolist()
    [[0.5, -1.0]]
    """
    if fmt is SampleFormat.FLOAT32:
        return samples.astype(np.float64)
    return samples * (1.0 / _FULL_SCALE[fmt])


def _rounded_counts(values: npt.NDArray[np.floating], scale: float) -> npt.NDArray[np.float64]:
    """``values * scale`` rounded half to even (SPEC 6.3), NaN (a FLOAT32 DAC stream) as 0.

    >>> _rounded_counts(np.array([0.5, 1.5, -2.5, np.nan]), 1.0).tolist()
    [0.0, 2.0, -2.0, 0.0]
    """
    counts = np.rint(np.asarray(values, dtype=np.float64) * scale)
    counts[np.isnan(counts)] = 0.0
    return counts


def from_full_scale(values: npt.NDArray[np.floating], fmt: SampleFormat) -> npt.NDArray[Any]:
    """Full-scale floats as wire samples of ``fmt``, rounded and clipped (ADC clipping).

    >>> from_full_scale(np.array([[0.5, -2.0]]), SampleFormat.INT16).tolist()
    [[16384, -32768]]
    """
    if fmt is SampleFormat.FLOAT32:
        return values.astype(np.float32)
    scale = _FULL_SCALE[fmt]
    counts = _rounded_counts(values, scale)
    np.clip(counts, -scale, scale - 1, out=counts)
    return counts.astype(np.int16 if fmt is SampleFormat.INT16 else np.int32)


def from_full_scale_clipped(
    values: npt.NDArray[np.floating], fmt: SampleFormat
) -> tuple[npt.NDArray[Any], int]:
    """:func:`from_full_scale`, and how many values were clipped (INT16/INT24 only; a float
    ADC format does not clip).

    >>> counts, clipped = from_full_scale_clipped(np.array([[0.5], [1.0]]), SampleFormat.INT16)
    >>> counts[:, 0].tolist(), clipped
    ([16384, 32767], 1)
    """
    if fmt is SampleFormat.FLOAT32:
        return values.astype(np.float32), 0
    scale = _FULL_SCALE[fmt]
    dtype = np.int16 if fmt is SampleFormat.INT16 else np.int32
    counts = np.rint(np.asarray(values, dtype=np.float64) * scale)
    if counts.size:
        # The usual block: no NaN (either extreme would be NaN) and nothing out of range, so
        # neither the NaN rule nor the clip changes a count: two reductions decide it.
        low, high = float(counts.min()), float(counts.max())
        if -scale <= low and high <= scale - 1:
            return counts.astype(dtype), 0
    counts[np.isnan(counts)] = 0.0  # as _rounded_counts
    clipped = int(np.count_nonzero((counts > scale - 1) | (counts < -scale)))
    np.clip(counts, -scale, scale - 1, out=counts)
    return counts.astype(dtype), clipped
