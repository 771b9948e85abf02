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

import numpy as np
from numpy.typing import NDArray

from hil.estimation.refine_kernels import echo_input


def echo_samples(
    columns: NDArray[np.complex128], first_index: int, count: int, fs_hz: float
) -> NDArray[np.float64]:
    """The echoes of ``columns`` (shape ``(5, Q)``, module docstring) at input samples
    ``first_index … first_index + count − 1`` (sample ``n`` at ``n / fs_hz`` s), shape
    ``(count,)``. A sample belongs to the hop whose interval ``[start, end)`` holds its time;
    hops of several echoes add; each sample's phase is a function of its own index (any
    split of a stretch gives the same samples). Compiled
    (:func:`~hil.estimation.refine_kernels.echo_input`)."""
    out = np.zeros(max(count, 0), dtype=np.float64)
    if count > 0 and columns.shape[1] > 0:
        echo_input(np.ascontiguousarray(columns), int(first_index), float(fs_hz), out)
    return out
