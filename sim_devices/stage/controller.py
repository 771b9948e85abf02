"""A simulated GRBL 1.1 controller driving one axis: a sans-IO core on an injected clock.

Bytes from the host go in with :meth:`SimulatedGrbl.receive_data`, bytes for the host come
out of :meth:`SimulatedGrbl.data_to_send`; :meth:`SimulatedGrbl.tick` brings the machine up
to the clock's present. Nothing here sleeps or reads the wall clock unless the clock given is
the wall clock, so tests advance a manual clock and run faster than real time. Motion is
computed analytically (:mod:`sim_devices.stage.motion`), so the state at any time does not
depend on how often ``tick`` is called.

What is modelled (GRBL 1.1 behaviour, single X axis):

- trapezoidal / triangular moves under ``$110`` max rate and ``$120`` acceleration, positions
  quantised to ``1/$100`` mm steps; queued blocks run one after another from rest to rest
  (no junction blending);
- soft limits (``$20``: ``ALARM:2`` for G-code, ``error:15`` for jogs) in the machine range
  ``[-$130, 0]`` mm, hard limits (``$21``: ``ALARM:1``, instant halt) at switches just
  outside it, both critical (``[MSG:Reset to continue]``, only a soft reset is accepted);
- power-up in ALARM when homing is enabled (``$22=1``) with ``[MSG:'$H'|'$X' to unlock]``;
  homing ``$H`` (seek at ``$25``, pull-off ``$27``, locate at ``$24``, pull-off), ``ALARM:9``
  when no switch is found; unlock ``$X``;
- feed hold ``!`` (``Hold:1`` while decelerating, ``Hold:0`` when complete), resume ``~``,
  jog ``$J=`` and jog cancel 0x85 (or ``!`` while jogging: decelerate, flush, Idle), soft
  reset 0x18 (banner again; position kept; ``ALARM:3`` if reset in motion, ``ALARM:6`` if
  homing), ``G4 P`` dwell that waits for the planner to empty;
- ``$$``, ``$x=val`` with GRBL's error codes, ``$G``, ``$I``, ``$``, status reports on ``?``;
- a host-silence watchdog (not a GRBL feature; safety of this testbench): with
  ``host_silence_timeout_s`` set, a move in progress is feed-held when the host sends no byte
  for that long or hangs up (:meth:`connection_lost`), and stays held until told otherwise.

Frames: ``physical`` positions are those of the carriage in the frame of a homed machine
(what :meth:`true_position` reports for the tank); ``machine`` positions are GRBL's step
counter (MPos). They differ by an offset until the machine is homed.
"""

from __future__ import annotations

import enum
import math
import re
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from sim_devices.stage.gcode import Block, GcodeError, clean, parse_block
from sim_devices.stage.motion import Path, plan_move, plan_stop

#: GRBL 1.1 defaults as printed by ``$$`` in the interface documentation.
DEFAULT_SETTINGS: dict[int, float] = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0,
    20: 0, 21: 0, 22: 0, 23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000, 31: 0,
    32: 0, 100: 250.0, 101: 250.0, 102: 250.0, 110: 500.0, 111: 500.0, 112: 500.0,
    120: 10.0, 121: 10.0, 122: 10.0, 130: 200.0, 131: 200.0, 132: 200.0,
}  # fmt: skip
INTEGER_SETTINGS = frozenset({0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 30, 31, 32})

PLANNER_BLOCKS = 15
RX_BUFFER_SIZE = 128
MAX_LINE_LENGTH = 79
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"
_SETTING_WRITE = re.compile(r"^\$(\d+)=(.*)$")


class GrblState(enum.Enum):
    """States the simulated controller can be in (GRBL's names)."""

    IDLE = "Idle"
    RUN = "Run"
    HOLD = "Hold"
    JOG = "Jog"
    ALARM = "Alarm"
    HOME = "Home"


