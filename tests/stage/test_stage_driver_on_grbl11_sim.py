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
    """A move into the far limit switch (at -501 mm, 6 mm from power-up) raised ALARM:1."""
    clock = ManualClock(100.0)
    config = replace(INSTANT, soft_limits=False, power_up_position_mm=-495.0)
    with (
        SimulatedGrblOnPty(config, clock=clock) as sim,
        GrblStage(sim.port_name, clock=clock, wait_step=0.1, read_timeout=0.005) as stage,
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
