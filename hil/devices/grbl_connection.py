"""The host end of a GRBL 1.1 link without I/O: bytes in, events out; commands in, bytes out.

:class:`GrblConnection` never reads, writes or sleeps; the caller passes the time (driver
clock, s) with every call that depends on it. :class:`~hil.devices.grbl.GrblStage` is the
I/O shell over it: it writes what the ``send_*`` methods return, feeds what it reads to
:meth:`GrblConnection.receive_data` and waits on the connection's state.

What the connection knows of GRBL 1.1h (``grbl/protocol.c``, ``grbl/report.c``):

- Lines are answered in order by ``ok`` or ``error:N``; a soft reset drops every line not
  yet answered (the banner ``Grbl 1.1h ['$' for help]`` marks the reset).
- ``ALARM:1`` (hard limit) and ``ALARM:2`` (soft limit) are *critical*: GRBL prints the
  alarm, sleeps 500 ms (``report_alarm_message``), prints ``[MSG:Reset to continue]``,
  clears any soft reset received meanwhile and then ignores everything but a soft reset,
  status queries included. The connection marks the alarm critical from its code, at once.
- A soft reset 0x18 is answered by the banner (after ``ALARM:3``/``ALARM:6`` and 500 ms if
  the machine was moving or homing). A reset that brings neither an alarm nor the banner
  within :data:`RESET_RETRY_S` was dropped and is due again (:meth:`reset_due`).
- A status query ``?`` is answered within milliseconds, except in a critical alarm or by a
  reset; reports are paired with the oldest query in flight and dated by it.

Examples
--------
>>> conn = GrblConnection()
>>> conn.send_reset(now=0.0)
b'\\x18'
>>> conn.receive_data(b"ALARM:1\\r\\n", now=0.01)
[Alarm(code=1, critical=True)]
>>> conn.critical, conn.reset_due(now=0.5), conn.reset_due(now=0.72)
(True, False, True)
>>> conn.receive_data(b"\\r\\nGrbl 1.1h ['$' for help]\\r\\n", now=0.8)
[Reset(version='1.1h', dropped=())]
>>> conn.critical, conn.banners
(False, 1)
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from hil.devices.grbl_codes import CRITICAL_ALARMS
from hil.devices.grbl_protocol import (
    MAX_LINE_LENGTH,
    SOFT_RESET,
    STATUS_QUERY,
    AlarmMessage,
    Banner,
    ErrorResponse,
    Feedback,
    LineSplitter,
    Ok,
    SettingLine,
    StartupLine,
    StatusReport,
    Unrecognised,
    parse_line,
)
from hil.errors import ConfigError

#: A status query unanswered for this long (s) is taken as dropped and may be sent again:
#: GRBL answers within milliseconds (a reset drops a pending query).
QUERY_LOST_S = 1.0
#: A query given up as lost is still awaited this long after it was sent (s): any report
#: read meanwhile may be its late answer, so none of them is dated (``reply_s`` infinite).
QUERY_FORGOTTEN_S = 2.0 * QUERY_LOST_S
#: GRBL 1.1 sleeps this long after printing an ALARM line (``report_alarm_message``); in a
#: critical alarm a soft reset received during it is cleared, s.
ALARM_REPORT_DELAY_S = 0.5
#: A soft reset that brought neither the banner nor an ALARM line for this long was dropped
#: and is sent again, s: longer than :data:`ALARM_REPORT_DELAY_S`, so the resend lands after
#: GRBL has started listening for it.
RESET_RETRY_S = 0.7
#: What GRBL prints once a critical alarm has locked it.
CRITICAL_MESSAGE = "Reset to continue"


@dataclass
class PendingLine:
    """A line sent and not yet answered; ``reset`` if GRBL reset before answering it."""

    line: str
    result: Ok | ErrorResponse | None = None
    reset: bool = False
    #: An alarm came while it was pending (a failed ``$H`` is answered ``ok`` after its
    #: ``ALARM:9``: that ``ok`` ends no alarm).
    alarmed: bool = False

    @property
    def done(self) -> bool:
        """Answered, or dropped by a reset."""
        return self.result is not None or self.reset


@dataclass(frozen=True)
class LineAnswered:
    """``ok`` or ``error:N`` for the oldest pending line."""

    pending: PendingLine


@dataclass(frozen=True)
class Report:
    """A status report with the machine position (mm, from MPos or WPos + the last WCO)
    and its date: ``host_time`` (s) the query it answers was sent, ``reply_s`` how long the
    answer took (infinite when its query is unknown)."""

    report: StatusReport
    mpos: tuple[float, ...] | None
    host_time: float
    reply_s: float


@dataclass(frozen=True)
class Alarm:
    """``ALARM:<code>``; ``critical`` for the codes after which only a soft reset is heard."""

    code: int
    critical: bool


@dataclass(frozen=True)
class Reset:
    """The banner: GRBL (re)initialised; ``dropped`` the lines it never answered."""

    version: str
    dropped: tuple[str, ...] = field(default=())


@dataclass(frozen=True)
class Message:
    """A bracketed push message (``[MSG:...]``, ``[GC:...]``, ...) or a startup-line result,
    as received."""

    text: str


@dataclass(frozen=True)
class Setting:
    """One ``$<number>=<value>`` line of a ``$$`` dump."""

    line: SettingLine


@dataclass(frozen=True)
class Noise:
    """A line that is not GRBL 1.1 (noise on the cable, another firmware)."""

    line: str


GrblEvent = LineAnswered | Report | Alarm | Reset | Message | Setting | Noise


class GrblConnection:
    """State of the host end of one GRBL 1.1 link (see the module docstring).

    Attributes
    ----------
    banners, reports:
        Banners and status reports received so far (waits compare counts).
    alarm:
        The last alarm code, until an ``$X`` or ``$H`` answered ``ok`` ends it, or None (a
        reset does not end it: with homing enabled GRBL stays locked after one).
    critical:
        A critical alarm (``ALARM:1``/``ALARM:2``) holds GRBL until a soft reset.
    critical_since:
        When that alarm was received (s), else None.
    last_report:
        The last :class:`Report`, or None.
    settings:
        ``$`` number -> value text, from the ``$$`` lines received.
    messages, noise:
        Push messages (``[MSG:...]`` as received) and unrecognised lines, oldest first.
    last_lines:
        The lines the last :meth:`receive_data` completed, without their line ends.
    """

    def __init__(self) -> None:
        self._splitter = LineSplitter()
        self.last_lines: list[str] = []
        self.pending: deque[PendingLine] = deque()
        self.banners = 0
        self.reports = 0
        self.alarm: int | None = None
        self.critical = False
        self.critical_since: float | None = None
        self.last_report: Report | None = None
        self.settings: dict[int, str] = {}
        self.messages: list[str] = []
        self.noise: list[str] = []
        self._wco: tuple[float, ...] | None = None
        self._queries: deque[float] = deque()  # send times of '?' in flight, oldest first
        self._lost: deque[float] = deque()  # send times of '?' given up as lost
        self._reset_sent: float | None = None  # a 0x18 awaiting its banner, sent then
        self._reset_heard = False  # an ALARM line since that 0x18: GRBL took it

    # ------------------------------------------------------------------ host -> GRBL
    def send_line(self, line: str) -> tuple[PendingLine, bytes]:
        """Queue ``line`` for its answer; return it and the bytes to write."""
        if len(line) > MAX_LINE_LENGTH or "\n" in line or "\r" in line:
            raise ConfigError(
                "line", line, f"one line of at most {MAX_LINE_LENGTH} characters (GRBL 1.1)"
            )
        pending = PendingLine(line)
        self.pending.append(pending)
        return pending, line.encode("ascii") + b"\n"

    def send_query(self, now: float) -> bytes:
        """``?``, or ``b""`` while a query is in flight: with one at a time every report is
        known to answer the oldest (GRBL merges two '?' that arrive before its main loop
        runs). A query unanswered for :data:`QUERY_LOST_S` is given up as lost first."""
        while self._queries and now - self._queries[0] >= QUERY_LOST_S:
            self._lost.append(self._queries.popleft())
        if self._queries:
            return b""
        self._queries.append(now)
        return STATUS_QUERY

    def expects_report(self) -> bool:
        """A query is in flight, or one given up as lost may still be answered."""
        return bool(self._queries or self._lost)

    @property
    def last_query(self) -> float:
        """When the query in flight was sent (s), ``-inf`` with none."""
        return self._queries[-1] if self._queries else -math.inf

    def send_reset(self, now: float) -> bytes:
        """Soft reset 0x18; the connection then awaits the banner (:meth:`reset_due`)."""
        self._reset_sent = now
        self._reset_heard = False
        return SOFT_RESET

    def abandon_reset(self) -> None:
        """Stop awaiting the banner of the reset sent (the caller gave up on it): no more
        resends are due."""
        self._reset_sent = None

    @property
    def resetting(self) -> bool:
        """A soft reset was sent and its banner has not come yet."""
        return self._reset_sent is not None

    def reset_due(self, now: float) -> bool:
        """The soft reset sent was dropped and should be sent again: no ALARM line and no
        banner for :data:`RESET_RETRY_S` (a critical alarm received after it also drops
        it: the resend then waits out GRBL's :data:`ALARM_REPORT_DELAY_S`)."""
        return (
            self._reset_sent is not None
            and not self._reset_heard
            and now - self._reset_sent >= RESET_RETRY_S
        )

    # ------------------------------------------------------------------ GRBL -> host
    def receive_data(self, data: bytes, now: float) -> list[GrblEvent]:
        """Take bytes read from GRBL at ``now`` (s); return the events they complete, one
        per line (the lines are in :attr:`last_lines`)."""
        self.last_lines = list(self._splitter.feed(data))
        return [self._handle(line, now) for line in self.last_lines]

    def discard_partial(self) -> None:
        """Forget a partial line (after unread input was thrown away)."""
        self._splitter.reset()

    def _handle(self, line: str, now: float) -> GrblEvent:
        msg = parse_line(line)
        if isinstance(msg, Ok | ErrorResponse):
            return self._answer(msg, line)
        if isinstance(msg, StatusReport):
            return self._report(msg, now)
        if isinstance(msg, AlarmMessage):
            return self._alarm(msg.code, now)
        if isinstance(msg, Banner):
            return self._banner(msg.version)
        if isinstance(msg, SettingLine):
            self.settings[msg.number] = msg.value
            return Setting(msg)
        if isinstance(msg, Feedback):
            text = f"[{msg.kind}:{msg.text}]"
            self.messages.append(text)
            if msg.kind == "MSG" and msg.text == CRITICAL_MESSAGE and not self.critical:
                self.critical, self.critical_since = True, now
            return Message(text)
        if isinstance(msg, StartupLine):
            return Message(line)
        assert isinstance(msg, Unrecognised)
        self.noise.append(msg.line)
        return Noise(msg.line)

    def _answer(self, msg: Ok | ErrorResponse, line: str) -> GrblEvent:
        if not self.pending:
            self.noise.append(line)  # an answer to nothing this connection sent
            return Noise(line)
        pending = self.pending.popleft()
        pending.result = msg
        if isinstance(msg, Ok) and pending.line in ("$X", "$H") and not pending.alarmed:
            self.alarm = None  # unlocked or homed: the alarm is over
        return LineAnswered(pending)

    def _report(self, report: StatusReport, now: float) -> Report:
        if report.wco is not None:
            self._wco = report.wco
        host_time, reply_s = self._date_report(now)
        event = Report(report, report.machine_position(self._wco), host_time, reply_s)
        self.last_report = event
        self.reports += 1
        return event

    def _alarm(self, code: int, now: float) -> Alarm:
        self.alarm = code
        for pending in self.pending:
            pending.alarmed = True
        critical = code in CRITICAL_ALARMS
        if critical:
            self.critical, self.critical_since = True, now
            if self._reset_sent is not None:
                # GRBL clears a reset received before it locks: send it again once it listens.
                self._reset_sent = now
        elif self._reset_sent is not None:
            self._reset_heard = True  # ALARM:3/6 is GRBL acting on the reset
        return Alarm(code, critical)

    def _banner(self, version: str) -> Reset:
        self.banners += 1
        self.critical, self.critical_since = False, None
        self._reset_sent = None
        self._queries.clear()  # a reset drops the queries GRBL had not answered
        self._lost.clear()
        dropped = tuple(p.line for p in self.pending)
        for pending in self.pending:
            pending.reset = True
        self.pending.clear()
        return Reset(version, dropped)

    def _date_report(self, received: float) -> tuple[float, float]:
        """``(host_time, reply_s)`` of a report received at ``received``.

        GRBL samples its state on the main-loop pass after the '?' arrives, while the
        report's ~60 bytes take 5 ms at 115 200 baud and the host may read them later still:
        the query's time dates the position. A report with no query in flight gets its
        receipt time and an infinite ``reply_s``. While a query given up as lost may still
        be answered (:data:`QUERY_FORGOTTEN_S` after it was sent), a report cannot be told
        from that late answer, so its ``reply_s`` is infinite too.
        """
        while self._lost and received - self._lost[0] >= QUERY_FORGOTTEN_S:
            self._lost.popleft()
        if self._queries:
            asked = self._queries.popleft()
            return asked, math.inf if self._lost else received - asked
        if self._lost:
            self._lost.popleft()  # its late answer, with none in flight: nothing else awaited
        return received, math.inf
