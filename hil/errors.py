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
