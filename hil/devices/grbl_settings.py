"""GRBL 1.1 ``$`` settings as typed attributes with units and validators.

One generic descriptor, :class:`GrblSetting`, declares a setting: its ``$`` number, its
type, its unit and its allowed range, in the settings style the board's settings share
(:class:`~hil.devices.setting_descriptor.TypedSetting`). :class:`GrblSettings` is a snapshot
of a ``$$`` dump read through those descriptors; :meth:`GrblSettings.check` validates a
value for writing and formats the ``$x=val`` line, so a bad value raises before anything is
sent.

Examples
--------
>>> s = GrblSettings({100: "80.000", 110: "600.000", 120: "50.000", 130: "400.000"})
>>> s.max_rate_x, s.max_rate, s.travel
(600.0, 0.01, 0.4)
>>> s.check("max_rate_x", 1200.0)
'$110=1200.000'
>>> s.check("acceleration_x", -5.0)
Traceback (most recent call last):
...
hil.errors.ConfigError: acceleration_x ($120) = -5.0 is not allowed: must be a number in \
(0, 100000] mm/s^2; give the X acceleration in mm/s^2
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, TypeVar, overload

from hil.devices.grbl_protocol import SettingLine, format_setting_line
from hil.devices.setting_descriptor import TypedSetting
from hil.errors import ConfigError

T = TypeVar("T", float, int, bool)

#: The axes of a GRBL 1.1 build, in ``$`` setting order (``$100`` X, ``$101`` Y, ``$102`` Z).
AXES = "XYZ"
#: GRBL 1.1h's stock homing cycles (``config.h``: ``HOMING_CYCLE_0`` Z, then
#: ``HOMING_CYCLE_1`` X and Y together). Every axis in them needs its switch, else ALARM:9.
STOCK_HOMING_CYCLES = ("Z", "XY")
#: ``limits.c``: the search covers 1.5 x the max travel, the locate phase 5 x the pull-off.
HOMING_SEARCH_SCALAR = 1.5
HOMING_LOCATE_SCALAR = 5.0


def check_homing_cycles(cycles: Sequence[str]) -> tuple[str, ...]:
    """``cycles`` as a tuple, or ConfigError naming a cycle that is not axes of X, Y, Z.

    >>> check_homing_cycles(["Z", "XY"])
    ('Z', 'XY')
    >>> check_homing_cycles(("XA",))
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: homing cycle = 'XA' is not allowed: must be a non-empty string \
of the axes X, Y, Z; GRBL 1.1's stock cycles are ('Z', 'XY')
    """
    for cycle in cycles:
        if not isinstance(cycle, str) or not cycle or any(a not in AXES for a in cycle):
            raise ConfigError(
                "homing cycle", cycle, "a non-empty string of the axes X, Y, Z",
                "GRBL 1.1's stock cycles are ('Z', 'XY')",
            )  # fmt: skip
    return tuple(cycles)


def _number(kind: type[Any]) -> Callable[[Any], Any]:
    """A converter to ``kind`` (float, int or bool) for values given by the host."""

    def convert(value: Any) -> Any:
        if kind is bool:
            if isinstance(value, bool) or value in (0, 1):
                return bool(value)
            raise ValueError(value)
        if not isinstance(value, int | float) or not math.isfinite(value):
            raise TypeError(value)
        if kind is int and float(value) != int(value):
            raise ValueError(value)
        return kind(value)

    return convert


class GrblSetting(TypedSetting[T]):
    """A GRBL ``$<number>`` setting of type ``kind`` in ``unit``
    (:class:`~hil.devices.setting_descriptor.TypedSetting`), read from the controller's
    ``$$`` dump.

    ``low``/``high`` bound the value; ``low_open`` excludes ``low`` itself (``> 0``).
    """

    def __init__(
        self,
        number: int,
        kind: type[T],
        unit: str,
        low: float,
        high: float,
        *,
        low_open: bool = False,
        hint: str = "",
    ) -> None:
        if kind is bool:
            allowed = "a boolean (True/False or 0/1)"
        else:
            what = "an integer" if kind is int else "a number"
            allowed = f"{what} in {'(' if low_open else '['}{low:g}, {high:g}]"
        super().__init__(
            _number(kind),
            unit="" if kind is bool else unit,
            check=lambda v: (v > low if low_open else v >= low) and v <= high,
            allowed=allowed,
            hint=hint,
            takes_bool=kind is bool,
        )
        self.number = number
        self.kind: type[T] = kind
        self.low = low
        self.high = high
        self.low_open = low_open
        self.name = f"${number}"

    @property
    def label(self) -> str:
        """``name ($number)``, as messages name a GRBL setting."""
        return f"{self.name} (${self.number})"

    @overload
    def __get__(self, obj: None, owner: type) -> GrblSetting[T]: ...
    @overload
    def __get__(self, obj: GrblSettings, owner: type) -> T: ...
    def __get__(self, obj: GrblSettings | None, owner: type) -> GrblSetting[T] | T:
        if obj is None:
            return self
        raw = obj.raw.get(self.number)
        if raw is None:
            raise ConfigError(
                self.label,
                None,
                "present in the $$ settings dump",
                "the controller did not report it: check the firmware is GRBL 1.1",
            )
        return self.parse(raw)

    def __set__(self, obj: GrblSettings, value: Any) -> None:
        raise AttributeError(
            f"{self.name} is read-only on a settings snapshot; write it with "
            f"GrblStage.write_setting({self.name!r}, value)"
        )

    def parse(self, raw: str) -> T:
        """Convert the text of a ``$$`` line to the setting's type."""
        return self.kind(float(raw))


