"""GRBL 1.1 stage driver: :class:`GrblStage`, a one-axis motion stage in SI units over serial.

The link is opened by URL through the transport registry the board uses
(:mod:`hil.transports.registry`: ``serial:///dev/ttyUSB0?dtr=0``, a plain device path,
``sim://stage``, ``spy://<url>?file=...``), or is a ready transport (tests inject a scripted
one). Serial lines open with DTR and RTS low unless the URL says ``?dtr=1``: an Arduino
Uno/Nano running GRBL resets on a raised DTR, losing its position.

The protocol lives in :class:`~hil.devices.grbl_connection.GrblConnection` (bytes in,
events out, no I/O); this class is its I/O shell: it writes what the connection returns,
feeds it what it reads, waits on the injected clock and converts to SI units (GRBL speaks mm,
mm/min and mm/s²). Lines go out one at a time and wait for their ``ok``/``error:N`` (GRBL's
simple send-response flow); realtime bytes (``?``, ``!``, ``~``, 0x18, 0x85) go out at any
time.

A critical alarm (``ALARM:1`` hard limit, ``ALARM:2`` soft limit) is known from its code:
GRBL then ignores everything but a soft reset, so :meth:`GrblStage.status` answers from the
last report, :meth:`GrblStage.stop` returns at once, and :meth:`GrblStage.reset` sends 0x18
again until the banner comes (GRBL drops one that arrives in the 0.5 s after the alarm).

Safety (DESIGN.md): every move is checked against the soft limits, the max rate ``$110`` and
the acceleration ``$120`` before anything is sent; leaving a ``with GrblStage(...)`` block by
an exception (Ctrl-C included) sends a feed hold before the port is closed. Status is polled
at no more than 5 Hz (``poll_interval`` >= 0.2 s).

All waiting goes through the injected clock (:mod:`hil.devices.clock`): with a simulated
clock whose ``sleep`` advances time, tests run long moves in milliseconds of wall time.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
from collections.abc import Callable, Mapping, Sequence
from types import TracebackType
from typing import Any, Protocol

from hil.devices.clock import Clock, MonotonicClock
from hil.devices.grbl_codes import alarm_recovery, alarm_text, error_text
from hil.devices.grbl_connection import (
    QUERY_FORGOTTEN_S,
    QUERY_LOST_S,
    Alarm,
    GrblConnection,
    PendingLine,
    Report,
)
from hil.devices.grbl_protocol import (
    CYCLE_START,
    FEED_HOLD,
    JOG_CANCEL,
    ErrorResponse,
    format_dwell_line,
    format_jog_line,
    format_move_line,
)
from hil.devices.grbl_settings import STOCK_HOMING_CYCLES, GrblSettings, check_homing_cycles
from hil.devices.stage import ProfileWindow, StageState, StageStatus
from hil.devices.stage_errors import (
    StageAlarmError,
    StageCommandError,
    StageError,
    StageHeldError,
    StageLimitError,
    StageTimeoutError,
    check_within_limits,
)
from hil.errors import ConfigError

#: Every line to and from GRBL, state changes and timeouts, at DEBUG (a run's run.log).
_LOG = logging.getLogger(__name__)

#: The fastest status polling GRBL's documentation recommends (5 Hz).
MIN_POLL_INTERVAL_S = 0.2
#: Reads of whatever a link already holds when the driver opens it, at most: stale output
#: of an earlier session is dropped (a chattering line cannot hold the open up for ever).
_STALE_READS = 64

__all__ = ["MIN_POLL_INTERVAL_S", "QUERY_FORGOTTEN_S", "QUERY_LOST_S", "ByteLink", "GrblStage"]


class ByteLink(Protocol):
    """The transport contract the driver uses (:mod:`hil.transports.base`): ``read`` returns
    as soon as any bytes are there, ``b""`` after ``timeout`` seconds."""

    timeout: float

    def write(self, data: bytes) -> int | None: ...

    def read(self, size: int) -> bytes: ...

    def close(self) -> None: ...


class GrblStage:
    """One-axis (X) GRBL 1.1 motion stage in SI units.

    Parameters
    ----------
    port:
        Transport URL or device path (:mod:`hil.transports.registry`; the baud rate is the
        URL's ``?baud=``, default GRBL 1.1's 115200), or an open transport (not closed by
        the driver).
    clock:
        Clock for all waits and timestamps (default: the wall clock).
    soft_limits:
        Optional narrower (low, high) limits in m inside GRBL's machine range
        ``[-$130, 0]`` mm; moves outside are refused before sending.
    poll_interval:
        Seconds between status queries while waiting, >= 0.2 (at most 5 Hz).
    read_timeout:
        Real seconds one read blocks waiting for bytes.
    wait_step:
        Clock seconds slept between reads when nothing arrived.
    response_timeout:
        Clock seconds to wait for ``ok``/``error`` of a non-motion line.
    reset_on_open:
        Send a soft reset (0x18) on open and wait for the banner (position is kept by GRBL
        when idle); otherwise only check that GRBL answers a status query.
    open_timeout:
        Clock seconds to wait for the banner / first status report on open.
    dtr, rts:
        Level of the serial modem lines when the driver opens a serial URL or path (a
        ``?dtr=``/``?rts=`` in the URL wins). Low by default: an Arduino Uno/Nano resets on
        a raised DTR.
    homing_cycles:
        The axes GRBL homes together, cycle by cycle (the firmware's ``HOMING_CYCLE_n``
        masks; stock GRBL 1.1h: ``("Z", "XY")``); the ``$H`` timeout covers them all.
    transport_options:
        More keyword options for the transport opener of a URL (``config=`` a
        ``GrblSimConfig`` for ``sim://stage``).

    Examples
    --------
    >>> GrblStage("loop://", poll_interval=0.05)
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: poll_interval = 0.05 is not allowed: must be >= 0.2 s (status \
polling at no more than 5 Hz); use the default 0.2
    """

    def __init__(
        self,
        port: str | ByteLink,
        *,
        clock: Clock | None = None,
        soft_limits: tuple[float, float] | None = None,
        poll_interval: float = MIN_POLL_INTERVAL_S,
        read_timeout: float = 0.02,
        wait_step: float = 0.02,
        response_timeout: float = 10.0,
        reset_on_open: bool = True,
        open_timeout: float = 5.0,
        dtr: bool = False,
        rts: bool = False,
        homing_cycles: Sequence[str] = STOCK_HOMING_CYCLES,
        transport_options: Mapping[str, Any] | None = None,
    ) -> None:
        if not (math.isfinite(poll_interval) and poll_interval >= MIN_POLL_INTERVAL_S):
            raise ConfigError(
                "poll_interval",
                poll_interval,
                f">= {MIN_POLL_INTERVAL_S} s (status polling at no more than 5 Hz)",
                "use the default 0.2",
            )
        for name, value in (
            ("read_timeout", read_timeout),
            ("wait_step", wait_step),
            ("response_timeout", response_timeout),
            ("open_timeout", open_timeout),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(name, value, "a number of seconds > 0")
        if soft_limits is not None and not (
            len(soft_limits) == 2 and all(math.isfinite(v) for v in soft_limits)
            and soft_limits[0] < soft_limits[1]
        ):  # fmt: skip
            raise ConfigError(
                "soft_limits", soft_limits, "(low, high) in m with low < high", "e.g. (-0.4, 0)"
            )
        self._homing_cycles = check_homing_cycles(homing_cycles)
        self._port = port
        self._dtr, self._rts = dtr, rts
        self._transport_options = dict(transport_options or {})
        self._clock: Clock = clock or MonotonicClock()
        self._user_limits = soft_limits
        self.poll_interval = poll_interval
        self._read_timeout = read_timeout
        self._wait_step = wait_step
        self.response_timeout = response_timeout
        self._reset_on_open = reset_on_open
        self._open_timeout = open_timeout
        self._ser: ByteLink | None = None
        self._owns_port = isinstance(port, str)
        self.connection = GrblConnection()
        self._last_query = -math.inf
        self._last_status: StageStatus | None = None
        self._new_alarm: int | None = None
        self._estop_latched = False
        self._direction = 1.0
        self._settings: GrblSettings | None = None
        self._original_accel: float | None = None
        #: Called at every step of every wait for the controller (a few times per 0.1 s, homing
        #: and moves included); whatever it raises abandons the wait and reaches the caller.
        #: A run sets it to check its other devices, so that one lost while the stage homes
        #: or positions stops the run at once, not when the motion ends.
        self.while_waiting: Callable[[], None] | None = None
        self._homing = False

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> GrblStage:
        """Open the port, sync with GRBL, read the ``$$`` settings and the status."""
        if isinstance(self._port, str):
            from hil.transports.registry import open_transport

            self._ser = open_transport(
                self._port,
                timeout=self._read_timeout,
                dtr=self._dtr,
                rts=self._rts,
                clock=self._clock.now,
                **self._transport_options,
            )
        else:
            self._ser = self._port
            with contextlib.suppress(AttributeError):
                self._ser.timeout = self._read_timeout
        try:
            self._sync()
        except BaseException:
            self.close()
            raise
        return self

    def _sync(self) -> None:
        """Drop stale input, reset GRBL (or check it answers), read ``$$`` and the status."""
        ser = self._require_open()
        for _ in range(_STALE_READS):
            if not ser.read(4096):
                break
        self.connection.discard_partial()
        if self._reset_on_open:
            self._soft_reset_and_wait(self._open_timeout)
        self._settings = self._read_settings()
        if self._settings.report_inches:
            raise ConfigError(
                "report_inches ($13)", True, "False (mm reports)", "send $13=0 to the controller"
            )
        self._check_user_limits()
        self._query_status(self._open_timeout)

    def close(self) -> None:
        """Restore a changed acceleration and close the port (if the driver opened it).

        In a critical alarm GRBL ignores lines until reset: nothing is sent then."""
        if self._ser is None:
            return
        try:
            if (
                self._original_accel is not None
                and self._settings is not None
                and not self.connection.critical
            ):
                with contextlib.suppress(StageError):
                    self.write_setting("acceleration_x", self._original_accel)
        finally:
            if self._owns_port:
                self._ser.close()
            self._ser = None

    def __enter__(self) -> GrblStage:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is not None and self._ser is not None:
            # Any failure inside the block (Ctrl-C included) stops the carriage first.
            with contextlib.suppress(Exception):
                self._ser.write(FEED_HOLD)
            self._original_accel = None  # no more lines to a controller we know is in trouble
        self.close()

    # ------------------------------------------------------------------ properties
    @property
    def url(self) -> str:
        """The controller's URL (or its link's), as every stage error and log line names
        it."""
        if isinstance(self._port, str):
            return self._port
        return str(getattr(self._port, "url", type(self._port).__name__))

    @property
    def settings(self) -> GrblSettings:
        """The controller's settings read at open (updated by :meth:`write_setting`)."""
        if self._settings is None:
            raise StageError(
                "the stage is not open: call open() or use 'with GrblStage(...)'", url=self.url
            )
        return self._settings

    @property
    def limits(self) -> tuple[float, float]:
        """Soft limits (low, high) of X in m: GRBL's ``[-$130, 0]`` mm, narrowed by the
        ``soft_limits`` given to the constructor."""
        low, high = -self.settings.travel, 0.0
        if self._user_limits is not None:
            low, high = max(low, self._user_limits[0]), min(high, self._user_limits[1])
        return low, high

    @property
    def last_status(self) -> StageStatus | None:
        """The last status report received (no query)."""
        return self._last_status

    @property
    def transport(self) -> ByteLink:
        """The open link to GRBL (what the URL opened, or the transport given)."""
        return self._require_open()

    @property
    def messages(self) -> list[str]:
        """Push messages received (``[MSG:...]`` as sent), oldest first."""
        return self.connection.messages

    @property
    def unrecognised(self) -> list[str]:
        """Lines received that are not GRBL 1.1, oldest first."""
        return self.connection.noise

    @property
    def critical(self) -> bool:
        """GRBL is held by a critical alarm (``ALARM:1``/``ALARM:2``) until :meth:`reset`."""
        return self.connection.critical

    # ------------------------------------------------------------------ commands
    def status(self) -> StageStatus:
        """Query and return the current status (waits so as to poll at most 5 Hz).

        Never raises for an alarm: the status says it. In a critical alarm GRBL answers no
        query, so the answer is what is known: the last report's position and time, state
        ALARM with the alarm's code, velocity 0 (GRBL has halted)."""
        self._require_open()
        if not self.connection.critical:
            self._clock.sleep(self._last_query + self.poll_interval - self._clock.now())
            self._query_status(self.response_timeout)
        self._new_alarm = None  # reported in the status
        if self.connection.critical:
            return self._known_status()
        assert self._last_status is not None
        return self._last_status

    def _known_status(self) -> StageStatus:
        """The status in a critical alarm, from the last report (GRBL answers none)."""
        code = self.connection.alarm
        if self._last_status is None:
            now = self._clock.now()
            return StageStatus(
                StageState.ALARM, None, math.nan, 0.0, False, code, None, None, now, math.inf
            )
        return dataclasses.replace(
            self._last_status, state=StageState.ALARM, substate=None, velocity=0.0, alarm=code
        )

    def home(self) -> StageStatus:
        """Run the homing cycle ``$H``; clears alarms and an e-stop latch. Refused first as
        :meth:`check_home` refuses."""
        self.check_home()
        # No polling while homing; the timeout covers the longest search of every cycle
        # (GRBL gives up with ALARM:9 before it), with a margin for acceleration.
        # Until '$H' is answered GRBL may be homing: a wait abandoned meanwhile (a timeout,
        # while_waiting) leaves the cycle running, which only a soft reset ends (stop()).
        self._homing = True
        self._command("$H", timeout=self.homing_timeout(), poll=False)
        self._homing = False
        self._estop_latched = False
        return self.status()

    def homing_timeout(self) -> float:
        """Clock seconds ``$H`` may take: 1.5 x GRBL's longest homing of every axis in
        ``homing_cycles`` (:meth:`GrblSettings.homing_time_bound`) + ``response_timeout``."""
        return 1.5 * self.settings.homing_time_bound(self._homing_cycles) + self.response_timeout

    def make_ready(self, on_step: Callable[[str], None] | None = None) -> StageStatus:
        """Leave any alarm the way a run does before its first move.

        A critical alarm is reset first (0x18). Then, in ALARM (power-up or reset with
        homing enabled, an earlier alarm): home with ``$H`` when homing is enabled
        (``$22=1``), else unlock with ``$X`` (no switches to find the origin with: the
        position is GRBL's count). An :meth:`estop` latch is cleared the same way.
        ``on_step(text)`` hears each action before it starts (progress for the user).
        """

        def step(text: str) -> None:
            if on_step is not None:
                on_step(text)

        if self.connection.critical:
            code = self.connection.alarm
            step(f"soft reset after ALARM:{code} ({alarm_text(code or 0).split(':')[0]})")
            status = self.reset()
        else:
            status = self.status()
        if status.state is not StageState.ALARM and not self._estop_latched:
            return status
        if self.settings.homing_enabled:
            step(f"homing ($H, up to {self.homing_timeout():.0f} s)")
            return self.home()
        step("unlocking ($X; homing is disabled, $22=0)")
        return self.unlock()

    def unlock(self) -> StageStatus:
        """Kill the alarm lock ``$X`` (position may be wrong: home when you can)."""
        self._require_not_critical()
        self._command("$X")
        self._estop_latched = False
        return self.status()

    def reset(self) -> StageStatus:
        """Soft reset (0x18) and wait for the banner; needed after a critical alarm. The
        reset is sent again every :data:`~hil.devices.grbl_connection.RESET_RETRY_S` without
        an answer (GRBL drops one that arrives in the 0.5 s after a critical alarm)."""
        self._require_open()
        self._soft_reset_and_wait(self.response_timeout)
        return self.status()

    def move_to(
        self, x: float, v: float, a: float | None = None, *, wait: bool = True
    ) -> StageStatus:
        """Move X to ``x`` (m) at up to ``v`` (m/s); ``a`` (m/s²) changes ``$120`` first.

        With ``wait`` return after the move completed (``G4 P0`` answers then); raises
        :class:`StageHeldError` if it is feed-held on the way.
        """
        self.check_move(x, v, a)
        if a is not None:
            self._set_acceleration(a)
        start = self._position_estimate()
        self._direction = 1.0 if x >= start else -1.0
        self._command(format_move_line(x * 1000.0, v * 60000.0))
        if wait:
            self._wait_motion_done(self._move_duration(abs(x - start), v))
        return self.status()

    def jog(self, dx: float, v: float, *, wait: bool = True) -> StageStatus:
        """Jog X by ``dx`` (m) at ``v`` (m/s) with ``$J=``; cancel with :meth:`jog_cancel`.
        Refused first as :meth:`check_jog` refuses."""
        start = self.check_jog(dx, v)
        self._direction = 1.0 if dx >= 0 else -1.0
        self._command(format_jog_line(dx * 1000.0, v * 60000.0))
        if not wait:
            return self.status()
        count = self.connection.reports
        step = self.settings.step
        self._wait(
            lambda: (
                self.connection.reports > count
                and self._last_status is not None
                and self._last_status.state is StageState.IDLE
                and abs(self._last_status.position - (start + dx)) <= step
            ),
            self._move_duration(abs(dx), v) * 1.5 + self.response_timeout,
            "the jog to finish",
            poll=True,
        )
        return self.status()

    def jog_cancel(self) -> StageStatus:
        """Cancel jogging (0x85): decelerate, flush queued jogs, return to Idle."""
        self._write_realtime(JOG_CANCEL)
        return self._wait_state(lambda s: s.state is StageState.IDLE, "Idle after jog cancel")

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
        """Tow from ``start`` to ``end`` (m) at constant ``speed`` (m/s).

        Positions at ``start - run_up`` first (at the max rate; not when the last status
        report has the carriage at rest there, within half a step), then one linear move to
        ``end + run_down`` at ``speed``. ``run_up``/``run_down`` (m) must cover the
        acceleration distance ``speed**2 / (2 * $120)``. Returns the driver-clock window in
        which the carriage is between ``start`` and ``end`` at constant speed, predicted from
        the time GRBL accepted the move (latency of the ``ok``: one serial round trip).
        """
        if not (math.isfinite(start) and math.isfinite(end)) or start == end:
            raise ConfigError("end", end, f"a finite position != start ({start} m)")
        self._check_speed("speed", speed)
        accel = self.settings.acceleration
        need = speed * speed / (2.0 * accel)
        for name, value in (("run_up", run_up), ("run_down", run_down)):
            if not (math.isfinite(value) and value >= need * (1.0 - 1e-9)):
                raise StageLimitError(
                    name,
                    value,
                    f">= {need:.6g} m, the distance to reach {speed:g} m/s at the axis X "
                    f"acceleration $120 = {self.settings.acceleration_x:.3f} mm/s^2",
                    "lengthen it or lower the speed",
                )
        d = 1.0 if end > start else -1.0
        x0, x1 = start - d * run_up, end + d * run_down
        self.check_position("run-up start x (start - run_up)", x0)
        self.check_position("run-down end x (end + run_down)", x1)
        here = self._last_status
        if not (
            here is not None
            and here.state is StageState.IDLE
            and abs(here.position - x0) <= 0.5 * self.settings.step
        ):
            # Not already resting there (a tow's next pass starts where the last one ended):
            # positioning ends by waiting for the planner and a 5 Hz status poll, up to 0.2 s
            # in which a caller streaming meanwhile (hil tank-run) captures nothing.
            self.move_to(x0, self.settings.max_rate)
        self._direction = d
        self._command(format_move_line(x1 * 1000.0, speed * 60000.0))
        t0 = self._clock.now()
        t_start = t0 + speed / accel + (run_up - need) / speed
        window = ProfileWindow(t_start, t_start + abs(end - start) / speed, start, end)
        if wait:
            self._wait_motion_done(self._move_duration(abs(x1 - x0), speed))
        return window

    def stop(self, *, cancel: bool = True) -> StageStatus:
        """Controlled stop: feed hold ``!`` and wait until stopped; with ``cancel`` then drop
        the rest of the move (soft reset from ``Hold:0``: GRBL keeps the position, no alarm).
        A homing cycle left unanswered (:meth:`home` abandoned) is ended by a soft reset
        instead, the only way GRBL stops homing (ALARM:6 follows: home again).
        Without ``cancel`` the stage stays held; :meth:`resume` continues. In a critical
        alarm GRBL has halted already and answers nothing: the known status returns at once.
        """
        self._require_open()
        if self.connection.critical:
            return self._known_status()
        if self._homing:
            # GRBL ignores a feed hold while it homes; a soft reset ends the cycle (it then
            # reports ALARM:6, homing reset, and needs homing again).
            status = self.reset()
            self._homing = False
            return status
        self._write_realtime(FEED_HOLD)
        status = self._wait_state(
            lambda s: (
                (s.state is StageState.HOLD and s.substate == 0)
                or s.state in (StageState.IDLE, StageState.ALARM)
            ),
            "the feed hold to complete",
            raise_alarm=False,
        )
        if self.connection.critical:
            return self._known_status()
        if cancel and status.state is StageState.HOLD:
            return self.reset()
        return status

    def resume(self) -> StageStatus:
        """Cycle start ``~``: resume a completed feed hold."""
        self._write_realtime(CYCLE_START)
        return self._wait_state(lambda s: s.state is not StageState.HOLD, "the hold to end")

    def estop(self) -> StageStatus:
        """Emergency stop: soft reset 0x18 at once (GRBL halts without deceleration and
        alarms if it was moving). Latched: motion is refused until :meth:`home` or
        :meth:`unlock`."""
        self._require_open()
        self._estop_latched = True
        self._soft_reset_and_wait(self.response_timeout)
        return self.status()

    def build_info(self) -> tuple[str, ...]:
        """GRBL's answer to ``$I``: its ``[VER:...]`` and ``[OPT:...]`` lines, as received
        (firmware version and build date, compile options); allowed in any state."""
        before = len(self.connection.messages)
        self._command("$I")
        return tuple(
            m for m in self.connection.messages[before:] if m.startswith(("[VER:", "[OPT:"))
        )

    def write_setting(self, name: str, value: Any) -> None:
        """Validate and write one ``$`` setting (by its attribute name, e.g.
        ``"max_rate_x"``); a bad value raises before anything is sent."""
        line = self.settings.check(name, value)
        self._command(line)
        self._settings = self.settings.updated(name, value)

    # ------------------------------------------------------------------ checks
    # Each motion command runs its check first; a caller runs it on its own to be refused
    # before it reports what it is about to do (hil stage's progress lines).
    def check_home(self) -> None:
        """Refuse :meth:`home` before anything is sent: homing disabled (``$22=0``, a
        :class:`~hil.errors.ConfigError` saying how to enable it or unlock instead) or a
        critical alarm (:class:`StageAlarmError`: reset first)."""
        if not self.settings.homing_enabled:
            raise ConfigError(
                "homing_enabled ($22)",
                False,
                "True to run a homing cycle",
                "set $22=1 on the controller (write_setting('homing_enabled', True)), or unlock"
                " it with $X instead (GrblStage.unlock(), hil stage unlock)",
            )
        self._require_not_critical()

    def check_move(self, x: float, v: float, a: float | None = None) -> None:
        """Refuse :meth:`move_to` ``(x m, v m/s, a m/s²)`` before anything is sent: a target
        outside the soft limits, a speed or acceleration out of range
        (:class:`StageLimitError`), or a stage that may not move (alarm, e-stop latch:
        :class:`StageAlarmError`; feed hold: :class:`StageHeldError`)."""
        self.check_position("x", x)
        self._check_speed("v", v)
        if a is not None:
            self._check_acceleration(a)
        self._require_ready()

    def check_jog(self, dx: float, v: float) -> float:
        """Refuse :meth:`jog` ``(dx m, v m/s)`` before anything is sent, as :meth:`check_move`
        refuses a move to the jog's target; return the position the jog starts from (m,
        from a status query)."""
        self._check_speed("v", v)
        self._require_ready()
        start = self.status().position
        self.check_position("jog target x", start + dx)
        return start

    def check_position(self, name: str, x: float) -> None:
        """Refuse a target ``x`` (m) named ``name`` outside :attr:`limits` (half a step of
        tolerance: GRBL rounds a target to its steps) before anything is sent
        (:class:`StageLimitError`)."""
        check_within_limits(
            name, x, self.limits, tolerance_m=0.5 * self.settings.step,
            travel=f" (max travel $130 = {self.settings.max_travel_x:.3f} mm, machine range"
            " [-travel, 0])",
        )  # fmt: skip

    def _check_speed(self, name: str, v: float) -> None:
        vmax = self.settings.max_rate
        if not (math.isfinite(v) and 0.0 < v <= vmax * (1.0 + 1e-9)):
            raise StageLimitError(
                f"{name} (axis X)",
                v,
                f"in (0, {vmax:.6g}] m/s, the axis X max rate $110 = "
                f"{self.settings.max_rate_x:.3f} mm/min",
                "lower the speed or raise $110 with write_setting('max_rate_x', ...)",
            )

    def _check_acceleration(self, a: float) -> None:
        cap = (
            self._original_accel if self._original_accel is not None
            else self.settings.acceleration_x
        ) / 1000.0  # fmt: skip
        if not (math.isfinite(a) and 0.0 < a <= cap * (1.0 + 1e-9)):
            raise StageLimitError(
                "a (axis X)",
                a,
                f"in (0, {cap:.6g}] m/s^2, the axis X acceleration $120 configured at open",
                "lower the acceleration",
            )

    def _set_acceleration(self, a: float) -> None:
        if abs(a * 1000.0 - self.settings.acceleration_x) < 1e-6:
            return
        if self._original_accel is None:
            self._original_accel = self.settings.acceleration_x
        self.write_setting("acceleration_x", a * 1000.0)

    def _require_open(self) -> ByteLink:
        if self._ser is None:
            raise StageError(
                "the stage is not open: call open() or use 'with GrblStage(...)'", url=self.url
            )
        return self._ser

    def _recovery(self, code: int | None) -> str:
        homing = None if self._settings is None else self._settings.homing_enabled
        return alarm_recovery(code, homing=homing)

    def _require_not_critical(self) -> None:
        self._require_open()
        if self.connection.critical:
            code = self.connection.alarm
            raise StageAlarmError(code, self._alarm_words(), self._recovery(code), url=self.url)

    def _require_ready(self) -> None:
        """Refuse motion while latched, in alarm or held, with what to do about it."""
        self._require_not_critical()
        if self._estop_latched:
            text = "emergency stop latched by estop()"
            code = self.connection.alarm
            if code is not None:
                text += f"; controller ALARM:{code} ({alarm_text(code)})"
            raise StageAlarmError(
                None,
                text,
                "check that the axis is clear, then home with $H (GrblStage.home()) or "
                "unlock with $X (GrblStage.unlock())",
                url=self.url,
            )
        status = self._last_status
        if status is not None and status.state is StageState.ALARM:
            code = self.connection.alarm
            raise StageAlarmError(code, self._alarm_words(), self._recovery(code), url=self.url)
        if status is not None and status.state is StageState.HOLD:
            raise StageHeldError(
                "stage is in a feed hold: call resume() to continue the held move or stop() "
                "to cancel it",
                url=self.url,
            )

    def _alarm_words(self) -> str:
        code = self.connection.alarm
        if code is None:
            return "locked at power-up or reset; GRBL needs homing or an unlock"
        return alarm_text(code)

    # ------------------------------------------------------------------ I/O

    def _write(self, data: bytes) -> None:
        if _LOG.isEnabledFor(logging.DEBUG):
            text = data.decode("ascii", "backslashreplace").rstrip("\n")
            _LOG.debug("stage %s -> %s", self.url, text if text.isprintable() else repr(data))
        self._require_open().write(data)

    def _write_realtime(self, byte: bytes) -> None:
        self._write(byte)

    def _command(self, line: str, *, timeout: float | None = None, poll: bool = False) -> None:
        """Send one line and wait for its ``ok``; raise on ``error:N`` or an alarm."""
        pending = self._send_line(line)
        self._wait_answer(pending, self.response_timeout if timeout is None else timeout, poll)
        if pending.reset:
            raise StageError(
                f"GRBL reset while {line!r} was pending; it was not executed", url=self.url
            )
        if isinstance(pending.result, ErrorResponse):
            code = pending.result.code
            raise StageCommandError(code, error_text(code), line, url=self.url)

    def _wait_answer(self, pending: PendingLine, timeout: float, poll: bool) -> None:
        """Wait for ``pending``'s ``ok``/``error:N`` (or the reset that drops it)."""
        self._wait(lambda: pending.done, timeout, f"a response to {pending.line!r}", poll=poll)

    def _send_line(self, line: str) -> PendingLine:
        pending, data = self.connection.send_line(line)
        self._write(data)
        return pending

    def _wait_motion_done(self, expected_s: float) -> None:
        """Wait for the planner to empty (``G4 P0`` answers then), polling the status."""
        pending = self._send_line(format_dwell_line())
        timeout = 1.5 * expected_s + self.response_timeout
        self._wait(
            lambda: pending.done or self._held(),
            timeout,
            "the move to finish",
            poll=True,
        )
        if pending.result is None:
            raise StageHeldError(
                "the move was feed-held before reaching its target: call resume() to "
                "continue or stop() to cancel",
                url=self.url,
            )

    def _held(self) -> bool:
        s = self._last_status
        return s is not None and s.state is StageState.HOLD

    def _wait_state(
        self, done: Callable[[StageStatus], bool], what: str, *, raise_alarm: bool = True
    ) -> StageStatus:
        count = self.connection.reports
        self._wait(
            lambda: (
                self.connection.critical
                or (
                    self.connection.reports > count
                    and self._last_status is not None
                    and done(self._last_status)
                )
            ),
            self.response_timeout,
            what,
            poll=True,
            raise_alarm=raise_alarm,
        )
        assert self._last_status is not None
        return self._last_status

    def _query_status(self, timeout: float) -> None:
        """Query and wait for the answer, or for a critical alarm (no answer then)."""
        self._query()
        count = self.connection.reports  # after the reports read before the '?' went out
        self._wait(
            lambda: self.connection.reports > count or self.connection.critical,
            timeout,
            "a status report",
            poll=True,
            raise_alarm=False,
        )

    def _query(self) -> None:
        """Send '?' unless one is in flight (see :meth:`GrblConnection.send_query`)."""
        ser = self._require_open()
        if self.connection.expects_report():
            # A report already received answers the query in flight (or one given up as
            # lost, answered late): read it first, so the next '?' is paired with its own.
            while self._receive(ser):
                pass
        if self.connection.critical:
            return  # GRBL answers no query until reset
        data = self.connection.send_query(self._clock.now())
        if data:
            self._last_query = self.connection.last_query
            self._write(data)

    def _soft_reset_and_wait(self, timeout: float) -> None:
        banners = self.connection.banners
        self._write(self.connection.send_reset(self._clock.now()))
        try:
            self._wait(
                lambda: self.connection.banners > banners,
                timeout,
                "banner",
                raise_alarm=False,
            )
        except StageTimeoutError:
            self.connection.abandon_reset()  # no 0x18 resent behind a later command
            raise
        # An ALARM:3 (reset in motion) is expected here: it is kept in the status, not raised.
        self._new_alarm = None

    def _read_settings(self) -> GrblSettings:
        """``$$``, asked again if a reset drops it: a board that restarts as the port opens
        (an Arduino on DTR) prints its power-up banner late, after the driver's own."""
        for _ in range(3):
            self.connection.settings.clear()
            pending = self._send_line("$$")
            self._wait_answer(pending, self.response_timeout, poll=False)
            if not pending.reset:
                break
        if isinstance(pending.result, ErrorResponse) or pending.reset:
            raise StageError(
                f"GRBL did not answer '$$' with its settings ({pending.result or 'reset'}): "
                "check that the firmware is GRBL 1.1 and that nothing else resets it",
                url=self.url,
            )
        return GrblSettings(self.connection.settings)

    def _wait(
        self,
        done: Callable[[], bool],
        timeout: float,
        what: str,
        *,
        poll: bool = False,
        raise_alarm: bool = True,
    ) -> None:
        """Read and handle input until ``done()``; meanwhile query the status every
        ``poll_interval`` (with ``poll``) and resend a soft reset GRBL dropped. Raises
        :class:`StageAlarmError` for an alarm received meanwhile (with ``raise_alarm``) and
        :class:`StageTimeoutError` after ``timeout`` clock seconds."""
        ser = self._require_open()
        deadline = self._clock.now() + timeout
        while True:
            got = self._receive(ser)
            if raise_alarm and self._new_alarm is not None:
                code, self._new_alarm = self._new_alarm, None
                raise StageAlarmError(code, alarm_text(code), self._recovery(code), url=self.url)
            if done():
                return
            if self.while_waiting is not None:
                self.while_waiting()
            now = self._clock.now()
            if now >= deadline:
                _LOG.debug(
                    "stage %s: timed out after %.3g s waiting for %s", self.url, timeout, what
                )
                raise StageTimeoutError(
                    f"no {what} from GRBL within {timeout:.3g} s: check the cable, the port "
                    "and the controller's power",
                    url=self.url,
                )
            if self.connection.reset_due(now):
                self._write(self.connection.send_reset(now))
            elif (
                poll
                and not self.connection.critical
                and now - self._last_query >= (self.poll_interval)
            ):
                self._query()
            if not got:
                self._clock.sleep(self._wait_step)

    def _receive(self, ser: ByteLink) -> bool:
        """Read what is there (waiting up to the read timeout) and handle its events."""
        data = ser.read(4096)
        if not data:
            return False
        events = self.connection.receive_data(data, self._clock.now())
        debug = _LOG.isEnabledFor(logging.DEBUG)
        for line, event in zip(self.connection.last_lines, events, strict=True):
            if debug:
                _LOG.debug("stage %s <- %s", self.url, line)
            if isinstance(event, Report):
                before = self._last_status
                self._last_status = self._to_status(event)
                if before is None or before.state is not self._last_status.state:
                    _LOG.debug(
                        "stage %s: state %s -> %s",
                        self.url,
                        "unknown" if before is None else before.state.name,
                        self._last_status.state.name,
                    )
            elif isinstance(event, Alarm):
                self._new_alarm = event.code
        return True

    def _to_status(self, event: Report) -> StageStatus:
        report, mpos = event.report, event.mpos
        position = mpos[0] / 1000.0 if mpos else math.nan
        state = StageState(report.state)
        speed = (report.feed or 0.0) / 60000.0
        return StageStatus(
            state=state,
            substate=report.substate,
            position=position,
            velocity=self._direction * speed,
            limit_triggered="X" in report.pins,
            alarm=self.connection.alarm if state is StageState.ALARM else None,
            planner_blocks_free=report.planner_blocks_free,
            rx_bytes_free=report.rx_bytes_free,
            host_time=event.host_time,
            reply_s=event.reply_s,
        )

    def _position_estimate(self) -> float:
        if self._last_status is None or math.isnan(self._last_status.position):
            return self.status().position
        return self._last_status.position

    def _move_duration(self, distance: float, v: float) -> float:
        """Seconds for a rest-to-rest move of ``distance`` m at ``v`` m/s (trapezoid)."""
        a = self.settings.acceleration
        if distance >= v * v / a:
            return distance / v + v / a
        return 2.0 * math.sqrt(distance / a)

    def _check_user_limits(self) -> None:
        if self._user_limits is None:
            return
        low, high = self._user_limits
        travel = self.settings.travel
        if low < -travel or high > 0.0:
            raise ConfigError(
                "soft_limits",
                self._user_limits,
                f"inside GRBL's machine range [{-travel:g}, 0] m ($130 = "
                f"{self.settings.max_travel_x:.3f} mm)",
                "narrow them or raise $130",
            )
