"""The one clock protocol (:class:`hil.devices.clock.Clock`: ``now``, ``sleep``,
``sleep_until``) as each implementation keeps it, on times that never wait on the wall
clock (a wall clock is only asked for a time already past)."""

from __future__ import annotations

import time

import pytest

from hil.devices.clock import Clock, MonotonicClock, VirtualClock
from hil.experiments.sim_tank import ScaledClock
from sim_devices.stage.clock import ManualClock


@pytest.mark.parametrize("make", [lambda: VirtualClock(tick_s=0.01), lambda: ManualClock(0.0)])
def test_a_simulated_clock_sleeps_until_a_time_at_once_and_never_back(make) -> None:  # type: ignore[no-untyped-def]
    clock: Clock = make()
    clock.sleep(0.25)
    clock.sleep_until(1.125)
    assert clock.now() == pytest.approx(1.125, abs=1e-12)
    clock.sleep_until(0.5)  # passed: time does not go back
    clock.sleep(-1.0)
    assert clock.now() == pytest.approx(1.125, abs=1e-12)


def test_a_virtual_clock_runs_its_services_on_the_way_to_the_time() -> None:
    clock = VirtualClock(tick_s=0.1)
    seen: list[float] = []
    clock.attach(lambda: seen.append(round(clock.now(), 9)))
    clock.sleep_until(0.35)
    assert seen == [0.1, 0.2, 0.3, 0.35]


@pytest.mark.parametrize(
    ("clock", "wall_per_s"), [(MonotonicClock(), 1.0), (ScaledClock(0.5), 2.0)]
)
def test_a_wall_clock_sleeps_the_rest_of_the_way(
    clock: Clock, wall_per_s: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    slept: list[float] = []
    monkeypatch.setattr(time, "sleep", slept.append)  # record, do not wait
    clock.sleep_until(clock.now() - 10.0)  # passed: no sleep at all
    assert slept == []
    clock.sleep_until(clock.now() + 2.0)
    assert len(slept) == 1
    # Its own seconds in wall seconds, less what passed between the two reads of now().
    assert 0.0 < slept[0] <= 2.0 * wall_per_s
    assert slept[0] == pytest.approx(2.0 * wall_per_s, abs=0.5)
