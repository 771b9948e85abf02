"""Arrays whose memory is mapped when they are made, not when a live loop first writes them.

``np.zeros`` asks the system for fresh zero pages that are mapped on first touch, and NumPy
asks for transparent huge pages on large arrays. A buffer that a live loop fills bit by bit
(a capture ring, a receiver's history) then takes a page fault on every new page it
reaches, with the GIL held: for a huge page that is allocate, maybe compact, and zero
2 MiB, measured at 6–9 ms on the development machine, which stalled every host thread
every 2^19 samples of a 1 MS/s × 2 ch int16 capture ring for its whole first pass. Writing
the zeros once at construction moves that cost to set-up.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def resident_zeros(shape: int | tuple[int, ...], dtype: npt.DTypeLike = np.float64) -> npt.NDArray:
    """Zeros of ``shape`` and ``dtype`` with every page already written (mapped).

    >>> resident_zeros((2, 3), np.int16).tolist()
    [[0, 0, 0], [0, 0, 0]]
    """
    out = np.empty(shape, dtype=dtype)
    out.fill(0)
    return out
