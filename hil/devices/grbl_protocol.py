"""GRBL 1.1 serial protocol without I/O: split bytes into lines, parse lines, format commands.

Every line GRBL sends is one of the message types of the GRBL 1.1 interface documentation
(``doc/markdown/interface.md``); :func:`parse_line` turns it into a frozen dataclass.
Realtime commands are single bytes sent outside the line stream.

Examples
--------
>>> parse_line("<Idle|MPos:1.000,0.000,0.000|FS:0,0|Bf:15,128|Pn:X>").mpos
(1.0, 0.0, 0.0)
>>> parse_line("error:22")
ErrorResponse(code=22)
>>> splitter = LineSplitter()
>>> splitter.feed(b"ok\\r\\nALA") + splitter.feed(b"RM:1\\r\\n")
['ok', 'ALARM:1']
>>> format_move_line(-12.3456, 600.0)
'G53 G1 X-12.346 F600.000'
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from hil.devices.grbl_codes import alarm_text, error_text

#: Realtime commands: single bytes acted on at once, never part of a line.
STATUS_QUERY = b"?"
FEED_HOLD = b"!"
CYCLE_START = b"~"
SOFT_RESET = b"\x18"
JOG_CANCEL = b"\x85"

#: GRBL's line buffer holds 80 characters including the terminator (LINE_BUFFER_SIZE).
MAX_LINE_LENGTH = 79
#: GRBL's serial receive buffer (RX_BUFFER_SIZE) in bytes, for the character-counting flow.
RX_BUFFER_SIZE = 128


@dataclass(frozen=True)
class Ok:
    """``ok``: the last line was parsed and executed (or queued)."""


@dataclass(frozen=True)
class ErrorResponse:
    """``error:<code>``: the last line was rejected; nothing of it was executed."""

    code: int

    @property
    def text(self) -> str:
        return error_text(self.code)


@dataclass(frozen=True)
class AlarmMessage:
    """``ALARM:<code>``: the controller entered an alarm state."""

    code: int

    @property
    def text(self) -> str:
        return alarm_text(self.code)


@dataclass(frozen=True)
class Banner:
    """``Grbl 1.1h ['$' for help]``: the controller (re)initialised."""

    version: str


@dataclass(frozen=True)
class SettingLine:
    """``$<number>=<value>`` from a ``$$`` settings dump; ``value`` as sent."""

    number: int
    value: str


@dataclass(frozen=True)
class Feedback:
    """A bracketed message ``[<kind>:<text>]``, e.g. ``[MSG:Reset to continue]``."""

    kind: str
    text: str


@dataclass(frozen=True)
class StartupLine:
    """``>G54G20:ok``: a stored startup block ran with ``result`` (``ok`` or ``error:N``)."""

    block: str
    result: str


@dataclass(frozen=True)
class StatusReport:
    """``<State|MPos:...|...>`` real-time status report; positions and rates in mm, mm/min.

    Fields that a report did not carry are ``None`` (``pins`` is ``""``).
    """

    state: str
    substate: int | None
    mpos: tuple[float, ...] | None
    wpos: tuple[float, ...] | None
    wco: tuple[float, ...] | None
    feed: float | None
    spindle: float | None
    planner_blocks_free: int | None
    rx_bytes_free: int | None
    line_number: int | None
    pins: str
    overrides: tuple[int, ...] | None

    def machine_position(self, last_wco: tuple[float, ...] | None) -> tuple[float, ...] | None:
        """MPos, from ``MPos:`` or as ``WPos + WCO`` (this report's WCO, else ``last_wco``).

        >>> parse_line("<Idle|WPos:-2.500,0.000,11.000>").machine_position((1.0, 0.0, -1.0))
        (-1.5, 0.0, 10.0)
        """
        if self.mpos is not None:
            return self.mpos
        wco = self.wco if self.wco is not None else last_wco
        if self.wpos is None or wco is None:
            return None
        return tuple(w + o for w, o in zip(self.wpos, wco, strict=False))


@dataclass(frozen=True)
class Unrecognised:
    """A line that is no GRBL 1.1 message (noise, a different firmware, a partial line)."""

    line: str


GrblMessage = (
    Ok
    | ErrorResponse
    | AlarmMessage
    | Banner
    | SettingLine
    | Feedback
    | StartupLine
    | StatusReport
    | Unrecognised
)

_BANNER = re.compile(r"^Grbl (\S+) \['\$' for help\]$")
_SETTING = re.compile(r"^\$(\d+)=(.*)$")
_STATES = ("Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep")


def parse_line(line: str) -> GrblMessage:
    """Parse one line from GRBL (without its line terminator).

    >>> parse_line("Grbl 1.1h ['$' for help]")
    Banner(version='1.1h')
    >>> parse_line("[MSG:'$H'|'$X' to unlock]")
    Feedback(kind='MSG', text="'$H'|'$X' to unlock")
    >>> parse_line("$110=500.000")
    SettingLine(number=110, value='500.000')
    >>> parse_line("<Hold:0|MPos:0.000,0.000,0.000|FS:0,0>").substate
    0
    >>> parse_line("garbage")
    Unrecognised(line='garbage')
    """
    line = line.strip()
    try:
        if line == "ok":
            return Ok()
        if line.startswith("error:"):
            return ErrorResponse(int(line[6:]))
        if line.startswith("ALARM:"):
            return AlarmMessage(int(line[6:]))
        if line.startswith("<") and line.endswith(">"):
            return _parse_status(line[1:-1])
        if line.startswith("[") and line.endswith("]"):
            kind, sep, text = line[1:-1].partition(":")
            if sep:
                return Feedback(kind, text)
            return Unrecognised(line)
        if line.startswith(">") and ":" in line:
            block, _, result = line[1:].partition(":")
            return StartupLine(block, result)
        if match := _BANNER.match(line):
            return Banner(match.group(1))
        if match := _SETTING.match(line):
            return SettingLine(int(match.group(1)), match.group(2))
    except ValueError:
        pass
    return Unrecognised(line)


def _floats(text: str) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split(","))


def _parse_status(body: str) -> StatusReport:
    fields = body.split("|")
    state, _, sub = fields[0].partition(":")
    if state not in _STATES:
        raise ValueError(f"unknown state {state!r}")
    values: dict[str, str] = {}
    for field in fields[1:]:
        name, sep, value = field.partition(":")
        if not sep:
            raise ValueError(f"status field without ':' {field!r}")
        values[name] = value
    if "MPos" not in values and "WPos" not in values:
        raise ValueError("status report without MPos or WPos")
    feed = spindle = None
    if "FS" in values:
        feed, spindle = _floats(values["FS"])[:2]
    elif "F" in values:
        feed = float(values["F"])
    bf = tuple(int(v) for v in values["Bf"].split(",")) if "Bf" in values else None
    return StatusReport(
        state=state,
        substate=int(sub) if sub else None,
        mpos=_floats(values["MPos"]) if "MPos" in values else None,
        wpos=_floats(values["WPos"]) if "WPos" in values else None,
        wco=_floats(values["WCO"]) if "WCO" in values else None,
        feed=feed,
        spindle=spindle,
        planner_blocks_free=bf[0] if bf else None,
        rx_bytes_free=bf[1] if bf else None,
        line_number=int(values["Ln"]) if "Ln" in values else None,
        pins=values.get("Pn", ""),
        overrides=tuple(int(v) for v in values["Ov"].split(",")) if "Ov" in values else None,
    )


class LineSplitter:
    """Split a byte stream from GRBL into lines; any chunking gives the same lines.

    Lines end at ``\\n``; a ``\\r`` before it is dropped; empty lines are skipped. Bytes are
    decoded as ASCII with undecodable bytes replaced, so noise never stops the reader.
    """

    def __init__(self) -> None:
        self._partial = bytearray()

    def feed(self, data: bytes) -> list[str]:
        """Add received bytes; return the complete lines now available, oldest first."""
        self._partial += data
        *complete, rest = self._partial.split(b"\n")
        self._partial = bytearray(rest)
        lines = [raw.rstrip(b"\r").decode("ascii", errors="replace") for raw in complete]
        return [line for line in lines if line.strip()]

    def reset(self) -> None:
        """Forget a partial line (after the port's input buffer was flushed)."""
        self._partial.clear()


def format_number(value: float) -> str:
    """A G-code number with 3 decimals (µm resolution in mm), no exponent.

    >>> format_number(1e-9), format_number(-0.0004)
    ('0.000', '0.000')
    """
    text = f"{value:.3f}"
    return "0.000" if text == "-0.000" else text


def format_move_line(x_mm: float, feed_mm_min: float) -> str:
    """Absolute linear move of X in machine coordinates (``G53`` ignores work offsets)."""
    return f"G53 G1 X{format_number(x_mm)} F{format_number(feed_mm_min)}"


def format_jog_line(dx_mm: float, feed_mm_min: float) -> str:
    """Incremental jog of X in mm at ``feed_mm_min``.

    >>> format_jog_line(10, 600)
    '$J=G91 G21 X10.000 F600.000'
    """
    return f"$J=G91 G21 X{format_number(dx_mm)} F{format_number(feed_mm_min)}"


def format_dwell_line(seconds: float = 0.0) -> str:
    """``G4 P<s>``: GRBL answers ``ok`` only once every queued motion has finished.

    >>> format_dwell_line()
    'G4 P0.000'
    """
    return f"G4 P{format_number(seconds)}"


def format_setting_line(number: int, value: float | int | bool) -> str:
    """``$<number>=<value>``; booleans as 0/1, integers without decimals.

    >>> format_setting_line(20, True), format_setting_line(10, 3), format_setting_line(110, 600.0)
    ('$20=1', '$10=3', '$110=600.000')
    """
    if isinstance(value, bool | int):
        return f"${number}={int(value)}"
    return f"${number}={format_number(value)}"
