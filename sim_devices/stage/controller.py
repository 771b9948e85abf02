"""A simulated GRBL 1.1h controller: a sans-IO core on an injected clock.

Bytes from the host go in with :meth:`SimulatedGrbl.receive_data`, bytes for the host come
out of :meth:`SimulatedGrbl.data_to_send`; :meth:`SimulatedGrbl.tick` brings the machine up
to the clock's present. Nothing here sleeps or reads the wall clock unless the clock given is
the wall clock, so tests advance a manual clock and run faster than real time. Motion is
computed analytically (:mod:`.motion`, :mod:`.planner`, :mod:`.homing`), so the state at any
time does not depend on how often ``tick`` is called.

The behaviour follows the GRBL 1.1h sources (``grbl/protocol.c``, ``system.c``,
``limits.c``, ``report.c``, ``planner.c``, ``gcode.c``) and ``doc/markdown/interface.md``:

- the main loop takes one line at a time, ``line_latency_s`` (~2.4 ms) each, and not while
  it is blocked: by a feed hold or jog cancel (``protocol_exec_rt_suspend``: lines sent
  during a hold wait until resume or reset), a full planner (15 blocks), a ``G4`` or an
  ``M3/M5/M8/M9`` change (both wait for the planner to empty), homing, an alarm;
- every ``ALARM:n`` is followed by 0.5 s in which the firmware does nothing
  (``report_alarm_message``: ``delay_ms(500)``); for the critical ones (1 hard limit,
  2 soft limit) ``[MSG:Reset to continue]`` comes next and clears any 0x18 that arrived
  meanwhile (``system_clear_exec_state_flag(EXEC_RESET)``: that reset is lost); then only a
  soft reset is taken, ``?`` is ignored. For the others (3 reset in motion, 6 reset while
  homing, 8/9 homing failures) the reset follows the delay by itself. A line the main loop
  was inside (a waiting ``G4``, ``$H``, a move waiting for planner room) is answered ``ok``
  when the reset aborts it, before the banner;
- soft reset: banner; ``ALARM:3`` and the banner 0.5 s later if in motion; the G92 offset
  and the G-code modes return to their defaults (``gc_init``); with hard limits on and a
  switch engaged, ``[MSG:Check Limits]`` (``CHECK_LIMITS_AT_INIT``) and the alarm lock;
- hard limits (``$21``): any change of a limit pin while not in alarm (``LIMIT_INT_vect``),
  so leaving a switch alarms too; soft limits (``$20``): ``ALARM:2`` for G-code (after a
  controlled stop if running), ``error:15`` for jogs;
- homing ``$H`` per :mod:`.homing`, ``ok`` on success; a failure reports its alarm, then
  ``ok``, then resets itself; power-up in ALARM when ``$22=1``;
- the look-ahead planner blends collinear blocks (:mod:`.planner`, ``$11``);
- status reports with ``Bf`` (``$10`` bit 1), ``FS``, ``Pn``, ``WCO`` (after a reset or an
  offset change, then every 10 reports idle / 30 busy) and ``Ov`` (every 10 / 20);
  ``G10 L2/L20``, ``G54``-``G59``, ``G92``/``G92.1`` offsets; MPos or WPos per ``$10``;
- ``$ $$ $# $G $I $N $Nx= $C $X $H $J= $SLP $RST= $x=val`` with ``system_execute_line``'s
  state checks and error codes; a blank EEPROM at power-up gives ``error:7``, the settings
  and the banner.

The machine drives X only: Y and Z exist for homing, offsets and reports; a block that
would move Y or Z is refused with ``error:20``. Overrides (0x90-0x9D) are ignored (``Ov``
stays at 100). A host-silence watchdog (not a GRBL feature; safety of this testbench): with
``host_silence_timeout_s`` set, a move in progress is feed-held when the host sends no byte
for that long or hangs up (:meth:`connection_lost`), and stays held until told otherwise.

Frames: ``physical`` positions are those of the carriage in the frame of a homed machine
(what :meth:`true_position` reports for the tank); ``machine`` positions are GRBL's step
counter (MPos). They differ by an offset until the machine is homed.
"""

from __future__ import annotations

