"""What a motion-stage driver reports, in SI units: machine state, status, profile window.

A stage tows the target along one axis (X). Positions are metres in the controller's machine
frame, speeds m/s, accelerations m/s², times seconds on the driver's clock (see
:mod:`hil.devices.clock`). The driver (:class:`~hil.devices.grbl.GrblStage`) converts to the
controller's units at the boundary (GRBL: mm, mm/min, mm/s²).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import NamedTuple


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
