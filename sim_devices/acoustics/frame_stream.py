"""A stream cut into frames rendered one after another, read in any sizes.

Reverberation and noise render whole frames (an FFT each) while a simulated device asks for
about a millisecond at a time. :class:`FrameStream` holds the frame being read and an offset
into it: a read costs a slice of the frames it spans, never a copy of what is left of a frame
(which would cost the frame's length on every read).

>>> import numpy as np
>>> frames = iter([np.arange(4.0), np.arange(4.0, 8.0)])
>>> stream = FrameStream(lambda: next(frames))
>>> stream.take(3).tolist(), stream.take(3).tolist(), stream.take(0).tolist()
([0.0, 1.0, 2.0], [3.0, 4.0, 5.0], [])
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from sim_devices.acoustics.trajectory import FloatArray


class FrameStream:
    """The samples of ``render_next()`` (the next frame, shape ``(m,)``, any ``m >= 1``) one
    after another; :meth:`take` hands out the next ``n`` as float64."""

    def __init__(self, render_next: Callable[[], FloatArray]) -> None:
        self._render_next = render_next
        self._frame: FloatArray = np.zeros(0)
        self._offset = 0

    def take(self, n_samples: int) -> FloatArray:
        """The next ``n_samples`` (shape ``(n_samples,)``, float64)."""
        n = int(n_samples)
        left = self._frame.shape[0] - self._offset
        if n <= left:
            out = self._frame[self._offset : self._offset + n]
            self._offset += n
            return np.array(out, dtype=np.float64)
        pieces = [self._frame[self._offset :]]
        have = left
        while have < n:
            self._frame = self._render_next()
            self._offset = min(self._frame.shape[0], n - have)
            pieces.append(self._frame[: self._offset])
            have += self._offset
        return np.concatenate(pieces).astype(np.float64, copy=False)