import enum
import re
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_devices.stage.config import AXES, GrblSimConfig, format_setting, store_setting
from sim_devices.stage.gcode import GcodeError, parse_block
from sim_devices.stage.homing import AxisSwitches, run_homing
from sim_devices.stage.motion import Path, plan_stop
from sim_devices.stage.parser_state import ParserState, axes_text
from sim_devices.stage.planner import plan_blocks
from sim_devices.stage.reports import ReportRefresh

PLANNER_BLOCKS = 15
RX_BUFFER_SIZE = 128
LINE_BUFFER_SIZE = 80
ALARM_DELAY_S = 0.5
CRITICAL_ALARMS = frozenset({1, 2})
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"

__all__ = ["GrblSimConfig", "GrblState", "SimStatus", "SimulatedGrbl"]


class GrblState(enum.Enum):
    """States the simulated controller can be in (GRBL's names)."""

    IDLE = "Idle"
    RUN = "Run"
    HOLD = "Hold"
    JOG = "Jog"
    ALARM = "Alarm"
    HOME = "Home"
    CHECK = "Check"
    SLEEP = "Sleep"


_BUSY = (GrblState.RUN, GrblState.HOLD, GrblState.JOG, GrblState.HOME)
_NO_HOLD = (GrblState.ALARM, GrblState.CHECK, GrblState.SLEEP)


@dataclass(frozen=True)
class SimStatus:
    """What the simulator knows, for tests: positions mm, velocity mm/s."""

    state: GrblState
    substate: int | None
    machine_mm: float
    physical_mm: float
    velocity_mm_s: float
    alarm: int | None
    critical: bool
    watchdog_tripped: bool
    queued_blocks: int


@dataclass(frozen=True)
class _Motion:
    target_machine_mm: float
    rate_mm_s: float
    jog: bool


@dataclass
class _Sync:
    """A line waiting for the planner to empty (``protocol_buffer_synchronize``), then
    ``dwell_s``, then ``then`` (if any), then its ``ok``."""

    dwell_s: float
    then: Callable[[], None] | None = None
    dwell_end: float | None = None


