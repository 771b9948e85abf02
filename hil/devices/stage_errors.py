"""Errors of motion-stage drivers, split by who broke the rule (DESIGN principle 11), in the
one error tree of :mod:`hil.errors` (each run-time one names the stage's URL, set by the
driver: ``/dev/ttyUSB0: GRBL rejected ...``).

- :class:`StageLimitError` (a :class:`~hil.errors.ConfigError`): the host asked for a move
  outside the soft limits or above the machine's rates; raised before anything is sent.
- :class:`StageCommandError` (a :class:`~hil.errors.DeviceRefused`): the controller rejected
  a line the host sent (``error:N``).
- :class:`StageAlarmError` (a :class:`~hil.errors.DeviceRefused`): the controller is in (or
  just entered) an alarm; the message says how to recover.
- :class:`StageHeldError` (a :class:`~hil.errors.DeviceRefused`): motion was feed-held (by
  :meth:`stop`, a watchdog or a button).
- :class:`StageTimeoutError` (a :class:`~hil.errors.DeviceTimedOut`): no answer in time
  (cable, port, power).
"""

from __future__ import annotations

import math

from hil.errors import ConfigError, DeviceError, DeviceRefused, DeviceTimedOut


class StageError(DeviceError):
    """Base class of run-time stage failures (not configuration mistakes)."""


class StageLimitError(ConfigError):
    """A move outside the soft limits or above a rate limit; nothing was sent.

    >>> str(StageLimitError("x (axis X)", -0.6, "within [-0.5, 0] m", "stay inside"))
    'x (axis X) = -0.6 is not allowed: must be within [-0.5, 0] m; stay inside'
    """


def check_within_limits(
    name: str, x: float, limits: tuple[float, float], *, tolerance_m: float = 0.0, travel: str = ""
) -> None:
    """Refuse a target ``x`` (m, machine coordinates) outside the soft limits ``(low, high)``
    (m) widened by ``tolerance_m`` (half a step, as the controller rounds a target to its
    steps): :class:`StageLimitError` naming ``name`` on axis X; ``travel`` adds where the
    limits come from. The one soft-limit rule of the driver and of the bluesky device.

    >>> check_within_limits("x", -0.6, (-0.5, 0.0))
    Traceback (most recent call last):
    ...
    hil.devices.stage_errors.StageLimitError: x (axis X) = -0.6 is not allowed: must be within \
the soft limits [-0.5, 0] m of axis X; choose a target inside the limits; positions are \
machine coordinates in m (0 at home, negative along the travel)
    """
    low, high = limits
    if not (math.isfinite(x) and low - tolerance_m <= x <= high + tolerance_m):
        raise StageLimitError(
            f"{name} (axis X)",
            x,
            f"within the soft limits [{low:.6g}, {high:.6g}] m of axis X{travel}",
            "choose a target inside the limits; positions are machine coordinates in m (0 at"
            " home, negative along the travel)",
        )


class StageCommandError(StageError, DeviceRefused):
    """The controller answered ``error:<code>`` to ``line``."""

    def __init__(self, code: int, text: str, line: str, *, url: str | None = None) -> None:
        self.code = code
        self.text = text
        self.line = line
        super().__init__(
            f"GRBL rejected {line!r} with error:{code} ({text}); nothing from that line was "
            "executed: fix the command or the controller state and send it again",
            url=url,
        )


class StageAlarmError(StageError, DeviceRefused):
    """The controller is in ALARM; ``code`` is the alarm number if one was reported."""

    def __init__(
        self, code: int | None, text: str, recovery: str, *, url: str | None = None
    ) -> None:
        self.code = code
        self.text = text
        self.recovery = recovery
        what = f"ALARM:{code} ({text})" if code is not None else f"ALARM ({text})"
        super().__init__(f"stage is in {what}; to recover: {recovery}", url=url)


class StageHeldError(StageError, DeviceRefused):
    """Motion stopped in a feed hold before reaching its target."""


class StageTimeoutError(StageError, DeviceTimedOut):
    """The controller did not answer in time."""