class GrblSettings:
    """Snapshot of the controller's settings (``raw``: ``$`` number -> text as sent).

    X-axis values are in GRBL's units (mm, mm/min, mm/s^2); the properties without a unit
    suffix in their name give SI values (``max_rate`` m/s, ``acceleration`` m/s^2, ...).
    """

    step_pulse = GrblSetting(0, int, "us", 3, 255, hint="GRBL needs at least 3 us")
    step_idle_delay = GrblSetting(1, int, "ms", 0, 255, hint="255 keeps the motors enabled")
    step_port_invert = GrblSetting(2, int, "", 0, 255)
    direction_port_invert = GrblSetting(3, int, "", 0, 255)
    step_enable_invert = GrblSetting(4, bool, "", 0, 1)
    limit_pins_invert = GrblSetting(5, bool, "", 0, 1, hint="1 for normally-closed switches")
    probe_pin_invert = GrblSetting(6, bool, "", 0, 1)
    status_report_mask = GrblSetting(
        10, int, "", 0, 255, hint="bit 0: MPos (1) or WPos (0); bit 1: report Bf"
    )
    junction_deviation = GrblSetting(11, float, "mm", 0, 1e3)
    arc_tolerance = GrblSetting(12, float, "mm", 0, 1e3)
    report_inches = GrblSetting(13, bool, "", 0, 1, hint="the drivers need mm: set $13=0")
    soft_limits = GrblSetting(20, bool, "", 0, 1, hint="soft limits need homing ($22=1)")
    hard_limits = GrblSetting(21, bool, "", 0, 1)
    homing_enabled = GrblSetting(22, bool, "", 0, 1)
    homing_dir_mask = GrblSetting(23, int, "", 0, 255, hint="bit 0 = home X towards -X")
    homing_feed = GrblSetting(24, float, "mm/min", 0, 1e5, low_open=True)
    homing_seek = GrblSetting(25, float, "mm/min", 0, 1e5, low_open=True)
    homing_debounce = GrblSetting(26, int, "ms", 0, 65535)
    homing_pulloff = GrblSetting(27, float, "mm", 0, 1e4)
    max_spindle_speed = GrblSetting(30, float, "rpm", 0, 1e6)
    min_spindle_speed = GrblSetting(31, float, "rpm", 0, 1e6)
    laser_mode = GrblSetting(32, bool, "", 0, 1)
    steps_per_mm_x = GrblSetting(100, float, "steps/mm", 0, 1e5, low_open=True)
    steps_per_mm_y = GrblSetting(101, float, "steps/mm", 0, 1e5, low_open=True)
    steps_per_mm_z = GrblSetting(102, float, "steps/mm", 0, 1e5, low_open=True)
    max_rate_x = GrblSetting(
        110, float, "mm/min", 0, 1e6, low_open=True, hint="give the X max rate in mm/min"
    )
    max_rate_y = GrblSetting(111, float, "mm/min", 0, 1e6, low_open=True)
    max_rate_z = GrblSetting(112, float, "mm/min", 0, 1e6, low_open=True)
    acceleration_x = GrblSetting(
        120, float, "mm/s^2", 0, 1e5, low_open=True, hint="give the X acceleration in mm/s^2"
    )
    acceleration_y = GrblSetting(121, float, "mm/s^2", 0, 1e5, low_open=True)
    acceleration_z = GrblSetting(122, float, "mm/s^2", 0, 1e5, low_open=True)
    max_travel_x = GrblSetting(
        130, float, "mm", 0, 1e6, low_open=True, hint="give the X travel in mm"
    )
    max_travel_y = GrblSetting(131, float, "mm", 0, 1e6, low_open=True)
    max_travel_z = GrblSetting(132, float, "mm", 0, 1e6, low_open=True)

    def __init__(self, raw: Mapping[int, str]) -> None:
        self.raw: dict[int, str] = dict(raw)

    @classmethod
    def from_lines(cls, lines: Iterable[SettingLine]) -> GrblSettings:
        """Build from the ``$x=val`` lines of a ``$$`` dump."""
        return cls({line.number: line.value for line in lines})

    @classmethod
    def descriptor(cls, name: str) -> GrblSetting[Any]:
        """The descriptor called ``name``; ConfigError listing the names if unknown."""
        found = cls.__dict__.get(name)
        if not isinstance(found, GrblSetting):
            names = sorted(k for k, v in cls.__dict__.items() if isinstance(v, GrblSetting))
            raise ConfigError("setting", name, "one of " + ", ".join(names))
        return found

    def check(self, name: str, value: Any) -> str:
        """Validate ``value`` for setting ``name``; return the ``$x=val`` line to send."""
        desc = self.descriptor(name)
        typed = desc.validate(value)
        if name == "soft_limits" and typed and not self.raw.get(22, "0").startswith("1"):
            raise ConfigError(
                "soft_limits ($20)",
                value,
                "False while homing is disabled ($22=0)",
                "GRBL needs homing for soft limits: enable homing_enabled first",
            )
        return format_setting_line(desc.number, typed)

    def updated(self, name: str, value: Any) -> GrblSettings:
        """A copy with ``name`` set to ``value`` (after a successful write)."""
        desc = self.descriptor(name)
        line = format_setting_line(desc.number, desc.validate(value))
        raw = dict(self.raw)
        raw[desc.number] = line.partition("=")[2]
        return GrblSettings(raw)

    @property
    def max_rate(self) -> float:
        """X max rate, m/s."""
        return self.max_rate_x / 60000.0

    @property
    def acceleration(self) -> float:
        """X acceleration, m/s^2."""
        return self.acceleration_x / 1000.0

    @property
    def travel(self) -> float:
        """X max travel, m."""
        return self.max_travel_x / 1000.0

    @property
    def step(self) -> float:
        """One X step, m."""
        return 1e-3 / self.steps_per_mm_x

    def travel_mm(self, axis: str) -> float | None:
        """Max travel ``$130``-``$132`` of ``axis`` ("X", "Y" or "Z") in mm, or None when
        the dump has no such setting (a build without that axis)."""
        number = 130 + AXES.index(axis)
        return float(self.raw[number]) if number in self.raw else None

    def homing_time_bound(self, cycles: Sequence[str] = STOCK_HOMING_CYCLES) -> float:
        """The longest ``$H`` can take before GRBL gives up with ``ALARM:9``, s.

        GRBL 1.1h homes the axes of each cycle together (``cycles``: its ``HOMING_CYCLE_n``
        masks, stock ``("Z", "XY")``), and per cycle: searches 1.5 x the largest travel at
        the seek rate ``$25``, pulls off ``$27`` at ``$25``, locates the switch within 5 x
        ``$27`` at the feed rate ``$24``, pulls off again, with the debounce ``$26`` after
        each of the 4 phases. Axes the dump has no travel for are skipped. Acceleration is
        not counted (the caller adds a margin).

        >>> s = GrblSettings({24: "25", 25: "500", 26: "250", 27: "1", 130: "200", 132: "100"})
        >>> round(s.homing_time_bound(), 3)  # Z: 18 + 0.24 + 12 + 1; XY: 36 + 0.24 + 12 + 1
        80.48
        """
        check_homing_cycles(cycles)
        seek, feed, pulloff = self.homing_seek, self.homing_feed, self.homing_pulloff
        debounce = (int(self.raw[26]) if 26 in self.raw else 250) / 1000.0
        total = 0.0
        for cycle in cycles:
            travels = [t for t in (self.travel_mm(axis) for axis in cycle) if t is not None]
            if not travels:
                continue
            total += (
                HOMING_SEARCH_SCALAR * max(travels) / seek * 60.0
                + 2.0 * pulloff / seek * 60.0
                + HOMING_LOCATE_SCALAR * pulloff / feed * 60.0
                + 4.0 * debounce
            )
        return total

    def __repr__(self) -> str:
        return f"GrblSettings({self.raw!r})"