@dataclass(frozen=True)
class GrblSimConfig:
    """Machine and simulation settings; the GRBL ones seed ``$100``, ``$110``, ...

    Parameters
    ----------
    steps_per_mm, max_rate_mm_min, acceleration_mm_s2, max_travel_mm:
        ``$100``, ``$110`` (mm/min), ``$120`` (mm/s²), ``$130`` (mm) of the X axis.
    soft_limits, hard_limits, homing, homing_dir_invert:
        ``$20``, ``$21``, ``$22`` and bit 0 of ``$23`` (home towards -X).
    homing_feed_mm_min, homing_seek_mm_min, homing_pulloff_mm:
        ``$24``, ``$25``, ``$27``.
    status_mask:
        ``$10``: bit 0 = report MPos (else WPos), bit 1 = report ``Bf:``.
    power_up_position_mm:
        Physical carriage position at power-up in the homed frame (mm); GRBL's counter
        starts at 0 there.
    limit_switch_margin_mm:
        How far beyond the travel range the far limit switch sits (mm); the homing switch
        is at machine 0 (or ``-$130`` when homing towards -X).
    host_silence_timeout_s:
        Feed-hold a move when the host is silent this long (s); ``None`` disables it.
    version:
        Version in the banner.
    """

    steps_per_mm: float = 80.0
    max_rate_mm_min: float = 1200.0
    acceleration_mm_s2: float = 100.0
    max_travel_mm: float = 500.0
    soft_limits: bool = True
    hard_limits: bool = True
    homing: bool = True
    homing_dir_invert: bool = False
    homing_feed_mm_min: float = 100.0
    homing_seek_mm_min: float = 1000.0
    homing_pulloff_mm: float = 1.0
    status_mask: int = 3
    power_up_position_mm: float = -250.0
    limit_switch_margin_mm: float = 1.0
    host_silence_timeout_s: float | None = None
    version: str = "1.1h"

    def __post_init__(self) -> None:
        positive = (
            "steps_per_mm",
            "max_rate_mm_min",
            "acceleration_mm_s2",
            "max_travel_mm",
            "homing_feed_mm_min",
            "homing_seek_mm_min",
            "homing_pulloff_mm",
            "limit_switch_margin_mm",
        )
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ConfigError(name, value, "a finite number > 0", "see GRBL $ settings")
        if self.soft_limits and not self.homing:
            raise ConfigError(
                "soft_limits", True, "False when homing is False", "GRBL error:10 otherwise"
            )
        if not 0 <= self.status_mask <= 3:
            raise ConfigError("status_mask", self.status_mask, "an integer in [0, 3]")
        t = self.host_silence_timeout_s
        if t is not None and not (math.isfinite(t) and t > 0):
            raise ConfigError("host_silence_timeout_s", t, "None or a number of seconds > 0")

    def settings(self) -> dict[int, float]:
        """The ``$`` settings table this configuration starts with."""
        table = dict(DEFAULT_SETTINGS)
        table.update(
            {
                10: self.status_mask,
                20: int(self.soft_limits),
                21: int(self.hard_limits),
                22: int(self.homing),
                23: int(self.homing_dir_invert),
                24: self.homing_feed_mm_min,
                25: self.homing_seek_mm_min,
                27: self.homing_pulloff_mm,
                100: self.steps_per_mm,
                110: self.max_rate_mm_min,
                120: self.acceleration_mm_s2,
                130: self.max_travel_mm,
            }
        )
        return table


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
    >>> sim = SimulatedGrbl(GrblSimConfig(homing=False, soft_limits=False), clock=lambda: t[0])
    >>> sim.data_to_send()
    b"\\r\\nGrbl 1.1h ['$' for help]\\r\\n"
    >>> sim.receive_data(b"G1 X-10 F600\\n")
    >>> sim.data_to_send()
    b'ok\\r\\n'
    >>> t[0] = 60.0
    >>> sim.receive_data(b"?")
    >>> sim.data_to_send()
    b'<Idle|MPos:-10.000,0.000,0.000|Bf:15,128|FS:0,0|WCO:0.000,0.000,0.000>\\r\\n'
    """

    def __init__(
        self, config: GrblSimConfig | None = None, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.config = config or GrblSimConfig()
        self._clock = clock
        self.settings = self.config.settings()
        self._t = clock()
        self._path = Path(self._t, self.config.power_up_position_mm)
        self._offset_times: list[float] = [self._t]
        self._offset_values: list[float] = [self.config.power_up_position_mm]
        self._out = bytearray()
        self._partial = bytearray()
        self._line_overflow = False
        self._lines: deque[tuple[str, bool]] = deque()
        self.rx_overflow_bytes = 0
        self._last_rx = self._t
        self.host_connected = False
        self.watchdog_tripped = False
        self._state = GrblState.IDLE
        self._alarm: int | None = None
        self._critical = False
        self._power_up()

    # ---------------------------------------------------------------- sans-IO interface
    def receive_data(self, data: bytes) -> None:
        """Bytes from the host, processed at the clock's present."""
        self._advance(self._clock())
        self._last_rx = self._t
        for byte in data:
            self._receive_byte(byte)

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
        if self.config.host_silence_timeout_s is not None and self._watchdog_applies():
            self._trip_watchdog()

    # ---------------------------------------------------------------- observation
    def status(self) -> SimStatus:
        """The simulator's state at the clock's present."""
        self._advance(self._clock())
        x, v = self._path.state_at(self._t)
        return SimStatus(
            state=self._state,
            substate=self._substate(),
            machine_mm=self._quantise(x - self._offset()),
            physical_mm=self._offset() + self._quantise(x - self._offset()),
            velocity_mm_s=v,
            alarm=self._alarm,
            critical=self._critical,
            watchdog_tripped=self.watchdog_tripped,
            queued_blocks=len(self._queue) + (self._active is not None),
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
            self._process_lines()
        self._t = max(self._t, now)
        self._process_lines()

    def _next_event(self) -> tuple[float, Callable[[], None]] | None:
        events: list[tuple[float, int, Callable[[], None]]] = []
        if self._moving():
            if self._hard_limits_on() and self._homing_end is None:
                t_hit = self._limit_crossing()
                if t_hit is not None:
                    events.append((t_hit, 0, self._on_hard_limit))
            if self._watchdog_applies():
                timeout = self.config.host_silence_timeout_s
                assert timeout is not None
                events.append((max(self._last_rx + timeout, self._t), 1, self._trip_watchdog))
            events.append((self._path.end_time(), 2, self._on_motion_end))
        if self._dwell_end is not None:
            events.append((self._dwell_end, 3, self._on_dwell_end))
        if not events:
            return None
        t, _, handler = min(events, key=lambda e: (e[0], e[1]))
        return t, handler

    def _moving(self) -> bool:
        return (
            self._homing_end is not None
            or self._hold == "decel"
            or (self._active is not None and self._hold is None)
        )

    def _watchdog_applies(self) -> bool:
        return (
            self.config.host_silence_timeout_s is not None
            and self._state in (GrblState.RUN, GrblState.JOG)
            and self._hold is None
        )

    # ---------------------------------------------------------------- reset and alarms
    def _power_up(self) -> None:
        self._state = GrblState.ALARM if self.settings[22] else GrblState.IDLE
        self._clear_motion()
        self._banner()

    def _clear_motion(self) -> None:
        self._queue: deque[_Motion] = deque()
        self._active: _Motion | None = None
        self._hold: str | None = None
        self._jog_cancel = False
        self._soft_alarm_pending = False
        self._homing_end: float | None = None
        self._homing_fail: int | None = None
        self._homing_machine_mm = 0.0
        self._sync_dwell: float | None = None
        self._dwell_end: float | None = None
        self._lines.clear()
        self._partial.clear()
        self._line_overflow = False
        self._distance = 90
        self._motion_mode = 0
        self._feed: float | None = None
        self._parser_x = self._machine_now()
        self._reports = 0

    def _banner(self) -> None:
        self._out += f"\r\nGrbl {self.config.version} ['$' for help]\r\n".encode()
        if self._state is GrblState.ALARM:
            self._emit("[MSG:'$H'|'$X' to unlock]")

    def _soft_reset(self) -> None:
        if self._moving():
            self._path.stop_at(self._t)
            self._emit(f"ALARM:{6 if self._homing_end is not None else 3}")
            self._alarm = 6 if self._homing_end is not None else 3
            self._state = GrblState.ALARM
        self._critical = False
        if self._state is not GrblState.ALARM:
            self._state = GrblState.IDLE
        self._clear_motion()
        self._banner()

    def _raise_alarm(self, code: int, critical: bool) -> None:
        self._emit(f"ALARM:{code}")
        if critical:
            self._emit("[MSG:Reset to continue]")
        self._alarm = code
        self._critical = critical
        self._state = GrblState.ALARM
        self._clear_motion()

    def _on_hard_limit(self) -> None:
        self._path.stop_at(self._t)
        self._raise_alarm(1, critical=True)

    def _trip_watchdog(self) -> None:
        self.watchdog_tripped = True
        self._feed_hold()

    # ---------------------------------------------------------------- motion events
    def _on_motion_end(self) -> None:
        if self._homing_end is not None:
            self._finish_homing()
        elif self._hold == "decel":
            if self._jog_cancel:
                self._queue.clear()
                self._active = None
                self._hold = None
                self._jog_cancel = False
                self._state = GrblState.IDLE
                self._parser_x = self._machine_now()
            else:
                self._hold = "complete"
            if self._soft_alarm_pending:
                self._raise_alarm(2, critical=True)
        else:
            self._active = None
            if self._queue:
                self._start_next()
            else:
                self._state = GrblState.IDLE
                if self._sync_dwell is not None:
                    self._dwell_end = self._t + self._sync_dwell

    def _on_dwell_end(self) -> None:
        self._dwell_end = None
        self._sync_dwell = None
        self._emit("ok")

    def _start_next(self) -> None:
        motion = self._queue.popleft()
        x, _ = self._path.state_at(self._t)
        target = motion.target_machine_mm + self._offset()
        accel = self.settings[120]
        self._path.replace_from(self._t, plan_move(self._t, x, target, motion.rate_mm_s, accel))
        self._active = motion
        self._state = GrblState.JOG if motion.jog else GrblState.RUN

    def _feed_hold(self) -> None:
        if self._state in (GrblState.RUN, GrblState.JOG) and self._hold is None:
            x, v = self._path.state_at(self._t)
            self._path.replace_from(self._t, plan_stop(self._t, x, v, self.settings[120]))
            self._hold = "decel"
            if self._state is GrblState.JOG:
                self._jog_cancel = True
            else:
                self._state = GrblState.HOLD
        elif self._state is GrblState.IDLE:
            self._state = GrblState.HOLD
            self._hold = "complete"

    def _resume(self) -> None:
        if self._state is not GrblState.HOLD or self._hold != "complete":
            return
        self.watchdog_tripped = False
        self._hold = None
        if self._active is not None:
            self._queue.appendleft(self._active)
            self._active = None
        if self._queue:
            self._start_next()
        else:
            self._state = GrblState.IDLE
            if self._sync_dwell is not None:
                self._dwell_end = self._t + self._sync_dwell

    def _jog_cancel_command(self) -> None:
        if self._state is GrblState.JOG and not self._jog_cancel:
            self._feed_hold()

    # ---------------------------------------------------------------- homing
    def _start_homing(self) -> None:
        s = self.settings
        travel, pulloff, accel = s[130], s[27], s[120]
        seek, feed = s[25] / 60.0, s[24] / 60.0
        direction = -1.0 if int(s[23]) & 1 else 1.0
        switch = 0.0 if direction > 0 else -travel
        t = self._t
        x, _ = self._path.state_at(t)
        self._state = GrblState.HOME
        self._homing_fail = None
        self._homing_machine_mm = -pulloff if direction > 0 else -travel + pulloff
        if direction * (x - switch) < 0.0:
            self._path.replace_from(t, plan_move(t, x, x + direction * 1.5 * travel, seek, accel))
            t_hit = self._path.first_crossing(t, switch, direction)
            if t_hit is None:
                self._homing_fail = 9
                self._homing_end = self._path.end_time()
                return
            t = t_hit
        self._path.replace_from(t, plan_move(t, switch, switch - direction * pulloff, seek, accel))
        t = self._path.end_time()
        self._path.replace_from(
            t, plan_move(t, switch - direction * pulloff, switch + direction * pulloff, feed, accel)
        )
        t_hit = self._path.first_crossing(t, switch, direction)
        assert t_hit is not None  # the locate move passes the switch by construction
        t = t_hit
        self._path.replace_from(t, plan_move(t, switch, switch - direction * pulloff, seek, accel))
        self._homing_end = self._path.end_time()

    def _finish_homing(self) -> None:
        self._homing_end = None
        if self._homing_fail is not None:
            self._raise_alarm(self._homing_fail, critical=False)
            self._state = GrblState.ALARM
            self._banner()
            return
        x, _ = self._path.state_at(self._t)
        self._set_offset(x - self._homing_machine_mm)
        self._state = GrblState.IDLE
        self._alarm = None
        self._parser_x = self._machine_now()
        self._emit("ok")

    # ---------------------------------------------------------------- bytes and lines
    def _receive_byte(self, byte: int) -> None:
        if byte == 0x18:
            self._soft_reset()
        elif byte == 0x3F:  # '?'
            if not self._critical and self._homing_end is None:
                self._emit(self._status_report())
        elif byte == 0x21:  # '!'
            if not self._critical:
                self._feed_hold()
        elif byte == 0x7E:  # '~'
            if not self._critical:
                self._resume()
        elif byte == 0x85:
            if not self._critical:
                self._jog_cancel_command()
        elif byte >= 0x80 or self._critical:
            return  # other overrides are not modelled; a critical alarm ignores lines
        elif byte in (0x0A, 0x0D):
            self._lines.append((self._partial.decode("ascii", "replace"), self._line_overflow))
            self._partial.clear()
            self._line_overflow = False
            self._process_lines()
        elif self._rx_used() >= RX_BUFFER_SIZE:
            self.rx_overflow_bytes += 1
        elif len(self._partial) >= MAX_LINE_LENGTH:
            self._line_overflow = True
        else:
            self._partial.append(byte)

    def _rx_used(self) -> int:
        return len(self._partial) + sum(len(line) + 1 for line, _ in self._lines)

    def _process_lines(self) -> None:
        while self._lines and not self._critical:
            if self._homing_end is not None or self._sync_dwell is not None:
                return
            if len(self._queue) + (self._active is not None) >= PLANNER_BLOCKS:
                return
            line, overflow = self._lines.popleft()
            if overflow:
                self._emit("error:11")
            else:
                self._execute(line)

    def _execute(self, line: str) -> None:
        text = clean(line)
        if not text:
            self._emit("ok")
        elif text.startswith("$"):
            self._system_command(text)
        else:
            self._gcode(text)

    def _idle_or_alarm(self) -> bool:
        return self._state in (GrblState.IDLE, GrblState.ALARM)

    def _system_command(self, text: str) -> None:
        if text == "$":
            self._emit(HELP)
        elif text == "$$":
            if not self._idle_or_alarm():
                return self._emit("error:8")
            for number, value in sorted(self.settings.items()):
                shown = str(int(value)) if number in INTEGER_SETTINGS else f"{value:.3f}"
                self._emit(f"${number}={shown}")
        elif text == "$X":
            if not self._idle_or_alarm():
                return self._emit("error:8")
            if self._state is GrblState.ALARM:
                self._emit("[MSG:Caution: Unlocked]")
                self._state = GrblState.IDLE
                self._alarm = None
        elif text == "$H":
            if not self.settings[22]:
                return self._emit("error:5")
            if not self._idle_or_alarm():
                return self._emit("error:8")
            self._start_homing()
            return  # ``ok`` when homing completes
        elif text == "$G":
            feed = 0 if self._feed is None else self._feed
            self._emit(f"[GC:G{self._motion_mode} G54 G17 G21 G{self._distance} G94 M5 M9 T0 "
                       f"F{feed:g} S0]")  # fmt: skip
        elif text == "$I":
            self._emit(f"[VER:{self.config.version}.20190830:]")
            self._emit("[OPT:V,15,128]")
        elif text.startswith("$J="):
            return self._jog(text[3:])
        elif text.startswith("$J"):
            return self._emit("error:16")
        elif match := _SETTING_WRITE.match(text):
            return self._write_setting(int(match.group(1)), match.group(2))
        else:
            return self._emit("error:3")
        self._emit("ok")

    def _write_setting(self, number: int, text: str) -> None:
        if not self._idle_or_alarm():
            return self._emit("error:8")
        if number not in self.settings:
            return self._emit("error:3")
        try:
            value = float(text)
        except ValueError:
            return self._emit("error:2")
        if value < 0:
            return self._emit("error:4")
        if number == 0 and value < 3:
            return self._emit("error:6")
        if number == 20 and value and not self.settings[22]:
            return self._emit("error:10")
        self.settings[number] = float(int(value)) if number in INTEGER_SETTINGS else value
        if number == 22 and not value:
            self.settings[20] = 0  # GRBL forces soft limits off with homing
        self._emit("ok")

    def _jog(self, body: str) -> None:
        if self._state not in (GrblState.IDLE, GrblState.JOG) or self._jog_cancel:
            return self._emit("error:8")
        block = parse_block(body, jog=True)
        if isinstance(block, GcodeError):
            return self._emit(f"error:{block.code}")
        assert block.x is not None and block.feed is not None
        target = self._target(block)
        if self.settings[20] and not self._within_travel(target):
            return self._emit("error:15")
        self._queue_motion(_Motion(target, min(block.feed, self.settings[110]) / 60.0, True))
        self._emit("ok")

    def _gcode(self, text: str) -> None:
        if self._state in (GrblState.ALARM, GrblState.JOG):
            return self._emit("error:9")
        block = parse_block(text)
        if isinstance(block, GcodeError):
            return self._emit(f"error:{block.code}")
        motion = self._motion_mode if block.motion is None else block.motion
        feed = self._feed if block.feed is None else block.feed
        if block.x is not None and motion == 1 and feed is None:
            return self._emit("error:22")
        if block.distance is not None:
            self._distance = block.distance
        self._motion_mode, self._feed = motion, feed
        if block.dwell is not None:
            self._sync_dwell = block.dwell
            if not self._moving() and not self._queue and self._state is GrblState.IDLE:
                self._dwell_end = self._t + block.dwell
            return  # ``ok`` when the planner is empty and the dwell is over
        if block.x is not None:
            target = self._target(block)
            if self.settings[20] and not self._within_travel(target):
                self._soft_limit_violation()
                return
            rate = self.settings[110] if motion == 0 else min(feed or 0.0, self.settings[110])
            self._queue_motion(_Motion(target, rate / 60.0, False))
        self._emit("ok")

    def _soft_limit_violation(self) -> None:
        # GRBL decelerates a running cycle to a stop first, then throws the alarm.
        if self._state is GrblState.RUN and self._hold is None:
            self._soft_alarm_pending = True
            self._feed_hold()
        else:
            self._raise_alarm(2, critical=True)

    def _target(self, block: Block) -> float:
        assert block.x is not None
        distance = block.distance or (90 if block.machine_coords else self._distance)
        return block.x if distance == 90 else self._parser_x + block.x

    def _within_travel(self, machine_mm: float) -> bool:
        return -self.settings[130] - 1e-9 <= machine_mm <= 1e-9

    def _queue_motion(self, motion: _Motion) -> None:
        self._parser_x = motion.target_machine_mm
        self._queue.append(motion)
        if self._state in (GrblState.IDLE, GrblState.JOG) and self._active is None:
            self._start_next()

    # ---------------------------------------------------------------- reports and frames
    def _substate(self) -> int | None:
        if self._state is GrblState.HOLD:
            return 0 if self._hold == "complete" else 1
        return None

    def _status_report(self) -> str:
        x, v = self._path.state_at(self._t)
        machine = self._quantise(x - self._offset())
        state = self._state.value
        if self._state is GrblState.HOLD:
            state += f":{self._substate()}"
        mask = int(self.settings[10])
        fields = [state, f"{'MPos' if mask & 1 else 'WPos'}:{machine:.3f},0.000,0.000"]
        if mask & 2:
            blocks = PLANNER_BLOCKS - len(self._queue) - (self._active is not None)
            fields.append(f"Bf:{blocks},{RX_BUFFER_SIZE - self._rx_used()}")
        fields.append(f"FS:{abs(v) * 60.0:.0f},0")
        if self._on_switch(x):
            fields.append("Pn:X")
        if self._reports == 0:
            fields.append("WCO:0.000,0.000,0.000")
        self._reports += 1
        return "<" + "|".join(fields) + ">"

    def _switches(self) -> tuple[float, float]:
        travel, margin = self.settings[130], self.config.limit_switch_margin_mm
        if int(self.settings[23]) & 1:
            return -travel, margin
        return -travel - margin, 0.0

    def _on_switch(self, x: float) -> bool:
        lo, hi = self._switches()
        half_step = 0.5 / self.settings[100]
        return x <= lo + half_step or x >= hi - half_step

    def _hard_limits_on(self) -> bool:
        return bool(self.settings[21])

    def _limit_crossing(self) -> float | None:
        lo, hi = self._switches()
        half_step = 0.5 / self.settings[100]
        hits = [
            self._path.first_crossing(self._t, hi + half_step, 1.0),
            self._path.first_crossing(self._t, lo - half_step, -1.0),
        ]
        found = [h for h in hits if h is not None]
        return min(found) if found else None

    def _offset(self) -> float:
        return self._offset_values[-1]

    def _set_offset(self, offset: float) -> None:
        self._offset_times.append(self._t)
        self._offset_values.append(offset)

    def _quantise(self, machine_mm: float) -> float:
        spm = self.settings[100]
        return float(np.round(machine_mm * spm) / spm)

    def _machine_now(self) -> float:
        x, _ = self._path.state_at(self._t)
        return self._quantise(x - self._offset())

    def _emit(self, line: str) -> None:
        self._out += line.encode("ascii") + b"\r\n"
