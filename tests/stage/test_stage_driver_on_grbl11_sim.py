"""The GRBL driver against the faithful simulator: what real GRBL 1.1h exposes.

After ALARM:1 the firmware sits 0.5 s, prints ``[MSG:Reset to continue]``, ignores ``?``
and drops a 0x18 that came in the 0.5 s (``tests/stage/test_stage_sim_grbl11.py``). A
driver must answer ``status()`` and ``reset()`` straight after the alarm within a second
(issue 20, "Must show"): the driver takes the alarm from its code and resends the reset
until the banner comes.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace

import pytest

from hil.devices.grbl import GrblStage
from hil.devices.stage import StageState
from hil.devices.stage_errors import StageAlarmError
from sim_devices.stage import ManualClock, SimulatedGrblOnPty
from tests.stage.conftest import INSTANT


@pytest.fixture
def after_hard_limit() -> Iterator[tuple[GrblStage, ManualClock, SimulatedGrblOnPty]]:
    """A move into the far limit switch (at -501 mm, 6 mm from power-up) raised ALARM:1.

    The driver moves the manual clock on by ``wait_step`` at each read that finds nothing
    (5 ms of real time): with the simulator's thread held off by other work, such reads come
    more often, each one 20 ms of the firmware's time here (0.1 s would spend the second's
    budget in ten of them)."""
    clock = ManualClock(100.0)
    config = replace(INSTANT, soft_limits=False, power_up_position_mm=-495.0)
    with (
        SimulatedGrblOnPty(config, clock=clock) as sim,
        GrblStage(sim.port_name, clock=clock, wait_step=0.02, read_timeout=0.005) as stage,
    ):
        stage.unlock()
        with pytest.raises(StageAlarmError, match=r"ALARM:1 \(Hard limit"):
            stage.move_to(-0.010, 0.01)
        assert sim.status().alarm == 1
        yield stage, clock, sim


def test_status_straight_after_a_hard_limit_within_a_second(
    after_hard_limit: tuple[GrblStage, ManualClock, SimulatedGrblOnPty],
) -> None:
    stage, clock, _ = after_hard_limit
    t0 = clock.now()
    status = stage.status()
    assert status.state is StageState.ALARM and status.alarm == 1
    assert clock.now() - t0 < 1.0


def test_reset_straight_after_a_hard_limit_within_a_second(
    after_hard_limit: tuple[GrblStage, ManualClock, SimulatedGrblOnPty],
) -> None:
    stage, clock, sim = after_hard_limit
    t0 = clock.now()
    stage.reset()
    assert clock.now() - t0 < 1.0
    assert not sim.status().critical


def test_hard_limit_mid_pass_stops_the_run_within_a_second() -> None:
    # Not homed: powered up 490 mm from the homing switch, GRBL counts from 0 there, so the
    # far switch (501 mm) sits at machine -11 mm, inside the travel the driver allows. The
    # pass: 1 mm to the run-up start at the max rate (0.2 s), then from -1 mm at 10 mm/s
    # (0.05 s to speed at 100 mm/s²): the switch 10 mm on, about 1.25 s after the start.
    from hil.experiments.live.devices import RunDevices

    clock = ManualClock(100.0)
    config = replace(INSTANT, soft_limits=False, homing=False, power_up_position_mm=-490.0)
    with SimulatedGrblOnPty(config, clock=clock) as sim:
        stage = GrblStage(sim.port_name, clock=clock, wait_step=0.01, read_timeout=0.005).open()
        stage.status()
        t0 = clock.now()
        with pytest.raises(StageAlarmError, match=r"ALARM:1 \(Hard limit"):
            stage.run_profile(-0.002, -0.015, 0.010, 0.001, 0.003)
        assert sim.status().alarm == 1
        assert sim.status().physical_mm == pytest.approx(-501.0, abs=0.1)
        assert clock.now() - (t0 + 1.25) < 1.0
        t1 = clock.now()
        RunDevices(stage=stage).safe_stop(hold=True)
        assert clock.now() - t1 < 1.0


@pytest.mark.slow
def test_homing_a_three_axis_stage() -> None:
    # Stock GRBL homes Z, then X and Y together, and needs every switch.
    clock = ManualClock(0.0)
    config = replace(
        INSTANT, homing_cycles=("Z", "XY"), switch_axes="XYZ", power_up_position_mm=-120.0,
        power_up_yz_mm=(-80.0, -40.0),
    )  # fmt: skip
    with SimulatedGrblOnPty(config, clock=clock) as sim:
        stage = GrblStage(sim.port_name, clock=clock, wait_step=0.05, read_timeout=0.005).open()
        status = stage.home()
        assert status.state is StageState.IDLE
        assert sim.status().machine_mm == pytest.approx(-config.homing_pulloff_mm, abs=0.01)
        # Z (40 mm) then X (120 mm, Y 80 mm alongside) at the seek rate, each with its
        # locate and pull-off: the driver waited that long and no longer than its timeout.
        assert 160.0 / (config.homing_seek_mm_min / 60.0) < clock.now() < 1000.0
        stage.close()
