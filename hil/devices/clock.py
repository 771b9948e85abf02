"""The one clock protocol drivers and simulated devices wait on: ``now()`` in seconds,
``sleep(seconds)`` and ``sleep_until(t_s)``.

Drivers take a clock so that tests can run a simulated device on simulated time: a clock
whose ``sleep`` advances ``now`` instantly (:class:`sim_devices.stage.clock.ManualClock`,
for tests) makes a 10 s move take milliseconds. The implementations: :class:`MonotonicClock`
(the wall clock), :class:`VirtualClock` (a whole run held in one thread),
:class:`~hil.experiments.sim_tank.ScaledClock` (the real-time simulated tank's, slowed) and
the tests' ``ManualClock``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol


class Clock(Protocol):
    """Seconds on a monotonic time base, and a way to let time pass."""

    def now(self) -> float:
        """Current time in seconds (monotonic; the zero is arbitrary)."""
        ...

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass (a negative or zero value returns at once)."""
        ...

    def sleep_until(self, t_s: float) -> None:
        """Return at (or after) time ``t_s``, s (at once when it has passed)."""
        ...


class SleepUntil:
    """``sleep_until(t_s)`` for a clock with ``now()`` and ``sleep()``: sleep the rest."""

    def now(self) -> float:
        raise NotImplementedError

    def sleep(self, seconds: float) -> None:
        raise NotImplementedError

    def sleep_until(self, t_s: float) -> None:
        """Return at (or after) time ``t_s``, s (at once when it has passed)."""
        self.sleep(t_s - self.now())


class MonotonicClock(SleepUntil):
    """The wall clock: :func:`time.monotonic` and :func:`time.sleep`.

    >>> c = MonotonicClock()
    >>> c.now() <= c.now()
    True
    >>> c.sleep_until(c.now() - 1.0)  # passed: returns at once
    """

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class VirtualClock(SleepUntil):
    """Simulated seconds for a whole run held in one thread: time passes only in
    :meth:`sleep`, and every attached service runs at each :attr:`tick_s` of it.

    A service is the background work a real device and its driver's threads do while the
    host waits (a board's link read, its DAC feed and keepalives): on virtual time nothing
    runs beside the host, so whoever sleeps lets the services run in its place. Time is kept
    in integer nanoseconds on a grid of ticks, so two runs of the same work see the same
    instants and give identical results, however loaded the machine. A service must not
    sleep (that would nest time).

    >>> clock = VirtualClock(tick_s=0.01)
    >>> seen = []
    >>> detach = clock.attach(lambda: seen.append(round(clock.now(), 3)))
    >>> clock.sleep(0.025); seen
    [0.01, 0.02, 0.025]
    >>> clock.wait_until(lambda: len(seen) >= 5, timeout_s=1.0), clock.now()
    (True, 0.04)
    >>> detach(); clock.sleep(1.0); len(seen)
    5
    >>> clock.sleep_until(2.5); clock.now()
    2.5
    """

    def __init__(self, tick_s: float = 0.001, start_s: float = 0.0) -> None:
        if not 1e-6 <= tick_s <= 1.0:
            from hil.errors import ConfigError

            raise ConfigError("tick_s", tick_s, "1 µs .. 1 s", "e.g. 0.001")
        self._tick_ns = round(tick_s * 1e9)
        self._ns = round(start_s * 1e9)
        self._services: dict[int, tuple[Callable[[], None], Callable[[], int | None] | None]] = {}
        self._next_id = 0
        self._in_service = False

    @property
    def tick_s(self) -> float:
        """Spacing of the instants the services run at, s."""
        return self._tick_ns / 1e9

    def now(self) -> float:
        """Current virtual time, s."""
        return self._ns / 1e9

    def __call__(self) -> float:
        return self._ns / 1e9

    def attach(
        self, service: Callable[[], None], quiet_until_ns: Callable[[], int | None] | None = None
    ) -> Callable[[], None]:
        """Run ``service()`` at every tick from now on; returns the call that detaches it.

        ``quiet_until_ns()``, if given, says how long the service may be left out: the
        virtual time (ns) before which a tick's call would only do work that its next call
        does the same (None: no such time). Such ticks are skipped (:meth:`sleep`); the
        call at the end of a sleep is never skipped, so whoever slept sees every service
        brought up to the present.
        """
        key = self._next_id
        self._next_id += 1
        self._services[key] = (service, quiet_until_ns)

        def detach() -> None:
            self._services.pop(key, None)

        return detach

    def _quiet_until(self) -> int:
        """The first virtual time (ns) at which some service must run (now when one has no
        quiet time)."""
        until = None
        for _, quiet in self._services.values():
            q = quiet() if quiet is not None else None
            if q is None:
                return self._ns
            until = q if until is None else min(until, q)
        return self._ns if until is None else until

    def _next_tick_at(self, t_ns: int) -> int:
        """The first tick after now and at or after ``t_ns``."""
        first = (self._ns // self._tick_ns + 1) * self._tick_ns
        return max(first, -(-t_ns // self._tick_ns) * self._tick_ns)

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of virtual time pass, tick by tick, running the services at each
        tick (but those ticks every service is quiet on, see :meth:`attach`) and at the
        end."""
        if self._in_service:
            raise RuntimeError("a VirtualClock service slept: services must return at once")
        end = self._ns + round(max(0.0, seconds) * 1e9)
        while self._ns < end:
            self._serve_at(min(end, self._next_tick_at(self._quiet_until())))

    def _serve_at(self, t_ns: int) -> None:
        """Advance to ``t_ns`` (a tick, or the end of a sleep) and run every service once."""
        if self._in_service:
            raise RuntimeError("a VirtualClock service slept: services must return at once")
        self._ns = t_ns
        self._in_service = True
        try:
            for service, _ in list(self._services.values()):
                service()
        finally:
            self._in_service = False

    def wait_until(self, done: Callable[[], bool], timeout_s: float) -> bool:
        """Sleep until ``done()`` (True) or ``timeout_s`` virtual s pass (False): to the next
        tick at a time, or past the ticks every service is quiet on (``done()`` holds on what
        the services did, so it cannot change there)."""
        deadline = self._ns + round(max(0.0, timeout_s) * 1e9)
        while not done():
            if self._ns >= deadline:
                return False
            # One step of sleep(): the services' quiet time just asked is the one sleep
            # would ask again (nothing ran in between), so the step is taken directly.
            self._serve_at(min(self._next_tick_at(self._quiet_until()), deadline))
        return True
