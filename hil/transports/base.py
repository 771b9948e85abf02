"""The transport contract every driver talks to, and the one I/O error tree.

A transport moves bytes and nothing else (the protocol is :mod:`firmware_protocol`'s job):

``read(size) -> bytes``
    Up to ``size`` bytes, returned as soon as *any* are available; ``b""`` when nothing
    arrived within :attr:`timeout` seconds. Never returns more than ``size``.
``write(data) -> int``
    Send all of ``data``; returns the byte count.
``close()``
    Release the link (idempotent). A transport that started a simulator stops it.
``timeout``
    Seconds one ``read`` may wait.
``url``
    What it was opened from (for messages).

I/O failures raise the :class:`~hil.errors.TransportError` tree (re-exported here; see
:mod:`hil.errors` for the whole tree): :class:`TransportClosedError` when the link is gone
(unplugged, hung up), :class:`TransportTimeoutError` when a write cannot complete,
:class:`TransportOpenError` when a device cannot be opened. Bad URLs are configuration
mistakes and raise :class:`~hil.errors.ConfigError` instead.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from hil.errors import (
    TransportClosedError,
    TransportError,
    TransportOpenError,
    TransportTimeoutError,
)

__all__ = [
    "Transport",
    "TransportClosedError",
    "TransportError",
    "TransportOpenError",
    "TransportTimeoutError",
]


@runtime_checkable
class Transport(Protocol):
    """A byte link (see the module docstring)."""

    timeout: float
    url: str

    def read(self, size: int) -> bytes: ...

    def write(self, data: bytes) -> int: ...

    def close(self) -> None: ...
