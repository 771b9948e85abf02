"""The tow controller: a small state machine that drives a checked tow's passes from the
stage's status reports.

States (:class:`TowPhase`): ``READY`` (the carriage waits for the next pass: a pass starts
on the first idle report once capture flows, so no part of it goes unrecorded), ``PASS``
(the stage is running a pass; it ends on the first idle report after the pass's predicted
constant-speed window), ``TAIL`` (every pass done: the capture keeps the last echoes for
``tail_s``), and ``DONE`` is the composition's to decide (on captured samples, not the
clock). A stage alarm in any state stops the run.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Protocol

from hil.devices.stage import ProfileWindow, StageState, StageStatus
from hil.experiments.live.plan import CheckedTow


class TowPhase(enum.Enum):
    """Where the tow is (see the module docstring)."""

    READY = "ready"
    PASS = "pass"
    TAIL = "tail"


class TowStage(Protocol):
    """What the controller asks of the stage: one constant-speed pass, not waited for."""

    def run_profile(
        self,
        start: float,
        end: float,
        speed: float,
        run_up: float,
        run_down: float,
        *,
        wait: bool = True,
    ) -> ProfileWindow: ...


class StageAlarmDuringRun(RuntimeError):
    """The stage reported an alarm while the run was towing."""


@dataclass
class TowController:
    """Drives ``tow`` on ``stage``: give it every status report (:meth:`on_report`).

    ``windows``: the constant-speed window (driver clock, s) the stage predicted for each
    pass started; ``tail_until``: the driver-clock time the run's capture must reach after
    the last pass (None before).
    """

    tow: CheckedTow
    stage: TowStage
    tail_s: float
    phase: TowPhase = TowPhase.READY
    passes_started: int = 0
    windows: list[tuple[float, float]] = field(default_factory=list)
    tail_until: float | None = None

    def on_report(self, status: StageStatus, now: float, capturing: bool) -> None:
        """One status report at driver-clock time ``now``; ``capturing``: samples flow into
        the recording and the receiver. Starts the next pass, ends one, or starts the tail."""
        if status.alarm is not None:
            raise StageAlarmDuringRun(
                f"stage alarm {status.alarm} during pass {self.passes_started} of"
                f" {len(self.tow.passes)}; the stage is held: check for an obstacle or a"
                " limit switch, then home it"
            )
        idle = status.state is StageState.IDLE
        if self.phase is TowPhase.READY and idle and capturing:
            self._start_pass()
        elif self.phase is TowPhase.PASS and idle and now > self.windows[-1][1]:
            if self.passes_started < len(self.tow.passes):
                self.phase = TowPhase.READY
            else:
                self.phase, self.tail_until = TowPhase.TAIL, now + self.tail_s

    def _start_pass(self) -> None:
        plan, leg = self.tow.plan, self.tow.passes[self.passes_started]
        window = self.stage.run_profile(
            leg.first_m, leg.last_m, plan.speed_mps, plan.run_up_m, plan.run_down_m, wait=False
        )
        self.windows.append((window.t_start, window.t_end))
        self.passes_started += 1
        self.phase = TowPhase.PASS