class SimulatedGrbl:
    """The sans-IO simulated controller (see the module docstring).

    Parameters
    ----------
    config:
        Machine settings.
    clock:
        ``now()`` in seconds; :func:`time.monotonic` for real time, a manual clock in tests.

    Examples
    --------
    >>> t = [0.0]
    >>> sim = SimulatedGrbl(GrblSimConfig(), clock=lambda: t[0])
    >>> sim.data_to_send()
    b"\\r\\nGrbl 1.1h ['$' for help]\\r\\n"
    >>> sim.receive_data(b"G1 X-10 F300\\n")
    >>> sim.data_to_send(), (t.__setitem__(0, 0.0024), sim.tick(), sim.data_to_send())[2]
    (b'', b'ok\\r\\n')
    >>> t[0] = 60.0
    >>> sim.receive_data(b"?")
    >>> sim.data_to_send()
    b'<Idle|MPos:-10.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>\\r\\n'
    """

    def __init__(
        self, config: GrblSimConfig | None = None, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.config = config or GrblSimConfig()
        self._clock = clock
        self.settings = self.config.settings()
        self._t = clock()
        physical = (self.config.power_up_position_mm, *self.config.power_up_yz_mm)
        self._paths = [Path(self._t, p) for p in physical]
        self._path = self._paths[0]
        self._offsets = list(physical)  # physical - machine, per axis
        self._offset_times: list[float] = [self._t]
        self._offset_values: list[float] = [physical[0]]
        self._gc = ParserState()
        self._startup_lines = ["", ""]
        self._out = bytearray()
        self._partial = bytearray()
        self._lines: deque[bytes] = deque()
        self.rx_overflow_bytes = 0
        self._last_rx = self._t
        self.host_connected = False
        self.watchdog_tripped = False
        self._alarm: int | None = None
        self._alarm_until: float | None = None
        self._alarm_critical = False
        self._critical = False
        self._state = GrblState.ALARM if self.settings[22] else GrblState.IDLE
        if self.config.blank_eeprom:
            self._emit("error:7")
            self._dump_settings()
        self._restart(self._state)

    # ---------------------------------------------------------------- sans-IO interface
    def receive_data(self, data: bytes) -> None:
        """Bytes from the host, processed at the clock's present."""
        self._advance(self._clock())
        self._last_rx = self._t
        for byte in data:
            self._receive_byte(byte)
        self._arm_line()
        self._advance(self._t)  # a line due at once (no latency) runs now

    def data_to_send(self) -> bytes:
        """Bytes for the host produced so far (and forget them)."""
        out = bytes(self._out)
        self._out.clear()
        return out

    def tick(self) -> None:
        """Bring the machine up to the clock's present (finish moves, holds, alarms)."""
        self._advance(self._clock())

    def connection_made(self) -> None:
        """A host opened the port."""
        self._advance(self._clock())
        self.host_connected = True
        self._last_rx = self._t

    def connection_lost(self) -> None:
        """The host closed the port or died: with the watchdog on, hold a move at once."""
        self._advance(self._clock())
        self.host_connected = False
        if self._watchdog_applies():
            self._trip_watchdog()

    # ---------------------------------------------------------------- observation
    def status(self) -> SimStatus:
        """The simulator's state at the clock's present."""
        self._advance(self._clock())
        _, v = self._path.state_at(self._t)
        machine = self._machine(0)
        return SimStatus(
            state=self._state,
            substate=self._substate(),
            machine_mm=machine,
            physical_mm=self._offsets[0] + machine,
            velocity_mm_s=v,
            alarm=self._alarm,
            critical=self._critical or (self._alarm_until is not None and self._alarm_critical),
            watchdog_tripped=self.watchdog_tripped,
            queued_blocks=len(self._blocks),
        )

    def true_position(self, times: ArrayLike) -> NDArray[np.float64]:
        """Physical carriage position (m) at ``times`` (s), any shape, step-quantised.

        Exact for times up to the last processed instant; later times give the current plan,
        which a hold, reset or alarm may still change.
        """
        t = np.asarray(times, dtype=np.float64)
        x = self._path.position(t)
        idx = np.clip(np.searchsorted(self._offset_times, t, side="right") - 1, 0, None)
        off = np.asarray(self._offset_values, dtype=np.float64)[idx]
        spm = self.settings[100]
        return np.asarray((off + np.round((x - off) * spm) / spm) / 1000.0, dtype=np.float64)

    def carriage_motion(self, times: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The carriage's motion as planned, not step-quantised (the mechanics smooth the
        microsteps): position (m) and velocity (m/s) at ``times`` (s), any shape. Within
        :meth:`true_position`'s step (``1/$100`` mm) of it; later times as there."""
        t = np.asarray(times, dtype=np.float64)
        return self._path.position(t) / 1000.0, self._path.velocity(t) / 1000.0

    def true_velocity(self, times: ArrayLike) -> NDArray[np.float64]:
        """Carriage velocity (m/s) at ``times`` (s), any shape (not quantised)."""
        return self._path.velocity(times) / 1000.0

    # ---------------------------------------------------------------- time
    def _advance(self, now: float) -> None:
        while True:
            event = self._next_event()
            if event is None or event[0] > now:
                break
            self._t = max(self._t, event[0])
            event[1]()
            self._arm_line()
        self._t = max(self._t, now)

    def _next_event(self) -> tuple[float, Callable[[], None]] | None:
        events: list[tuple[float, int, Callable[[], None]]] = []
        if self._alarm_until is not None:
            events.append((self._alarm_until, 5, self._on_alarm_delay_end))
        if self._homing_end is not None:
            events.append((self._homing_end, 3, self._finish_homing))
        elif self._moving():
            if self.settings[21] and self._state is not GrblState.ALARM:
                t_pin = self._limit_pin_change()
                if t_pin is not None:
                    events.append((t_pin, 0, self._on_hard_limit))
            if self._watchdog_applies():
                timeout = self.config.host_silence_timeout_s
                assert timeout is not None
                events.append((max(self._last_rx + timeout, self._t), 1, self._trip_watchdog))
            if self._hold == "decel":
                events.append((self._path.end_time(), 2, self._on_hold_stopped))
            elif self._block_ends:
                events.append((self._block_ends[0], 2, self._on_block_end))
        if self._sync is not None and self._sync.dwell_end is not None:
            events.append((self._sync.dwell_end, 4, self._on_dwell_end))
        if self._line_due is not None:
            events.append((self._line_due, 6, self._on_line_due))
        if not events:
            return None
        t, _, handler = min(events, key=lambda e: (e[0], e[1]))
        return t, handler

    def _moving(self) -> bool:
        return self._homing_end is not None or self._hold == "decel" or self._running()

    def _running(self) -> bool:
        moving_states = (GrblState.RUN, GrblState.JOG)
        return bool(self._blocks) and self._hold is None and self._state in moving_states

    def _watchdog_applies(self) -> bool:
        return (
            self.config.host_silence_timeout_s is not None
            and self._running()
            and self._homing_end is None
        )

    # ---------------------------------------------------------------- reset and alarms
    def _restart(self, prior: GrblState) -> None:
        """GRBL's ``main()`` loop after power-up or a soft reset (and ``gc_init``)."""
        self._clear_motion()
        self._lines.clear()
        self._partial.clear()
        self._line_due: float | None = None
        self._line_in_progress = False
        self._critical = False
        self._alarm_until = None
        self._gc.reset([self._machine(i) for i in range(3)])
        self._refresh = ReportRefresh()
        locked = prior in (GrblState.ALARM, GrblState.SLEEP)
        self._state = GrblState.ALARM if locked else GrblState.IDLE
        self._out += f"\r\nGrbl {self.config.version} ['$' for help]\r\n".encode()
        if self.settings[21] and self._engaged_axes():
            self._state = GrblState.ALARM
            self._emit("[MSG:Check Limits]")
        if self._state is GrblState.ALARM:
            self._emit("[MSG:'$H'|'$X' to unlock]")
        else:
            self._alarm = None

    def _clear_motion(self) -> None:
        self._blocks: deque[_Motion] = deque()
        self._block_ends: list[float] = []
        self._blocked_motion: _Motion | None = None
        self._hold: str | None = None
        self._hold_direction = 0.0
        self._jog_cancel = False
        self._soft_alarm_pending = False
        self._homing_end: float | None = None
        self._homing_alarm: int | None = None
        self._sync: _Sync | None = None
        if self._state is not GrblState.ALARM:
            self._parser_sync()

    def _on_reset_byte(self) -> None:
        if self._alarm_until is not None:
            return  # inside the 0.5 s after ALARM: lost (critical) or already resetting
        if self._critical:
            self._abort()
        elif self._moving():
            for path in self._paths:
                path.stop_at(self._t)
            self._start_alarm(6 if self._homing_end is not None else 3)
        else:
            self._abort()

    def _abort(self) -> None:
        """The soft reset proper: answer the line the main loop was inside, then restart."""
        if self._line_in_progress:
            self._emit("ok")
        self._restart(self._state)

    def _start_alarm(self, code: int) -> None:
        """``mc_reset`` + ``report_alarm_message``: ALARM at once, then 0.5 s of nothing."""
        self._emit(f"ALARM:{code}")
        self._alarm = code
        self._state = GrblState.ALARM
        self._alarm_critical = code in CRITICAL_ALARMS
        self._alarm_until = self._t + ALARM_DELAY_S
        self._clear_motion()
        self._line_due = None

    def _on_alarm_delay_end(self) -> None:
        self._alarm_until = None
        if self._alarm_critical:
            self._emit("[MSG:Reset to continue]")
            self._critical = True
        else:
            self._abort()

    def _on_hard_limit(self) -> None:
        for path in self._paths:
            path.stop_at(self._t)
        self._start_alarm(1)

    def _trip_watchdog(self) -> None:
        self.watchdog_tripped = True
        self._feed_hold()

    # ---------------------------------------------------------------- planner and motion
    def _replan(self) -> None:
        """Re-plan the queued blocks from the present position and speed."""
        x, v = self._path.state_at(self._t)
        if not self._blocks:
            self._block_ends = []
            return
        off = self._offsets[0]
        targets = [b.target_machine_mm + off for b in self._blocks]
        direction = 1.0 if targets[0] >= x else -1.0
        pieces, ends = plan_blocks(
            self._t,
            x,
            max(0.0, v * direction),
            targets,
            [b.rate_mm_s for b in self._blocks],
            self.settings[120],
            self.settings[11],
        )
        self._path.replace_from(self._t, pieces)
        self._block_ends = ends

    def _on_block_end(self) -> None:
        self._blocks.popleft()
        self._block_ends.pop(0)
        if self._blocked_motion is not None:
            self._queue_block(self._blocked_motion)
            self._blocked_motion = None
            self._finish_line("ok")
        if not self._blocks:
            self._state = GrblState.IDLE
            self._start_sync_dwell()

    def _queue_block(self, motion: _Motion) -> None:
        self._blocks.append(motion)
        if self._hold is not None or self._state is GrblState.HOLD:
            return
        if self._state in (GrblState.IDLE, GrblState.RUN, GrblState.JOG):
            self._state = GrblState.JOG if motion.jog else GrblState.RUN
            self._replan()

    def _feed_hold(self) -> None:
        if self._state in (GrblState.RUN, GrblState.JOG) and self._hold is None:
            x, v = self._path.state_at(self._t)
            self._path.replace_from(self._t, plan_stop(self._t, x, v, self.settings[120]))
            self._block_ends = []
            self._hold_direction = 1.0 if v > 0 else -1.0 if v < 0 else 0.0
            self._hold = "decel"
            if self._state is GrblState.JOG:
                self._jog_cancel = True
            else:
                self._state = GrblState.HOLD
        elif self._state is GrblState.IDLE:
            self._state = GrblState.HOLD
            self._hold = "complete"

    def _on_hold_stopped(self) -> None:
        self._drop_passed_blocks()
        if self._jog_cancel:
            self._blocks.clear()
            self._jog_cancel = False
            self._hold = None
            self._state = GrblState.IDLE
            self._parser_sync()
        elif self._soft_alarm_pending:
            self._start_alarm(2)
        else:
            self._hold = "complete"

    def _drop_passed_blocks(self) -> None:
        """After a hold: forget the blocks the deceleration carried the carriage through
        (it never passes a reversal, where the planner had the speed at zero)."""
        x, _ = self._path.state_at(self._t)
        x -= self._offsets[0]
        eps = 0.5 / self.settings[100]
        s = self._hold_direction
        prev: float | None = None
        while self._blocks and s != 0.0:
            target = self._blocks[0].target_machine_mm
            if prev is not None and (target - prev) * s <= 0.0:
                break
            if (x - target) * s < -eps:
                break
            prev = target
            self._blocks.popleft()

    def _resume(self) -> None:
        if self._state is not GrblState.HOLD or self._hold != "complete":
            return
        self.watchdog_tripped = False
        self._hold = None
        if self._blocks:
            self._state = GrblState.RUN
            self._replan()
        else:
            self._state = GrblState.IDLE
            self._start_sync_dwell()

    def _jog_cancel_command(self) -> None:
        if self._state is GrblState.JOG and not self._jog_cancel:
            self._feed_hold()

    def _start_sync_dwell(self) -> None:
        if self._sync is not None and self._sync.dwell_end is None and not self._blocks:
            self._sync.dwell_end = self._t + self._sync.dwell_s

    def _on_dwell_end(self) -> None:
        sync, self._sync = self._sync, None
        assert sync is not None
        if sync.then is not None:
            sync.then()
        self._finish_line("ok")

    # ---------------------------------------------------------------- homing
    def _switches(self, axis: int) -> AxisSwitches:
        travel, margin = self.settings[130 + axis], self.config.limit_switch_margin_mm
        wired = AXES[axis] in self.config.switch_axes
        if int(self.settings[23]) >> axis & 1:
            return AxisSwitches(-travel, margin, -1.0, wired)
        return AxisSwitches(0.0, -travel - margin, 1.0, wired)

    def _engaged_axes(self) -> str:
        return "".join(
            AXES[i]
            for i in range(3)
            if self._switches(i).engaged(self._paths[i].state_at(self._t)[0])
        )

    def _start_homing(self) -> None:
        self._state = GrblState.HOME
        cycles = [[AXES.index(a) for a in cycle] for cycle in self.config.homing_cycles]
        outcome = run_homing(
            self._paths, self._t, cycles, [self._switches(i) for i in range(3)], self.settings
        )
        self._homing_end = outcome.end
        self._homing_alarm = outcome.alarm
        self._homed_axes = [i for cycle in cycles for i in cycle]

    def _finish_homing(self) -> None:
        self._homing_end = None
        if self._homing_alarm is not None:
            self._start_alarm(self._homing_alarm)
            return
        pull = self.settings[27]
        for i in self._homed_axes:
            x, _ = self._paths[i].state_at(self._t)
            machine = -self.settings[130 + i] + pull if self._switches(i).toward_home < 0 else -pull
            self._set_offset(i, x - machine)
        self._state = GrblState.IDLE
        self._alarm = None
        self._parser_sync()
        self._finish_line("ok")

    # ---------------------------------------------------------------- bytes and lines
    def _receive_byte(self, byte: int) -> None:
        blocked = self._alarm_until is not None or self._critical
        if byte == 0x18:
            self._on_reset_byte()
        elif byte == 0x3F:  # '?'
            if not blocked and self._homing_end is None:
                self._emit(self._status_report())
        elif byte in (0x21, 0x7E, 0x85):  # '!', '~', jog cancel
            if not blocked and self._homing_end is None and self._state not in _NO_HOLD:
                {0x21: self._feed_hold, 0x7E: self._resume, 0x85: self._jog_cancel_command}[byte]()
        elif byte >= 0x80:
            return  # overrides and other extended commands are not modelled
        elif byte in (0x0A, 0x0D):
            self._lines.append(bytes(self._partial))
            self._partial.clear()
        elif self._rx_used() >= RX_BUFFER_SIZE:
            self.rx_overflow_bytes += 1
        else:
            self._partial.append(byte)

    def _rx_used(self) -> int:
        return len(self._partial) + sum(len(line) + 1 for line in self._lines)

    def _main_loop_free(self) -> bool:
        return not (
            self._alarm_until is not None
            or self._critical
            or self._line_in_progress
            or self._line_due is not None
            or self._hold is not None
            or self._jog_cancel
            or self._state is GrblState.SLEEP
        )

    def _arm_line(self) -> None:
        if self._lines and self._main_loop_free():
            self._line_due = self._t + self.config.line_latency_s

    def _on_line_due(self) -> None:
        self._line_due = None
        raw = self._lines.popleft()
        self._line_in_progress = True
        text, overflow = _preparse(raw)
        if overflow:
            self._finish_line("error:11")
        elif not text:
            self._finish_line("ok")
        elif text.startswith("$"):
            self._system_command(text)
        elif self._state in (GrblState.ALARM, GrblState.JOG):
            self._finish_line("error:9")
        else:
            self._gcode(text)

    def _finish_line(self, reply: str) -> None:
        self._emit(reply)
        self._line_in_progress = False

    def _error(self, code: int) -> None:
        self._finish_line(f"error:{code}")

    # ---------------------------------------------------------------- $ commands
    def _system_command(self, text: str) -> None:
        """``system_execute_line``: state checks first, as GRBL makes them."""
        if text == "$":
            self._emit(HELP)
            return self._finish_line("ok")
        letter = text[1]
        if letter == "J":
            if self._state not in (GrblState.IDLE, GrblState.JOG):
                return self._error(8)
            if text[2:3] != "=":
                return self._error(3)
            return self._jog(text[3:])
        if letter in "$GCX":
            if len(text) != 2:
                return self._error(3)
            return {"$": self._cmd_settings, "G": self._cmd_modes, "C": self._cmd_check,
                    "X": self._cmd_unlock}[letter]()  # fmt: skip
        if self._state not in (GrblState.IDLE, GrblState.ALARM):
            return self._error(8)
        if text == "$#":
            return self._cmd_parameters()
        if letter == "H":
            if not self.settings[22]:
                return self._error(5)
            if text != "$H":
                return self._error(3)
            return self._start_homing()  # ``ok`` when homing ends
        if letter == "S":
            if text != "$SLP":
                return self._error(3)
            self._finish_line("ok")
            self._emit("[MSG:Sleeping]")
            self._state = GrblState.SLEEP
            return None
        if letter == "I":
            if text == "$I":
                self._emit(f"[VER:{self.config.version}.20190830:]")
                self._emit("[OPT:V,15,128]")
            return self._finish_line("ok")
        if letter == "R":
            return self._cmd_restore(text)
        if letter == "N":
            return self._cmd_startup(text)
        return self._write_setting(text)

    def _cmd_settings(self) -> None:
        if self._state in (GrblState.RUN, GrblState.HOLD):
            return self._error(8)
        self._dump_settings()
        return self._finish_line("ok")

    def _dump_settings(self) -> None:
        for number, value in sorted(self.settings.items()):
            self._emit(format_setting(number, value))

    def _cmd_modes(self) -> None:
        self._emit(self._gc.modes_report())
        self._finish_line("ok")

    def _cmd_check(self) -> None:
        if self._state is GrblState.CHECK:
            self._emit("[MSG:Disabled]")
            self._finish_line("ok")
            self._restart(GrblState.CHECK)
            return
        if self._state is not GrblState.IDLE:
            return self._error(8)
        self._state = GrblState.CHECK
        self._emit("[MSG:Enabled]")
        self._finish_line("ok")

    def _cmd_unlock(self) -> None:
        if self._state is GrblState.ALARM:
            self._emit("[MSG:Caution: Unlocked]")
            self._state = GrblState.IDLE
            self._alarm = None
            self._parser_sync()
        self._finish_line("ok")

    def _cmd_parameters(self) -> None:
        for line in self._gc.parameters_report():
            self._emit(line)
        self._finish_line("ok")

    def _cmd_restore(self, text: str) -> None:
        if text not in ("$RST=$", "$RST=#", "$RST=*"):
            return self._error(3)
        if text[-1] in "$*":
            self.settings = self.config.settings()
        if text[-1] in "#*":
            self._gc.coords = ParserState().coords
        self._emit("[MSG:Restoring defaults]")
        self._finish_line("ok")
        self._restart(self._state)

    def _cmd_startup(self, text: str) -> None:
        if text == "$N":
            for n, line in enumerate(self._startup_lines):
                self._emit(f"$N{n}={line}")
            return self._finish_line("ok")
        if self._state is not GrblState.IDLE:
            return self._error(8)
        match = re.fullmatch(r"\$N(\d)=(.*)", text)
        if match is None or int(match.group(1)) >= len(self._startup_lines):
            return self._error(3)
        block = parse_block(match.group(2))
        if isinstance(block, GcodeError):
            return self._error(block.code)
        self._startup_lines[int(match.group(1))] = match.group(2)
        return self._finish_line("ok")

    def _write_setting(self, text: str) -> None:
        error = store_setting(self.settings, text)
        self._finish_line("ok" if error is None else f"error:{error}")

    # ---------------------------------------------------------------- g-code
    def _jog(self, body: str) -> None:
        block = parse_block(body, jog=True)
        if isinstance(block, GcodeError):
            return self._error(block.code)
        target, feed = self._gc.jog_target(block)
        if any(abs(target[i] - self._gc.position[i]) > 1e-9 for i in (1, 2)):
            return self._error(20)  # the simulated machine drives X only
        if self.settings[20] and not self._within_travel(target):
            return self._error(15)
        moved = target[0] != self._gc.position[0]
        self._gc.position = target
        if moved:
            self._plan_or_wait(_Motion(target[0], min(feed, self.settings[110]) / 60.0, True))
        else:
            self._finish_line("ok")

    def _gcode(self, text: str) -> None:
        block = parse_block(text)
        if isinstance(block, GcodeError):
            return self._error(block.code)
        checking = self._state is GrblState.CHECK
        done = self._gc.execute(block, spindle_syncs=not checking)
        if isinstance(done, GcodeError):
            return self._error(done.code)
        if done.wco_changed:
            self._refresh.offset_changed()
        if done.target is not None:
            if self.settings[20] and not self._within_travel(done.target):
                return self._soft_limit_violation()
            moved = done.target[0] != self._gc.position[0]
            self._gc.position = done.target
            if moved and not checking:
                rate = (
                    self.settings[110] if done.rapid else min(done.feed_mm_min, self.settings[110])
                )
                motion = _Motion(done.target[0], rate / 60.0, False)
                if len(self._blocks) >= PLANNER_BLOCKS:
                    self._blocked_motion = motion
                    return None  # ``ok`` when a block ends
                self._queue_block(motion)
        if done.sync and not checking:
            program = done.program
            self._sync = _Sync(
                done.dwell_s, None if program is None else lambda: self._program(program)
            )
            self._start_sync_dwell()
            return None  # ``ok`` when the planner is empty and the dwell is over
        return self._finish_line("ok")

    def _plan_or_wait(self, motion: _Motion) -> None:
        """``mc_line``: plan the block and answer ``ok``, or wait (the line unanswered)
        until a block ends and the planner has room."""
        if len(self._blocks) >= PLANNER_BLOCKS:
            self._blocked_motion = motion
            return
        self._queue_block(motion)
        self._finish_line("ok")

    def _program(self, code: int) -> None:
        """After the sync: M0/M1 pause (a feed hold), M2/M30 end the program."""
        if code in (0, 1):
            self._state, self._hold = GrblState.HOLD, "complete"
            return
        self._gc.end_program()
        self._emit("[MSG:Pgm End]")

    def _soft_limit_violation(self) -> None:
        # limits_soft_check: a running cycle decelerates to a stop first, then ALARM:2;
        # the line stays in progress (its ``ok`` comes with the reset).
        if self._state is GrblState.RUN and self._hold is None:
            self._soft_alarm_pending = True
            self._feed_hold()
        else:
            self._start_alarm(2)

    def _within_travel(self, target: list[float]) -> bool:
        return all(-self.settings[130 + i] - 1e-9 <= target[i] <= 1e-9 for i in range(3))

    # ---------------------------------------------------------------- reports and frames
    def _substate(self) -> int | None:
        if self._state is GrblState.HOLD:
            return 0 if self._hold == "complete" else 1
        return None

    def _status_report(self) -> str:
        state = self._state.value
        if self._state is GrblState.HOLD:
            state += f":{self._substate()}"
        mask = int(self.settings[10])
        machine = [self._machine(i) for i in range(3)]
        wco = self._gc.wco()
        shown = machine if mask & 1 else [m - w for m, w in zip(machine, wco, strict=True)]
        fields = [state, f"{'MPos' if mask & 1 else 'WPos'}:{axes_text(shown)}"]
        if mask & 2:
            free = PLANNER_BLOCKS - len(self._blocks)
            fields.append(f"Bf:{free},{RX_BUFFER_SIZE - self._rx_used()}")
        _, v = self._path.state_at(self._t)
        speed = self._gc.spindle_speed if self._gc.spindle != 5 else 0.0
        fields.append(f"FS:{abs(v) * 60.0:.0f},{speed:.0f}")
        pins = self._engaged_axes()
        if pins:
            fields.append(f"Pn:{pins}")
        show_wco, show_ov = self._refresh.next(busy=self._state in _BUSY)
        if show_wco:
            fields.append(f"WCO:{axes_text(wco)}")
        if show_ov:
            fields.append("Ov:100,100,100")
            spindle = {3: "S", 4: "C"}.get(self._gc.spindle, "")
            accessories = spindle + ("F" if self._gc.coolant == 8 else "")
            if accessories:
                fields.append(f"A:{accessories}")
        return "<" + "|".join(fields) + ">"

    def _limit_pin_change(self) -> float | None:
        """First time a moving X limit pin changes state (either way), or ``None``."""
        sw = self._switches(0)
        if not sw.wired:
            return None
        x, _ = self._path.state_at(self._t)
        hits = []
        for level, outward in ((sw.home, sw.toward_home), (sw.far, -sw.toward_home)):
            inside = (x - level) * outward >= 0.0
            hits.append(self._path.first_crossing(self._t, level, -outward if inside else outward))
        found = [h for h in hits if h is not None]
        return min(found) if found else None

    def _set_offset(self, axis: int, offset: float) -> None:
        self._offsets[axis] = offset
        if axis == 0:
            self._offset_times.append(self._t)
            self._offset_values.append(offset)

    def _machine(self, axis: int) -> float:
        x, _ = self._paths[axis].state_at(self._t)
        spm = self.settings[100 + axis]
        return float(np.round((x - self._offsets[axis]) * spm) / spm)

    def _parser_sync(self) -> None:
        self._gc.position = [self._machine(i) for i in range(3)]

    def _emit(self, line: str) -> None:
        self._out += line.encode("ascii") + b"\r\n"


def _preparse(raw: bytes) -> tuple[str, bool]:
    """GRBL's character filter (``protocol_main_loop``): drop spaces and control
    characters, ``/``, ``(...)`` and ``;`` comments; upper-case; flag an overflow past
    ``LINE_BUFFER_SIZE - 1`` kept characters."""
    kept: list[str] = []
    paren = semicolon = overflow = False
    for byte in raw:
        c = chr(byte)
        if paren or semicolon or overflow:
            if c == ")" and paren:
                paren = False
            continue
        if c <= " " or c == "/":
            continue
        if c == "(":
            paren = True
        elif c == ";":
            semicolon = True
        elif len(kept) >= LINE_BUFFER_SIZE - 1:
            overflow = True
        else:
            kept.append(c.upper())
    return "".join(kept), overflow
