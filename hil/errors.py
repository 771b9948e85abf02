"""Error types shared by the host package.

Every configuration error names the field, the value, the allowed range and what to do, so
the command line can print it as one line and exit with status 2 (see :mod:`hil.cli.main`).
"""

from __future__ import annotations

from typing import Any


class ConfigError(ValueError):
    """A setting, option or input is invalid.

    Parameters
    ----------
    field:
        Name of the offending setting as the user wrote it (``"n_tones"``, ``"--fs"``).
    value:
        The value given.
    allowed:
        The allowed range or set, in words (``">= 3"``, ``"one of att, tank-audio"``).
    hint:
        What to do about it.

    Examples
    --------
    >>> str(ConfigError("fs_hz", 40000.0, "> 2 x 31500 Hz (Nyquist)", "raise --fs"))
    'fs_hz = 40000.0 is not allowed: must be > 2 x 31500 Hz (Nyquist); raise --fs'
    """

    def __init__(self, field: str, value: Any, allowed: str, hint: str = "") -> None:
        self.field = field
        self.value = value
        self.allowed = allowed
        self.hint = hint
        message = f"{field} = {value!r} is not allowed: must be {allowed}"
        if hint:
            message += f"; {hint}"
        super().__init__(message)


class ConfigErrors(ConfigError):
    """Every problem of one input (a config file) at once, one line each.

    ``errors`` holds them in the order found; ``field``, ``value``, ``allowed`` and ``hint``
    are the first one's, so code that handles one :class:`ConfigError` still works.

    Examples
    --------
    >>> both = ConfigErrors([ConfigError("tow.speed_mps", -1.0, "> 0 m/s"),
    ...                      ConfigError("tow.repeats", 0, "an integer >= 1")])
    >>> print(both)
    tow.speed_mps = -1.0 is not allowed: must be > 0 m/s
    tow.repeats = 0 is not allowed: must be an integer >= 1
    >>> both.field, len(both.errors)
    ('tow.speed_mps', 2)
    """

    def __init__(self, errors: list[ConfigError]) -> None:
        if not errors:
            raise ValueError("ConfigErrors needs at least one error")
        first = errors[0]
        super().__init__(first.field, first.value, first.allowed, first.hint)
        self.errors: tuple[ConfigError, ...] = tuple(errors)
        self.args = ("\n".join(str(e) for e in self.errors),)
