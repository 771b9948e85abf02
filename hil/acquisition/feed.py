"""The receiver's side of a capture: raw sample blocks indexed by board sample in, the
receiver's input out (one channel, float64, scaled), with the samples that never arrived
told to it as ``gap_before``.

Live (:class:`~hil.acquisition.capture.CaptureLoop`) and on replay
(:func:`hil.recording.replay`) a receiver is fed through a :class:`ReceiverFeed`; receivers
are chunk-invariant, so replay blocks need not match the live ones, and the gaps are the
same because both come from the board sample indices.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation.base import Estimate, Receiver


class ReceiverFeed:
    """Feeds raw sample blocks indexed by board sample to a receiver.

    ``origin`` is the board sample index that is the receiver's sample 0 (the schedule's
    t = 0); samples before it are dropped, samples fed twice are refused. Column ``channel``
    of each block, converted to float64 and multiplied by ``scale``, is the receiver's input.
    """

    def __init__(self, receiver: Receiver, *, origin: int, channel: int = 0, scale: float = 1.0):
        self.receiver = receiver
        self.origin = int(origin)
        self.channel = int(channel)
        self.scale = float(scale)
        self._next = self.origin

    @property
    def next_index(self) -> int:
        """Board index of the next sample the receiver expects."""
        return self._next

    @property
    def next_useful_index(self) -> int:
        """Board index the stream must reach before the receiver can emit its next estimate
        (:attr:`Receiver.next_decision_index <hil.estimation.base.Receiver.next_decision_index>`
        on board indices; for the two-stage GCAS, its next decision after the look-ahead). A
        live loop that waits for it calls the receiver less often and gets every estimate as
        early."""
        return max(self._next, self.origin + int(self.receiver.next_decision_index))

    def wait_index(self, max_block: int) -> int:
        """Board index a live loop waits for before it feeds again: the receiver's next
        decision (:attr:`next_useful_index`) when it comes within ``max_block`` samples of
        :attr:`next_index`, else ``max_block`` samples on. No estimate can come out before
        the decision index, and waiting past it only makes the estimate later; the cap keeps
        a receiver without decisions (or far from one) fed in bounded blocks.

        >>> class Deciding:  # decides at its sample 700 (board index 1700)
        ...     next_decision_index = 700
        >>> feed = ReceiverFeed(Deciding(), origin=1000)  # type: ignore[arg-type]
        >>> feed.wait_index(1920), feed.wait_index(500)
        (1700, 1500)
        """
        if max_block < 1:
            raise ConfigError("max_block", max_block, ">= 1 sample", "wait at least one sample")
        cap = self._next + int(max_block)
        useful = self.next_useful_index
        return useful if self._next < useful < cap else cap

    def feed(self, first_index: int, block: NDArray[Any]) -> list[Estimate]:
        """Process ``block`` (shape ``(n, n_channels)``) received from board sample
        ``first_index``; the samples since the previous block that never arrived go to the
        receiver as ``gap_before``."""
        if first_index < self.origin:
            # Samples before the receiver's sample 0 (captured while the loopback latency was
            # measured) are not the receiver's input: drop them, as live does.
            skip = min(block.shape[0], self.origin - int(first_index))
            block = block[skip:]
            first_index = int(first_index) + skip
            if block.shape[0] == 0:
                return []
        gap = int(first_index) - self._next
        if gap < 0:
            raise ConfigError(
                "first_index",
                int(first_index),
                f">= {self._next} (after the samples already fed and the origin {self.origin})",
            )
        if block.ndim != 2 or not 0 <= self.channel < block.shape[1]:
            raise ConfigError(
                "receiver.channel", self.channel, f"a column of blocks shaped {block.shape}"
            )
        x = block[:, self.channel].astype(np.float64) * self.scale
        self._next = int(first_index) + block.shape[0]
        return self.receiver.process(x, gap_before=gap)

    def finish(self) -> list[Estimate]:
        """End of input: the estimates the receiver still holds."""
        return self.receiver.flush()
