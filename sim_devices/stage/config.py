"""Settings of the simulated GRBL 1.1h: the ``$`` table and the machine it drives.

The defaults are stock GRBL 1.1h (``grbl/defaults.h``, ``DEFAULTS_GENERIC``, as printed by
``$$`` in ``doc/markdown/interface.md``): homing, soft and hard limits off, 250 steps/mm,
500 mm/min, 10 mm/s², 200 mm travel, ``$10=1``. A simulated lab machine states its own
settings explicitly (see ``hil.experiments.sim_tank.tank_stage_config``).

Compile-time options of ``grbl/config.h`` that a host can notice are fields here too:
``homing_cycles`` (``HOMING_CYCLE_0 = Z``, ``HOMING_CYCLE_1 = X|Y`` by default) and the axes
that have limit switches wired (all three by default).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from hil.errors import ConfigError

#: GRBL 1.1h defaults as printed by ``$$`` (interface.md, ``DEFAULTS_GENERIC``).
DEFAULT_SETTINGS: dict[int, float] = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0,
    20: 0, 21: 0, 22: 0, 23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000, 31: 0,
    32: 0, 100: 250.0, 101: 250.0, 102: 250.0, 110: 500.0, 111: 500.0, 112: 500.0,
    120: 10.0, 121: 10.0, 122: 10.0, 130: 200.0, 131: 200.0, 132: 200.0,
}  # fmt: skip
INTEGER_SETTINGS = frozenset({0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 30, 31, 32})
AXES = "XYZ"


@dataclass(frozen=True)
class GrblSimConfig:
    """Machine and simulation settings; the GRBL ones seed ``$100``, ``$110``, ...

    Parameters
    ----------
    steps_per_mm, max_rate_mm_min, acceleration_mm_s2, max_travel_mm:
        ``$100``, ``$110`` (mm/min), ``$120`` (mm/s²), ``$130`` (mm); the same value is
        given to Y and Z (``$101``, ``$111``, ...).
    soft_limits, hard_limits, homing:
        ``$20``, ``$21``, ``$22``.
    homing_dir_mask:
        ``$23``: bit n set homes axis n (X=0, Y=1, Z=2) towards its negative end.
    homing_feed_mm_min, homing_seek_mm_min, homing_debounce_ms, homing_pulloff_mm:
        ``$24``, ``$25``, ``$26``, ``$27``.
    junction_deviation_mm:
        ``$11``, the planner's cornering tolerance (mm).
    status_mask:
        ``$10``: bit 0 = report MPos (else WPos), bit 1 = report ``Bf:``.
    homing_cycles:
        Axes homed together, cycle by cycle (``HOMING_CYCLE_0``... of ``config.h``).
    switch_axes:
        Axes with limit switches wired (each has a switch at the homing end and one
        ``limit_switch_margin_mm`` beyond the other end, on one shared pin per axis).
    power_up_position_mm, power_up_yz_mm:
        Physical X (and Y, Z) carriage position at power-up in the homed frame (mm); GRBL's
        step counters start at 0 there.
    limit_switch_margin_mm:
        How far beyond the travel range the far limit switch sits (mm); the homing switch
        is at machine 0 (or ``-$130`` when homing towards the negative end).
    blank_eeprom:
        Power up as on a new board: ``error:7``, the restored settings, then the banner.
    line_latency_s:
        Time the firmware takes to parse and plan one line before it answers (s); GRBL 1.1h
        on an ATmega328p at 16 MHz answers a ``G1`` in about 2.4 ms.
    host_silence_timeout_s:
        Feed-hold a move when the host is silent this long (s); ``None`` disables it.
    version:
        Version in the banner.
    """

    steps_per_mm: float = 250.0
    max_rate_mm_min: float = 500.0
    acceleration_mm_s2: float = 10.0
    max_travel_mm: float = 200.0
    soft_limits: bool = False
    hard_limits: bool = False
    homing: bool = False
    homing_dir_mask: int = 0
    homing_feed_mm_min: float = 25.0
    homing_seek_mm_min: float = 500.0
    homing_debounce_ms: int = 250
    homing_pulloff_mm: float = 1.0
    junction_deviation_mm: float = 0.010
    status_mask: int = 1
    homing_cycles: tuple[str, ...] = ("Z", "XY")
    switch_axes: str = "XYZ"
    power_up_position_mm: float = -100.0
    power_up_yz_mm: tuple[float, float] = (-100.0, -100.0)
    limit_switch_margin_mm: float = 1.0
    blank_eeprom: bool = False
    line_latency_s: float = 0.0024
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
            "junction_deviation_mm",
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
        if not 0 <= self.homing_dir_mask <= 7:
            raise ConfigError("homing_dir_mask", self.homing_dir_mask, "an integer in [0, 7]")
        if not 0 <= self.homing_debounce_ms <= 65535:
            raise ConfigError("homing_debounce_ms", self.homing_debounce_ms, "0 to 65535 ms")
        cycles = "".join(self.homing_cycles)
        if not self.homing_cycles or set(cycles) - set(AXES) or len(set(cycles)) != len(cycles):
            raise ConfigError(
                "homing_cycles", self.homing_cycles, "groups of X, Y, Z, each axis once"
            )
        if set(self.switch_axes) - set(AXES):
            raise ConfigError("switch_axes", self.switch_axes, "letters among X, Y, Z")
        if not (math.isfinite(self.line_latency_s) and self.line_latency_s >= 0):
            raise ConfigError("line_latency_s", self.line_latency_s, "a number of seconds >= 0")
        t = self.host_silence_timeout_s
        if t is not None and not (math.isfinite(t) and t > 0):
            raise ConfigError("host_silence_timeout_s", t, "None or a number of seconds > 0")

    def settings(self) -> dict[int, float]:
        """The ``$`` settings table this configuration starts with."""
        table = dict(DEFAULT_SETTINGS)
        table.update(
            {
                10: self.status_mask,
                11: self.junction_deviation_mm,
                20: int(self.soft_limits),
                21: int(self.hard_limits),
                22: int(self.homing),
                23: self.homing_dir_mask,
                24: self.homing_feed_mm_min,
                25: self.homing_seek_mm_min,
                26: self.homing_debounce_ms,
                27: self.homing_pulloff_mm,
            }
        )
        for axis in range(3):
            table[100 + axis] = self.steps_per_mm
            table[110 + axis] = self.max_rate_mm_min
            table[120 + axis] = self.acceleration_mm_s2
            table[130 + axis] = self.max_travel_mm
        return table


def format_setting(number: int, value: float) -> str:
    """One ``$$`` line, as GRBL prints it (integers bare, others with 3 decimals)."""
    shown = str(int(value)) if number in INTEGER_SETTINGS else f"{value:.3f}"
    return f"${number}={shown}"


_FLOAT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)")


def store_setting(settings: dict[int, float], text: str) -> int | None:
    """Apply a ``$x=val`` line to ``settings``; return GRBL's error code, ``None`` if stored.

    As ``system_execute_line`` and ``settings_store_global_setting``: a number that does not
    read is ``error:2``, a missing ``=``, trailing text or an unknown setting ``error:3``, a
    negative value ``error:4``, ``$0`` under 3 µs ``error:6``, soft limits without homing
    ``error:10``; ``$22=0`` turns soft limits off too.

    >>> table = GrblSimConfig().settings()
    >>> store_setting(table, "$110=900"), table[110], store_setting(table, "$Q")
    (None, 900.0, 2)
    """
    head = _FLOAT.match(text, 1)
    if head is None:
        return 2
    if text[head.end() : head.end() + 1] != "=":
        return 3
    tail = _FLOAT.match(text, head.end() + 1)
    if tail is None:
        return 2
    number, value = float(head.group()), float(tail.group())
    if tail.end() != len(text) or number > 255:
        return 3
    key = int(number)
    if value < 0:
        return 4
    if key not in settings:
        return 3
    if key == 0 and value < 3:
        return 6
    if key == 20 and value and not settings[22]:
        return 10
    settings[key] = float(int(value)) if key in INTEGER_SETTINGS else value
    if key == 22 and not value:
        settings[20] = 0
    return None
