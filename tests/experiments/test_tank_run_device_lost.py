"""A device lost at any phase of a run (homing, positioning, streaming) stops it within 1 s,
naming the device, with the stage held where it was.

On virtual time (:mod:`hil.experiments.virtual_tank`) the board is unplugged as a phase begins
and the stop is timed on the run's own clock: from the unplug to the moment the run raised
the loss. The board's link counts as lost after ``LOST_AFTER_S`` (0.5 s) down, so 1 s leaves
the waits of every phase half a second to look."""

from __future__ import annotations

import dataclasses
import os
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from hil.experiments.live.stops import LOST_AFTER_S, DeviceLostError
from hil.experiments.tank_run import LiveView, RunOutcome, run_experiment

# A tow far from home: positioning for it takes seconds of the simulated stage.
FAR = DEFAULT_EXPERIMENT.replace("start_m = -2.0", "start_m = -6.0").replace(
    "end_m = -5.0", "end_m = -7.5"
)
#: Where the simulated stage powers up for the homing test, mm: 3 m from home, a 30 s search.
FAR_FROM_HOME_MM = -3000.0


class PhaseView(LiveView):
    """A silent live view that hands every status text to ``on_text`` (the run's phases)."""

    def __init__(self, on_text: Callable[[str], None]) -> None:
        super().__init__(enabled=False)
        self.on_text = on_text

    def update(self, text: str, *, force: bool = False) -> None:
        self.on_text(text)


@dataclasses.dataclass
class LossRun:
    """A virtual-time run whose board is unplugged when a status text starts with ``at``."""

    tanks: list[Any]
    unplugged_at: list[float]
    raised_at: list[float]
    texts: list[str]


