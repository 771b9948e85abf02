"""The clock a driver waits on: ``now()`` in seconds and ``sleep(seconds)``.

Drivers take a clock so that tests can run a simulated device on simulated time: a clock
whose ``sleep`` advances ``now`` instantly (for example
:class:`sim_devices.stage.clock.ManualClock`) makes a 10 s move take milliseconds.
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """Seconds on a monotonic time base, and a way to let time pass."""

    def now(self) -> float:
        """Current time in seconds (monotonic; the zero is arbitrary)."""
        ...

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass (a negative or zero value returns at once)."""
        ...


class MonotonicClock:
    """The wall clock: :func:`time.monotonic` and :func:`time.sleep`.

    >>> c = MonotonicClock()
    >>> c.now() <= c.now()
    True
    """

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)
