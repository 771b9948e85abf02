"""Circular sample buffers addressed by absolute sample index (at most two slice copies).

A ring of ``R`` rows holds sample index ``n`` at row ``n mod R``; it remembers the last ``R``
samples written. Used for the delay lines of the simulated backend, with no allocation per
block.

Examples
--------
>>> import numpy as np
>>> ring = np.zeros((4, 1), dtype=np.float32)
>>> ring_write(ring, 3, np.array([[1.0], [2.0], [3.0]], dtype=np.float32))
>>> ring[:, 0].tolist()
[2.0, 3.0, 0.0, 1.0]
>>> out = np.empty((3, 1), dtype=np.float32)
>>> ring_read(ring, 3, out)
>>> out[:, 0].tolist()
[1.0, 2.0, 3.0]
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def ring_write(ring: npt.NDArray[np.float32], start: int, block: npt.NDArray[np.float32]) -> None:
    """Store ``block`` (frames, channels) at sample indices ``start ... start + frames - 1``.

    ``frames`` must not exceed the ring length.
    """
    size = ring.shape[0]
    frames = block.shape[0]
    first = start % size
    head = min(frames, size - first)
    ring[first : first + head] = block[:head]
    if head < frames:
        ring[: frames - head] = block[head:]


def ring_read(ring: npt.NDArray[np.float32], start: int, out: npt.NDArray[np.float32]) -> None:
    """Fill ``out`` (frames, channels) with the samples at ``start ... start + frames - 1``.

    ``start`` may be negative (before the first write): those rows of a zero-initialised
    ring read as silence as long as the ring is at least ``delay + frames`` long.
    """
    size = ring.shape[0]
    frames = out.shape[0]
    first = start % size
    head = min(frames, size - first)
    out[:head] = ring[first : first + head]
    if head < frames:
        out[head:] = ring[: frames - head]
