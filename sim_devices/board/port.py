"""Thread-safe access to a :class:`SimulatedBoard` for in-process links (memory, USB).

A :class:`BoardPort` ticks the board whenever the host polls it, so the board runs exactly
as fast as its clock says: real time with :func:`time.monotonic`, or as the test advances an
injected clock. ``faults.disconnect()`` makes every call raise
:class:`~hil.errors.TransportClosedError` until ``faults.replug()``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import TypeVar

from hil.errors import TransportClosedError
from sim_devices.board.core import SimulatedBoard

R = TypeVar("R")


class BoardPort:
    """The host end of an in-process link to ``board``; one host at a time.

    Parameters
    ----------
    board:
        The simulated board.
    poll_s:
        Real seconds between polls while the board has nothing to send.
    """

    def __init__(self, board: SimulatedBoard, *, poll_s: float = 0.0005) -> None:
        self.board = board
        self.lock = threading.RLock()
        self.poll_s = poll_s
        self._rx = bytearray()
        self.is_open = False

    def call(self, fn: Callable[[SimulatedBoard], R]) -> R:
        """Run ``fn(board)`` under the lock (safe from any thread)."""
        with self.lock:
            return fn(self.board)

    def _check(self, what: str) -> None:
        if self.board.faults.unplugged:
            if self.is_open:
                self.is_open = False
                self.board.connection_lost()
            raise TransportClosedError(
                f"simulated board unplugged during {what}; reconnect once it is back"
            )

    def open(self) -> None:
        """Plug the host in: the board starts a fresh session."""
        with self.lock:
            self._check("open")
            self._rx.clear()
            self.board.connection_made()
            self.is_open = True

    def close(self) -> None:
        """Unplug the host: the board drops its session."""
        with self.lock:
            if self.is_open:
                self.is_open = False
                self.board.connection_lost()

    def write(self, data: bytes) -> int:
        """Deliver host bytes to the board; returns the byte count."""
        with self.lock:
            self._check("write")
            self.board.receive_data(bytes(data))
        return len(data)

    def quiet_until_ns(self, awaited_index: int | None, max_bytes: int) -> int:
        """:meth:`SimulatedBoard.quiet_until_ns`; 0 (due at once) while bytes wait to be
        read or the port is closed."""
        with self.lock:
            if self._rx or not self.is_open:
                return 0
            return self.board.quiet_until_ns(awaited_index, max_bytes)

    def read(self, size: int, timeout_s: float) -> bytes:
        """Up to ``size`` board bytes, as soon as any exist; ``b""`` after ``timeout_s`` s."""
        deadline = time.monotonic() + timeout_s
        while True:
            with self.lock:
                self._check("read")
                if not self._rx:
                    self.board.tick()
                    self._rx += self.board.data_to_send()
                if self._rx:
                    out = bytes(self._rx[:size])
                    del self._rx[:size]
                    return out
            if time.monotonic() >= deadline:
                return b""
            time.sleep(self.poll_s)


class MemoryBoardLink:
    """A transport (the :class:`hil.transports.Transport` contract) wired into a board.

    >>> from firmware_protocol import Connection, Role
    >>> link = MemoryBoardLink(BoardPort(SimulatedBoard()))
    >>> host = Connection(Role.HOST)
    >>> _ = link.write(host.send(host.make_hello()))
    >>> host.receive_data(link.read(4096))
    >>> type(host.next_event()).__name__, type(host.next_event()).__name__
    ('Version', 'Capabilities')
    >>> link.close()
    """

    def __init__(
        self, port: BoardPort, *, timeout: float = 0.05, url: str = "sim://board?via=memory"
    ) -> None:
        self.port = port
        self.timeout = timeout
        self.url = url
        port.open()

    @property
    def board(self) -> SimulatedBoard:
        """The simulated board behind the link (hold ``port.lock`` to poke it)."""
        return self.port.board

    def read(self, size: int) -> bytes:
        """Up to ``size`` bytes, as soon as some arrive, or ``b""`` after :attr:`timeout` s."""
        return self.port.read(size, self.timeout)

    def write(self, data: bytes) -> int:
        """Send bytes to the board."""
        return self.port.write(data)

    def quiet_until_ns(self, awaited_index: int | None, max_bytes: int) -> int:
        """Board time (ns) before which the board only captures samples below
        ``awaited_index`` (None: none awaited), or idles, with nothing to send
        (:meth:`SimulatedBoard.quiet_until_ns`): a host on virtual time need not read it
        before then."""
        return self.port.quiet_until_ns(awaited_index, max_bytes)

    def close(self) -> None:
        """Unplug (idempotent)."""
        self.port.close()