def _run_unplugging(
    text: str, at: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> tuple[RunOutcome, LossRun]:
    from hil.experiments import virtual_tank

    loss = LossRun([], [], [], [])
    original = virtual_tank.VirtualTank.__init__

    def keep(self: virtual_tank.VirtualTank, *args: Any, **kwargs: Any) -> None:
        original(self, *args, **kwargs)
        loss.tanks.append(self)

    monkeypatch.setattr(virtual_tank.VirtualTank, "__init__", keep)
    lost_init = DeviceLostError.__init__

    def timed(self: DeviceLostError, *args: Any) -> None:
        lost_init(self, *args)
        loss.raised_at.append(loss.tanks[0].clock.now())

    monkeypatch.setattr(DeviceLostError, "__init__", timed)

    def on_text(status: str) -> None:
        loss.texts.append(status)
        if status.startswith(at) and not loss.unplugged_at:
            loss.unplugged_at.append(loss.tanks[0].clock.now())
            loss.tanks[0].board_faults.disconnect()

    outcome = run_experiment(
        parse_experiment(text),
        folder=tmp_path / "run",
        view=PhaseView(on_text),
        virtual_time=True,
    )
    return outcome, loss


def _at_rest(tank: Any) -> float:
    """The simulated carriage's position now (m), checked to stay there."""
    now = tank.clock.now()
    x_now, x_later = tank.true_stage_position(np.array([now, now + 1.0]))
    assert x_later == x_now
    return float(x_now)


def _check_board_loss(outcome: RunOutcome, loss: LossRun) -> None:
    assert loss.unplugged_at and loss.raised_at
    delay = loss.raised_at[0] - loss.unplugged_at[0]
    assert LOST_AFTER_S <= delay <= 1.0
    assert outcome.error.startswith("DeviceLostError: board sim://board lost: its link dropped")
    assert "check its USB cable and power" in outcome.error
    assert outcome.events[-1] == (
        "alarm",
        outcome.events[-1][1],
        0,
        f"stop: error: {outcome.error}",
    )


def test_a_board_lost_while_the_stage_homes_stops_the_run_within_a_second(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from hil.experiments import sim_tank, virtual_tank

    def far_from_home() -> Any:
        return dataclasses.replace(
            sim_tank.tank_stage_config(), power_up_position_mm=FAR_FROM_HOME_MM
        )

    monkeypatch.setattr(virtual_tank, "tank_stage_config", far_from_home)
    outcome, loss = _run_unplugging(DEFAULT_EXPERIMENT, "stage: homing", monkeypatch, tmp_path)
    _check_board_loss(outcome, loss)
    assert loss.texts[-1].startswith("stage: homing ($H")  # stopped in the homing phase
    assert not outcome.estimates and outcome.samples == 0  # nothing transmitted
    # Stopped on its way home (the search covers 0.1 m/s of the 3 m): nowhere near it.
    x = _at_rest(loss.tanks[0])
    assert FAR_FROM_HOME_MM / 1000.0 < x < FAR_FROM_HOME_MM / 1000.0 + 0.2


def test_a_board_lost_while_the_stage_positions_stops_the_run_within_a_second(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    outcome, loss = _run_unplugging(FAR, "stage: positioning", monkeypatch, tmp_path)
    _check_board_loss(outcome, loss)
    assert loss.texts[-1] == "stage: positioning for the first pass"
    assert not outcome.estimates and outcome.samples == 0
    # Held on the way: past home, short of the first pass's run-up start (-5.4 m).
    x = _at_rest(loss.tanks[0])
    assert -5.4 < x < -0.01


@pytest.mark.slow
@pytest.mark.parametrize("phase", ["stage: homing", "stage: positioning"])
def test_the_built_in_tank_killed_while_the_stage_moves_stops_the_run_naming_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, phase: str
) -> None:
    """The simulated tank's process (board and stage) killed as the stage starts to home or
    to position: the run stops at the stage's next wait step, naming the tank (not a stage
    timeout when the motion would have ended)."""
    from hil.experiments import sim_tank

    started: list[sim_tank.SimulatedTankProcess] = []
    original = sim_tank.SimulatedTankProcess.__init__

    def keep(self: sim_tank.SimulatedTankProcess, *args: Any) -> None:
        original(self, *args)  # type: ignore[arg-type]
        started.append(self)

    monkeypatch.setattr(sim_tank.SimulatedTankProcess, "__init__", keep)
    texts: list[str] = []

    def on_text(status: str) -> None:
        texts.append(status)
        if status.startswith(phase) and started[0].exit_code() is None:
            os.kill(started[0].pid, signal.SIGKILL)
            started[0]._proc.wait()  # reaped: the run's next look finds it gone

    outcome = run_experiment(
        parse_experiment(FAR), folder=tmp_path / "run", view=PhaseView(on_text)
    )
    pid = started[0].pid
    assert outcome.error == (
        f"DeviceLostError: the built-in simulated tank (process {pid}) lost: its process exited"
        " with code -9; check that nothing killed it (its errors are printed above)"
    )
    assert texts[-1].startswith(phase)  # stopped in that phase
    assert outcome.samples == 0


@pytest.mark.parametrize("tank_ended", [True, False])
def test_a_link_failure_after_the_tank_ended_is_reported_as_the_tank_lost(
    tank_ended: bool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The simulated tank serves the board and the stage: once its process ended, whichever
    # link noticed first fails in its own way (here the board's transport, waiting for a DAC
    # preload credit), and the run names the tank. A link failure while the tank runs is
    # reported as it is.
    from hil.errors import TransportTimeoutError
    from hil.experiments import tank_run, virtual_tank

    ended = DeviceLostError(
        "the built-in simulated tank", "(process 1)", "its process exited with code -9",
        "that nothing killed it",
    )  # fmt: skip
    monkeypatch.setattr(
        virtual_tank.VirtualTank, "lost", lambda self, grace_s=0.0: ended if tank_ended else None
    )

    def timed_out(session: Any, max_duration_s: float, stop: Any) -> None:
        session.transmit()
        raise TransportTimeoutError("no DAC preload (credit) within 5.0 s")

    monkeypatch.setattr(tank_run, "_transmit_and_tow", timed_out)
    outcome = run_experiment(
        parse_experiment(DEFAULT_EXPERIMENT), folder=tmp_path / "run",
        view=LiveView(enabled=False), virtual_time=True,
    )  # fmt: skip
    expected = (
        f"DeviceLostError: {ended}"
        if tank_ended
        else "TransportTimeoutError: no DAC preload (credit) within 5.0 s"
    )
    assert outcome.error == expected
    assert outcome.events[-1][3] == f"stop: error: {expected}"
