"""A manual clock for simulated time: ``now()`` only moves when told to.

It also satisfies the one clock protocol (:class:`hil.devices.clock.Clock`): ``sleep`` and
``sleep_until`` advance the time at once, so a driver waiting on it and a simulator reading
it run a 10 s move in milliseconds. Safe to read from one thread while another advances it.

>>> c = ManualClock(5.0)
>>> c.sleep(0.25); c.advance(1.0); c.now()
6.25
>>> c.sleep_until(7.0); c.sleep_until(3.0); c.now()
7.0
"""

from __future__ import annotations

import threading


class ManualClock:
    """Seconds that advance only through :meth:`advance` / :meth:`sleep`."""

    def __init__(self, start: float = 0.0) -> None:
        self._now = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        """Current simulated time, s."""
        return self._now

    def __call__(self) -> float:
        return self._now

    def advance(self, seconds: float) -> None:
        """Move the time forward by ``seconds`` (negative values are ignored)."""
        if seconds > 0:
            with self._lock:
                self._now += seconds

    def sleep(self, seconds: float) -> None:
        """Same as :meth:`advance`: simulated time passes instantly."""
        self.advance(seconds)

    def sleep_until(self, t_s: float) -> None:
        """Advance to ``t_s`` at once (never backwards)."""
        with self._lock:
            self._now = max(self._now, float(t_s))
