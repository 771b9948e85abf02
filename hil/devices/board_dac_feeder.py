"""The DAC side of the board driver: a DAC source turned into wire sample blocks.

:class:`DacFeeder` takes from a source (a callable ``source(k, n)``, an iterable of blocks or
an object with ``read(n)``) as much as the board's credit allows, skips samples whose time has
passed, and keeps what it sent until the board accepted START, so a refused start can be
tried again with the same samples. :class:`ResumedSource` hands what a feeder has left to the
start that follows a reconnect.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

from firmware_protocol import SampleFormat
from hil.devices.board_settings import to_wire_samples

DacSource = Callable[[int, int], npt.ArrayLike] | Iterable[npt.ArrayLike]
"""A callable ``source(k, n) -> block`` (samples ``k .. k+n-1`` of the transmission, numbered
from 0 at the index :meth:`hil.devices.board.Board.start` returns; not board indices) or an
iterable of blocks. Blocks are (n,) (played on every channel) or (n, dac_channels); floats
are full scale (+-1.0), integers are counts of the DAC format. An object with ``read(n)``
(BlockSynthesizer) is accepted too."""


class DacFeeder:
    """Turns a DAC source into wire sample blocks of any requested length.

    Sample ``k`` of the transmission plays at board index ``first + k``; a callable source
    is asked ``source(k, n)`` by that sample number. Until :meth:`started`, the blocks sent
    are kept, so a START the board refused can be retried later with the same samples
    (:meth:`restart_at`). ``lock`` is held by whoever takes from or moves the feeder (the
    writer thread, a retried start).
    """

    def __init__(self, source: Any, fmt: SampleFormat, channels: int, first: int) -> None:
        self.fmt = fmt
        self.channels = channels
        self.next_index = first
        self.lock = threading.Lock()
        # Sample number of the next sample the source produces: ahead of the next one sent
        # by what is taken but not yet sent, so a burst asks for fresh samples.
        self._source_index = 0
        self._call: Callable[[int, int], npt.ArrayLike] | None = None
        self._iter: Iterator[npt.ArrayLike] | None = None
        self._indexed = False  # a source(k, n) callable: samples asked by number
        if hasattr(source, "read") and callable(source.read):
            self._call = lambda first, n: source.read(n)
        elif callable(source):
            self._call = source
            self._indexed = True
        else:
            self._iter = iter(source)
        self._pending: npt.NDArray[Any] | None = None
        self._sent: list[npt.NDArray[Any]] | None = []  # None once started
        self.exhausted = False

    def sent(self, blocks: list[npt.NDArray[Any]]) -> None:
        """Record blocks that went to the board (kept until :meth:`started`)."""
        if self._sent is not None:
            self._sent.extend(blocks)

    def started(self) -> None:
        """The board accepted START: what was sent need not be kept any longer."""
        self._sent = None

    def restart_at(self, first: int) -> None:
        """Send everything again from sample 0, at board index ``first`` (the board dropped
        what it had: its START was refused and it was stopped)."""
        if self._sent is None:
            raise RuntimeError("restart_at() after started(): the sent samples are gone")
        rest = [] if self._pending is None else [self._pending]
        if self._sent or rest:
            self._pending = np.concatenate(self._sent + rest)
        self._sent = []
        self.next_index = first
        if self._pending is not None and self._pending.shape[0]:
            self.exhausted = False  # the source may have ended; what it gave is sent again

    def take(self, n: int) -> npt.NDArray[Any] | None:
        """Up to ``n`` wire samples (rows), or None when the source has ended."""
        if self._pending is None or self._pending.shape[0] == 0:
            if self._call is not None:
                raw = self._call(self._source_index, n)
            else:
                assert self._iter is not None
                try:
                    raw = next(self._iter)
                except StopIteration:
                    self.exhausted = True
                    return None
            self._pending = to_wire_samples(raw, self.fmt, self.channels)
            self._source_index += self._pending.shape[0]
        block, self._pending = self._pending[:n], self._pending[n:]
        return block

    def skip(self, n: int) -> None:
        """Drop the next ``n`` samples unsent (their time has passed on the board)."""
        pending = 0 if self._pending is None else self._pending.shape[0]
        from_pending = min(n, pending)
        if self._pending is not None:
            self._pending = self._pending[from_pending:]
        rest = n - from_pending
        if self._indexed:
            self._source_index += rest  # asked by index: nothing to render
            rest = 0
        while rest > 0:  # a sequential source: read and drop
            block = self.take(rest)
            if block is None:
                break
            rest -= block.shape[0]
        self.next_index += n

    def put_back(self, block: npt.NDArray[Any]) -> None:
        """Return samples that could not be sent (credit was reset)."""
        rest = self._pending if self._pending is not None else block[:0]
        self._pending = np.concatenate((block, rest))


class ResumedSource:
    """The remaining samples of a feeder, as a sequential source (an iterable of blocks) for
    a new start: skipping late samples reads and drops them, so every later sample still
    plays at its own place, and the source's end is passed on."""

    _BLOCK = 4096  # samples per block taken from the old feeder

    def __init__(self, feeder: DacFeeder) -> None:
        self._feeder = feeder

    def __iter__(self) -> Iterator[npt.NDArray[Any]]:
        while (block := self._feeder.take(self._BLOCK)) is not None and block.shape[0]:
            yield block
