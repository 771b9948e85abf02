"""Run-time failures of the transducer board: :class:`BoardError` and the refusal of a
command, :class:`BoardCommandError` (configuration mistakes are :class:`hil.errors.ConfigError`).

Both carry the board's URL, so a message always says which device failed.
"""

from __future__ import annotations

from firmware_protocol import Nak
from hil.errors import DeviceError, DeviceRefused


class BoardError(DeviceError):
    """Base class of run-time board failures (not configuration mistakes)."""


class BoardCommandError(BoardError, DeviceRefused):
    """The board refused a command (NAK) or did not answer it."""

    def __init__(self, message: str, nak: Nak | None = None, *, url: str | None = None) -> None:
        super().__init__(message, url=url)
        self.nak = nak
