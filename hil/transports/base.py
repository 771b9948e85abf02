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
    "IdentifiedTransport",
    "QuietTransport",
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


@runtime_checkable
class QuietTransport(Transport, Protocol):
    """A transport whose device says how long it has nothing to send (an in-process
    simulated board: :class:`~sim_devices.board.port.MemoryBoardLink`), so that a host on
    virtual time skips the reads that would return nothing
    (:meth:`~hil.devices.board_link_virtual.VirtualTimeBoardLink.quiet_until_ns`)."""

    def quiet_until_ns(self, awaited_index: int | None, max_bytes: int) -> int:
        """Device time (ns) before which the device only captures samples below
        ``awaited_index`` (None: none awaited), or idles, with nothing to send in reads of
        ``max_bytes``."""
        ...


@runtime_checkable
class IdentifiedTransport(Transport, Protocol):
    """A transport that can say what it resolved to, for the run's record of what was
    connected (:func:`~hil.transports.identity.port_identity`): a serial port, a USB
    device, a spy around one."""

    def identity(self) -> dict[str, str]:
        """``port``, ``usb_vid_pid``, ``usb_serial``, ``manufacturer``, ``product`` as far
        as they are known."""
        ...
