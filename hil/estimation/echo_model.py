"""The input that measured echoes put into a stretch of samples (successive cancellation).

An echo measured by the refinement (:mod:`hil.estimation.refine`) is one copy of the
transmitted schedule at a fitted delay, time scale (and its rate) and complex amplitude
``β``. Its hops are held as the ``known`` columns of
:func:`~hil.estimation.refine_kernels.candidate_sums` (shape ``(5, Q)``, one column per hop):
the hop's complex weight ``w = ½ β conj(k)``, its received frequency ``g`` (Hz), the start
and end of its received interval (s) and the time ``t_e`` (s) its phase is counted from.
Over that interval the echo is

    x(t) = Re(2 w e^{j2π g (t − t_e)}),

the model the refinement takes out of a detection's likelihood; here it is written out at
the input rate so that the same echoes can be taken out of the input a detector searches.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray


def echo_samples(
    columns: NDArray[np.complex128], first_index: int, count: int, fs_hz: float
) -> NDArray[np.float64]:
    """The echoes of ``columns`` (shape ``(5, Q)``, module docstring) at input samples
    ``first_index … first_index + count − 1`` (sample ``n`` at ``n / fs_hz`` s), shape
    ``(count,)``. A sample belongs to the hop whose interval ``[start, end)`` holds its time;
    hops of several echoes add."""
    if count <= 0 or columns.shape[1] == 0:
        return np.zeros(max(count, 0), dtype=np.float64)
    fs = float(fs_hz)
    starts = np.clip(np.ceil(columns[2].real * fs - first_index), 0, count).astype(np.int64)
    ends = np.clip(np.ceil(columns[3].real * fs - first_index), 0, count).astype(np.int64)
    keep = np.flatnonzero(ends > starts)
    if keep.size == 0:
        return np.zeros(count, dtype=np.float64)
    lo, n = starts[keep], ends[keep] - starts[keep]
    g, t_e, w = columns[1, keep].real, columns[4, keep].real, columns[0, keep]
    # Re(2 w e^{jθ}) = 2|w| cos(θ + arg w); θ in cycles from each hop's first sample on
    # (the whole cycles dropped in float64 before the samples' steps are added).
    cyc0 = (g * ((first_index + lo) / fs - t_e) + np.angle(w) / (2.0 * math.pi)) % 1.0
    hop = np.repeat(np.arange(keep.size), n)
    k = np.arange(hop.size) - np.repeat(np.cumsum(n) - n, n)  # sample within its hop
    at = np.repeat(lo, n) + k
    wave = 2.0 * np.abs(w)[hop] * np.cos(2.0 * math.pi * (cyc0[hop] + (g / fs)[hop] * k))
    return np.asarray(np.bincount(at, weights=wave, minlength=count), dtype=np.float64)
