"""The virtual clock a whole simulated run shares: services at every tick, exact integer
time, refusals with their messages."""

from __future__ import annotations

import pytest

from hil.devices.clock import VirtualClock
from hil.errors import ConfigError


def test_services_run_on_the_tick_grid_and_at_the_end_of_each_sleep() -> None:
    clock = VirtualClock(tick_s=0.004, start_s=0.001)
    seen: list[int] = []
    clock.attach(lambda: seen.append(round(clock.now() * 1e6)))
    clock.sleep(0.01)
    assert seen == [4000, 8000, 11000]
    clock.sleep(0.0)
    clock.sleep(-1.0)
    assert seen == [4000, 8000, 11000] and clock.now() == pytest.approx(0.011)


def test_ten_thousand_ticks_add_up_exactly() -> None:
    clock = VirtualClock(tick_s=0.001)
    for _ in range(10_000):
        clock.sleep(0.001)
    assert clock.now() == 10.0  # integer nanoseconds: no drift of summed floats


def test_wait_until_gives_up_at_its_timeout() -> None:
    clock = VirtualClock(tick_s=0.01)
    assert clock.wait_until(lambda: False, timeout_s=0.25) is False
    assert clock.now() == pytest.approx(0.25)


def test_a_detached_service_no_longer_runs() -> None:
    clock = VirtualClock()
    calls: list[float] = []
    detach = clock.attach(lambda: calls.append(clock.now()))
    clock.sleep(0.002)
    detach()
    detach()  # twice: harmless
    clock.sleep(0.01)
    assert len(calls) == 2


def test_a_service_that_sleeps_is_refused() -> None:
    clock = VirtualClock()
    clock.attach(lambda: clock.sleep(0.001))
    with pytest.raises(RuntimeError, match="a VirtualClock service slept"):
        clock.sleep(0.001)


@pytest.mark.parametrize("tick_s", [0.0, 1e-7, 2.0, -0.001])
def test_a_tick_out_of_range_is_refused(tick_s: float) -> None:
    with pytest.raises(
        ConfigError, match=rf"^tick_s = {tick_s!r} is not allowed: must be 1 µs \.\. 1 s"
    ):
        VirtualClock(tick_s=tick_s)


class _Producer:
    """A service that makes one unit per elapsed ms (work a later call does the same), with
    an optional quiet time: until ``awaited`` units exist, or the next 'event' (every 7 ms)
    it must see on time."""

    def __init__(self, clock: VirtualClock, quiet: bool) -> None:
        self.clock, self.quiet = clock, quiet
        self.made = 0
        self.awaited: int | None = None
        self.calls = 0
        self.quiet_asked = 0
        self.events: list[int] = []

    def __call__(self) -> None:
        self.calls += 1
        now = round(self.clock.now() * 1e9)
        self.made = now // 1_000_000
        if now // 7_000_000 > len(self.events):
            self.events.append(now)

    def quiet_until_ns(self) -> int | None:
        self.quiet_asked += 1
        if not self.quiet or self.awaited is None:
            return None
        next_event = (len(self.events) + 1) * 7_000_000
        return min(self.awaited * 1_000_000, next_event)


def _wait_for(producer: _Producer, clock: VirtualClock, units: int) -> tuple[bool, int]:
    producer.awaited = units
    try:
        ok = clock.wait_until(lambda: producer.made >= units, timeout_s=1.0)
    finally:
        producer.awaited = None
    return ok, round(clock.now() * 1e9)


def test_quiet_ticks_are_skipped_and_the_waits_end_as_on_every_tick() -> None:
    runs = {}
    for quiet in (False, True):
        clock = VirtualClock(tick_s=0.001)
        producer = _Producer(clock, quiet)
        clock.attach(producer, producer.quiet_until_ns)
        ends = [_wait_for(producer, clock, units) for units in (30, 31, 95)]
        clock.sleep(0.0105)  # no wait: every tick runs, and the end of the sleep
        runs[quiet] = (ends, producer.made, producer.events, round(clock.now() * 1e9))
        runs[quiet, "calls"] = producer.calls
    assert runs[True] == runs[False]
    assert runs[False][0] == [(True, 30_000_000), (True, 31_000_000), (True, 95_000_000)]
    # every 7 ms event seen at its own tick
    assert runs[True][2] == [k * 7_000_000 for k in range(1, 16)]
    assert runs[False, "calls"] == 106
    # The waits' ends (30, 31, 95 ms), the 13 events before 95 ms, then every tick of the
    # plain sleep (96 … 105 ms) and its end.
    assert runs[True, "calls"] == 3 + 13 + 11


def test_a_quiet_service_still_runs_at_the_end_of_every_sleep() -> None:
    clock = VirtualClock(tick_s=0.001)
    seen: list[int] = []
    clock.attach(lambda: seen.append(round(clock.now() * 1e6)), lambda: 10**12)
    clock.sleep(0.0025)
    clock.sleep(0.002)
    assert seen == [2500, 4500]
    assert clock.wait_until(lambda: False, timeout_s=0.01) is False
    assert seen == [2500, 4500, 14500] and round(clock.now() * 1e6) == 14500


def test_a_wait_asks_the_quiet_time_once_per_turn_it_runs() -> None:
    clock = VirtualClock(tick_s=0.001)
    producer = _Producer(clock, quiet=True)
    clock.attach(producer, producer.quiet_until_ns)
    assert _wait_for(producer, clock, 30) == (True, 30_000_000)
    # Turns at the 7, 14, 21 and 28 ms events and at 30 ms: one question before each.
    assert producer.calls == 5
    assert producer.quiet_asked == 5
