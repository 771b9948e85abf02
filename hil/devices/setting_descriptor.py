"""One declarative style for device settings: a typed descriptor with a unit and a validator.

:class:`TypedSetting` is what every device's settings share (pymeasure's ``control()``
idea as one generic descriptor): it converts a value to the setting's type, checks it, and
raises :class:`~hil.errors.ConfigError` naming the setting, the value, the allowed range
with its unit, and what to do. Where the value lives is the subclass's business: the board's
:class:`~hil.devices.board_settings.Setting` keeps it on the instance (the host chooses it),
GRBL's :class:`~hil.devices.grbl_settings.GrblSetting` reads it from the controller's ``$$``
dump (the controller holds it).

>>> class Demo:
...     gain_db = TypedSetting(float, unit="dB", check=lambda v: -6 <= v <= 6,
...                            allowed="-6 .. 6", hint="the amplifier's range")
>>> Demo.gain_db.validate(3)
3.0
>>> Demo.gain_db.validate(7)
Traceback (most recent call last):
...
hil.errors.ConfigError: gain_db = 7 is not allowed: must be -6 .. 6 dB; the amplifier's range
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Generic, TypeVar

from hil.errors import ConfigError

T = TypeVar("T")
Check = Callable[[Any], bool]


class TypedSetting(Generic[T]):
    """A setting's type, unit and validator (see the module docstring).

    Parameters
    ----------
    convert:
        Turns a given value into the setting's type, raising ``ValueError``/``TypeError``
        for values of the wrong kind.
    unit:
        Unit for messages ("Hz", "mm/min", "" for none).
    check:
        True for an allowed (converted) value.
    allowed:
        The allowed values in words, without the unit, for messages.
    hint:
        What to do about a bad value.
    takes_bool:
        Booleans are values of this setting (a switch); otherwise ``True`` is refused
        rather than taken for 1.
    """

    def __init__(
        self,
        convert: Callable[[Any], T],
        *,
        unit: str,
        check: Check,
        allowed: str,
        hint: str = "",
        takes_bool: bool = False,
    ) -> None:
        self.convert = convert
        self.unit = unit
        self.check = check
        self.allowed = allowed
        self.hint = hint
        self.takes_bool = takes_bool
        self.name = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @property
    def label(self) -> str:
        """How messages name the setting."""
        return self.name

    def allowed_text(self) -> str:
        """The allowed values with the unit."""
        return f"{self.allowed} {self.unit}".rstrip()

    def validate(self, value: Any) -> T:
        """The converted value, or ConfigError naming the setting, range and unit."""
        if isinstance(value, bool) and not self.takes_bool:
            raise ConfigError(self.label, value, self.allowed_text(), self.hint)
        try:
            converted = self.convert(value)
        except (TypeError, ValueError):
            raise ConfigError(self.label, value, self.allowed_text(), self.hint) from None
        if not self.check(converted):
            raise ConfigError(self.label, value, self.allowed_text(), self.hint)
        return converted
