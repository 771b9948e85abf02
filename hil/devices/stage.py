"""The motion-stage interface, in SI units, shared by every stage driver.

A stage tows the target along one axis (X). Positions are metres in the controller's machine
frame, speeds m/s, accelerations m/s², times seconds on the driver's clock (see
:mod:`hil.devices.clock`). Drivers convert to the controller's units at the boundary (GRBL:
mm, mm/min, mm/s²).

Every motion method checks its arguments against the soft limits and the machine's rate and
acceleration limits *before* anything is sent, and raises
:class:`~hil.devices.stage_errors.StageLimitError` naming the axis, the value and the limit.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import NamedTuple, Protocol, runtime_checkable


class StageState(enum.Enum):
    """Machine state as GRBL 1.1 reports it in the first field of a status report."""

    IDLE = "Idle"
    RUN = "Run"
    HOLD = "Hold"
    JOG = "Jog"
    ALARM = "Alarm"
    DOOR = "Door"
    CHECK = "Check"
    HOME = "Home"
    SLEEP = "Sleep"


@dataclass(frozen=True)
class StageStatus:
    """One status snapshot of the stage.

    Attributes
    ----------
    state, substate:
        Machine state; ``substate`` is GRBL's number after the colon (``Hold:0`` = hold
        complete, ready to resume; ``Hold:1`` = hold in progress) or ``None``.
    position:
        Machine position of the X axis, m.
    velocity:
        Speed along X, m/s, signed with the direction of the current move (GRBL reports the
        magnitude only, with 1 mm/min resolution).
    limit_triggered:
        The X limit switch is pressed (``Pn:X``).
    alarm:
        The last alarm code reported since the last reset/unlock/homing, or ``None``.
    planner_blocks_free, rx_bytes_free:
        Free planner blocks and serial RX bytes (``Bf:``), ``None`` if not reported.
    host_time:
        Driver-clock time (s) the report describes: when the status query it answers was
        sent (the controller samples its state right after; the report reaches the host
        later, by its transmission and however long the host took to read it), or when it
        was received if no query was pending.
    reply_s:
        How long after that query the report was received, s (infinite with no query
        pending, and while a query the driver gave up as lost may still be answered late,
        as the report may be that answer: its instant is unknown).
        The controller sampled its state somewhere in between: a long reply (a stalled host
        or controller) leaves that instant uncertain by up to ``reply_s``.
    """

    state: StageState
    substate: int | None
    position: float
    velocity: float
    limit_triggered: bool
    alarm: int | None
    planner_blocks_free: int | None
    rx_bytes_free: int | None
    host_time: float
    reply_s: float = 0.0

    @property
    def moving(self) -> bool:
        """True in states where the carriage may be moving (Run, Jog, Home, Hold:1)."""
        if self.state is StageState.HOLD:
            return self.substate != 0
        return self.state in (StageState.RUN, StageState.JOG, StageState.HOME)


class ProfileWindow(NamedTuple):
    """The part of a towed run spent at constant speed between ``x_start`` and ``x_end``.

    ``t_start``/``t_end`` are driver-clock seconds at which the carriage passes ``x_start``
    and ``x_end`` (m); in between it moves at the commanded constant speed.
    """

    t_start: float
    t_end: float
    x_start: float
    x_end: float


@runtime_checkable
class Stage(Protocol):
    """A one-axis motion stage in SI units."""

    @property
    def limits(self) -> tuple[float, float]:
        """Soft limits (low, high) of the X axis, m."""
        ...

    def home(self) -> None:
        """Run the homing cycle; afterwards the position is known and alarms are cleared."""
        ...

    def move_to(
        self, x: float, v: float, a: float | None = None, *, wait: bool = True
    ) -> StageStatus:
        """Move to ``x`` (m) at up to ``v`` (m/s) with acceleration ``a`` (m/s², ``None``:
        the machine's setting); with ``wait`` return when the move is complete."""
        ...

    def jog(self, dx: float, v: float, *, wait: bool = True) -> StageStatus:
        """Jog by ``dx`` (m) at ``v`` (m/s); a jog can be cancelled at any time."""
        ...

    def run_profile(
        self,
        start: float,
        end: float,
        speed: float,
        run_up: float,
        run_down: float,
        *,
        wait: bool = True,
    ) -> ProfileWindow:
        """Tow from ``start`` to ``end`` (m) at constant ``speed`` (m/s), accelerating over
        ``run_up`` (m) before ``start`` and stopping within ``run_down`` (m) after ``end``;
        return when (driver clock) the carriage is at constant speed in the window."""
        ...

    def stop(self) -> StageStatus:
        """Controlled stop: feed hold (decelerate at the machine acceleration)."""
        ...

    def estop(self) -> StageStatus:
        """Emergency stop: immediate halt; latched until :meth:`home` or an unlock."""
        ...

    def status(self) -> StageStatus:
        """Current status (polled no faster than the driver's poll interval)."""
        ...
