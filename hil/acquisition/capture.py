"""The capture loop of a live run: wait for samples, read them, hand them on, feed the
receiver; one block per step.

A :class:`CaptureLoop` reads a :class:`SampleSource` (the board or the audio interface: a
ring of samples by board index) from a start index on. Each :meth:`CaptureLoop.step` waits
until the source holds what is worth reading (once a receiver is attached: its next decision
index when that comes within one block, so an estimate leaves as soon as its look-ahead has
arrived; else one block), reads everything held up to one block, gives it to the observer
(the recording, a latency probe, a benchmark's clocks) and then to the receiver.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy.typing as npt

from hil.acquisition.feed import ReceiverFeed
from hil.acquisition.ring import SampleRing
from hil.estimation.base import Estimate


class SampleSource(Protocol):
    """What the loop reads: the capture side of a
    :class:`~hil.acquisition.device.StreamingDevice` (a board, an audio interface)."""

    @property
    def ring(self) -> SampleRing | None: ...

    def wait_for_samples(self, end_index: int, /, timeout_s: float) -> bool: ...

    def read(self, first: int, n: int, /) -> npt.NDArray[Any]: ...


@dataclass(frozen=True)
class CapturedBlock:
    """One step's block: samples ``first_index ..`` (``data``: shape ``(n, channels)``, the
    source's dtype), what the receiver gave for it, and when (``time.monotonic`` s: the
    wait began, the samples were there, the receiver returned; ``feed_cpu_s``: the main
    thread's CPU time in the receiver)."""

    first_index: int
    data: npt.NDArray[Any]
    estimates: list[Estimate]
    wanted_index: int
    held_index: int
    wait_began: float
    seen_at: float
    fed_at: float
    feed_cpu_s: float


#: What a loop's observer is called with, before the receiver sees the block (its
#: ``estimates`` are then empty) and again after (``after_feed``).
Observer = Callable[[CapturedBlock], None]


@dataclass
class CaptureLoop:
    """Reads ``source`` from ``next_index`` on, ``max_block`` samples at most per step.

    ``on_block`` sees every block before the receiver (to record it: a recording then holds
    a block the receiver refused); ``on_fed`` sees it with its estimates. ``feed`` may be
    attached later (a run measures its loopback latency on the first blocks first), also
    by ``on_block``: it is then fed from the next block on.
    """

    source: SampleSource
    next_index: int
    max_block: int
    feed: ReceiverFeed | None = None
    on_block: Observer | None = None
    on_fed: Observer | None = None
    #: Wait for this many samples per step instead of the receiver's next decision (more
    #: receiver calls, the same estimates); None: the decision rule.
    every: int | None = None
    #: Most samples held but not yet read at a step (how far the loop fell behind).
    backlog_max: int = field(default=0)

    def wanted_index(self, limit: int | None = None) -> int:
        """The board index the next step waits for (see the module docstring), at most
        ``limit``."""
        if self.every is not None:
            wanted = self.next_index + self.every
        elif self.feed is not None:
            wanted = max(self.next_index + 1, self.feed.wait_index(self.max_block))
        else:
            wanted = self.next_index + self.max_block
        return wanted if limit is None else min(wanted, limit)

    def step(self, timeout_s: float, limit: int | None = None) -> CapturedBlock | None:
        """Wait up to ``timeout_s`` (real s) for samples, then read, observe and feed one
        block (not past index ``limit``); None when nothing came in time, or the capture
        has reached ``limit``."""
        if limit is not None and self.next_index >= limit:
            return None
        wanted = self.wanted_index(limit)
        began = time.monotonic()
        if not self.source.wait_for_samples(wanted, timeout_s=timeout_s):
            return None
        seen = time.monotonic()
        ring = self.source.ring
        held = ring.end_index if ring is not None and ring.end_index is not None else wanted
        self.backlog_max = max(self.backlog_max, held - self.next_index)
        stop = min(held, self.next_index + self.max_block)
        if limit is not None:
            stop = min(stop, limit)
        first, n = self.next_index, stop - self.next_index
        data = self.source.read(first, n)
        block = CapturedBlock(first, data, [], wanted, held, began, seen, seen, 0.0)
        feed = self.feed  # one attached by on_block now takes the blocks after this one
        if self.on_block is not None:
            self.on_block(block)
        self.next_index = stop
        if feed is None:
            return block
        cpu0 = time.thread_time()
        estimates = feed.feed(first, data)
        cpu = time.thread_time() - cpu0
        fed = CapturedBlock(
            first, data, estimates, wanted, held, began, seen, time.monotonic(), cpu
        )
        if self.on_fed is not None:
            self.on_fed(fed)
        return fed

    def run_while(self, go_on: Callable[[], bool], timeout_s: float) -> None:
        """Steps while samples come within ``timeout_s`` and ``go_on()`` holds after each."""
        while self.step(timeout_s) is not None and go_on():
            pass
