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
