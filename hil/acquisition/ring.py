"""A ring buffer of sample frames addressed by board sample index."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from hil.errors import ConfigError
from hil.resident_arrays import resident_zeros


class SampleRing:
    """The last ``capacity`` sample frames of a stream, by board sample index.

    ``write(first, block)`` stores ``block`` (n, channels) at indices ``first ..
    first+n-1``. Indices skipped by a write are filled with zeros and counted in
    :attr:`missing`; a write that starts before :attr:`end_index` (a repeat) is refused and
    returns False. ``read(first, n)`` returns a copy, or raises if the span is not held.

    Parameters
    ----------
    capacity:
        Sample frames kept (older ones are overwritten).
    channels:
        Channels per frame.
    dtype:
        Sample dtype (int16, int32 or float32 as unpacked from the wire).

    Examples
    --------
    >>> ring = SampleRing(8, 1, np.int16)
    >>> ring.write(10, np.array([[1], [2], [3]], dtype=np.int16))
    True
    >>> ring.write(15, np.array([[6]], dtype=np.int16)), ring.missing
    (True, 2)
    >>> ring.read(10, 6)[:, 0].tolist(), ring.start_index, ring.end_index
    ([1, 2, 3, 0, 0, 6], 10, 16)
    """

    def __init__(self, capacity: int, channels: int, dtype: npt.DTypeLike = np.int16) -> None:
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 1:
            raise ConfigError("capacity", capacity, "an integer >= 1 (sample frames)")
        if isinstance(channels, bool) or not isinstance(channels, int) or channels < 1:
            raise ConfigError("channels", channels, "an integer >= 1")
        self.capacity = capacity
        self.channels = channels
        # Mapped now: faulting pages in on the stream's first pass stalled every host
        # thread for 6–9 ms every 2 MiB (hil.resident_arrays).
        self._data = resident_zeros((capacity, channels), dtype)
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self.start_index: int | None = None
        """Index of the oldest frame held (None before the first write)."""
        self.end_index: int | None = None
        """Index after the newest frame held."""
        self.written = 0
        """Sample frames stored (each index at most once)."""
        self.missing = 0
        """Sample frames skipped (zero-filled)."""
        self._targets: list[int] = []  # end indices the threads in wait_for are waiting for
        self.on_write: Callable[[int], None] | None = None
        """Observer called by the writing thread with the new :attr:`end_index` after each
        block stored (outside the ring's lock): when samples arrived, for benchmarks."""

    def write(self, first: int, block: npt.NDArray[Any]) -> bool:
        """Store ``block`` from index ``first``; False (nothing stored) if it repeats data."""
        n = block.shape[0]
        with self._cond:
            end = self.end_index
            if self.written == 0 and end is not None and first < end:
                end = None  # before the index expect() named: the stream starts here
            if end is not None and first < end:
                return False
            if end is None:
                self.start_index = first
                end = first
            if first > end:
                self._put(end, np.zeros((first - end, self.channels), self._data.dtype))
                self.missing += first - end
            self._put(first, block)
            self.end_index = first + n
            self.written += n
            assert self.start_index is not None
            self.start_index = max(self.start_index, self.end_index - self.capacity)
            # Wake a waiter only once its index is reached: at 1 MS/s a block arrives about
            # every millisecond, and a loop waiting for several blocks would otherwise wake
            # (and take the GIL) for each one.
            if self._targets and self.end_index >= min(self._targets):
                self._cond.notify_all()
            end_index = self.end_index
        if self.on_write is not None:
            self.on_write(end_index)
        return True

    def expect(self, first: int) -> None:
        """The stream starts at index ``first``: if its first samples are lost (an ADC
        overrun or a dropped frame at the start), the first block that arrives is preceded by
        zero-filled :attr:`missing` frames, as after any gap, so the span from ``first`` can
        be read. Before anything is stored only (a ring that holds samples keeps them).

        >>> ring = SampleRing(8, 1, np.int16)
        >>> ring.expect(10)
        >>> ring.write(12, np.array([[3]], dtype=np.int16)), ring.missing
        (True, 2)
        >>> ring.read(10, 3)[:, 0].tolist()
        [0, 0, 3]

        A stream that starts earlier than expected starts the ring where it starts:

        >>> early = SampleRing(8, 1, np.int16)
        >>> early.expect(10)
        >>> early.write(9, np.array([[1], [2]], dtype=np.int16)), early.start_index
        (True, 9)
        """
        with self._cond:
            if self.written == 0 and self.missing == 0:
                self.start_index = self.end_index = int(first)

    def _put(self, first: int, block: npt.NDArray[Any]) -> None:
        n = block.shape[0]
        if n > self.capacity:
            block, first, n = block[-self.capacity :], first + n - self.capacity, self.capacity
        pos = first % self.capacity
        head = min(n, self.capacity - pos)
        self._data[pos : pos + head] = block[:head]
        self._data[: n - head] = block[head:]

    def read(self, first: int, n: int) -> npt.NDArray[Any]:
        """A copy of frames ``first .. first+n-1`` (n, channels); raises if not all held."""
        with self._lock:
            if self.start_index is None or self.end_index is None:
                raise ConfigError("first", first, "an index held by the ring", "nothing written")
            if first < self.start_index or first + n > self.end_index or n < 0:
                raise ConfigError(
                    "first .. first+n",
                    f"{first} .. {first + n}",
                    f"within {self.start_index} .. {self.end_index} (held samples)",
                    "read more often or enlarge the ring",
                )
            out = np.empty((n, self.channels), dtype=self._data.dtype)
            pos = first % self.capacity
            head = min(n, self.capacity - pos)  # two slices where the span wraps
            out[:head] = self._data[pos : pos + head]
            out[head:] = self._data[: n - head]
            return out

    def wait_for(self, index: int, timeout_s: float) -> bool:
        """Block until ``end_index >= index`` (True) or ``timeout_s`` real seconds pass."""
        with self._cond:
            self._targets.append(index)
            try:
                return self._cond.wait_for(
                    lambda: self.end_index is not None and self.end_index >= index, timeout_s
                )
            finally:
                self._targets.remove(index)
