"""The one error tree of the host package and its simulated devices.

::

    HilError
    ├── ConfigError (also a ValueError)   a setting, option or input is invalid
    └── DeviceError                       a device failed; its URL starts the message
        ├── DeviceUnavailable             it cannot be opened (missing, busy, no permission)
        ├── DeviceRefused                 it answered with a refusal (NAK, error:N, alarm)
        ├── DeviceTimedOut                it did not answer in time
        └── DeviceLost                    its link went away while in use

The drivers' own classes hang under these (``hil.devices.stage_errors``, the board's
``BoardError``, the run's ``DeviceLostError``); the byte links' errors are here too
(:class:`TransportError` and its three kinds), so the simulated devices, which may import
this module and no driver, raise the same classes as the real links.

Every configuration error names the field, the value, the allowed range and what to do, so
the command line can print it as one line and exit with status 2 (see :mod:`hil.cli.main`).
Every device error names the device by its URL (``url=``, or set later by the driver that
knows it, before the error leaves the driver), so a message read alone in a log says which
of the run's devices failed.

>>> str(DeviceTimedOut("no answer to $$ within 2 s: check the cable", url="/dev/ttyUSB0"))
'/dev/ttyUSB0: no answer to $$ within 2 s: check the cable'
>>> issubclass(TransportClosedError, DeviceLost), issubclass(ConfigError, HilError)
(True, True)
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "ConfigError",
    "DeviceError",
    "DeviceLost",
    "DeviceRefused",
    "DeviceTimedOut",
    "DeviceUnavailable",
    "HilError",
    "TransportClosedError",
    "TransportError",
    "TransportOpenError",
    "TransportTimeoutError",
    "device_url",
]


class HilError(Exception):
    """Base of every error the host package raises on purpose."""


class DeviceError(HilError):
    """A device failed at run time (not a configuration mistake).

    Parameters
    ----------
    message:
        What happened and what to check.
    url:
        The device's URL (``/dev/ttyUSB0``, ``sim://stage``); None when the raiser does not
        know it: the driver that does sets :attr:`url` before the error leaves it.
    """

    def __init__(self, message: str = "", *, url: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.url = url

    def __str__(self) -> str:
        if self.url and self.url not in self.message:
            return f"{self.url}: {self.message}"
        return self.message


class DeviceUnavailable(DeviceError):
    """The device cannot be opened: missing, unplugged, busy, no permission, no driver."""


class DeviceRefused(DeviceError):
    """The device answered, with a refusal (a NAK, GRBL's ``error:N``, an alarm, a hold)."""


class DeviceTimedOut(DeviceError):
    """The device did not answer in time."""


class DeviceLost(DeviceError):
    """The device's link went away while in use (unplugged, powered off, process killed)."""


class TransportError(DeviceError):
    """Base of the byte links' I/O errors (serial ports, USB, sockets, pseudo-terminals)."""


class TransportOpenError(TransportError, DeviceUnavailable):
    """The device named by a URL could not be opened (missing, busy, no permission)."""


class TransportTimeoutError(TransportError, DeviceTimedOut):
    """No byte arrived (or a write did not complete) within the link's timeout."""


class TransportClosedError(TransportError, DeviceLost):
    """The link was closed (port unplugged, socket reset, pty closed)."""


def device_url(error: BaseException, url: str) -> BaseException:
    """``error`` naming the device ``url`` when it is a :class:`DeviceError` that does not
    name one yet (a driver calls this as an error leaves it); ``error`` itself.

    >>> str(device_url(DeviceLost("link closed"), "sim://board"))
    'sim://board: link closed'
    """
    if isinstance(error, DeviceError) and not error.url:
        error.url = url
    return error


class ConfigError(HilError, ValueError):
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
