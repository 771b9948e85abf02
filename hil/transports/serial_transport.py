"""pyserial ports (device paths, ``loop://``, ``socket://``, ptys) as transports."""

from __future__ import annotations

import contextlib
import os
import select
from collections.abc import Callable
from typing import Any

from hil.transports.base import TransportClosedError, TransportOpenError, TransportTimeoutError


class SerialTransport:
    """A pyserial port with the transport contract (:mod:`hil.transports.base`).

    ``read`` returns as soon as any byte is there (pyserial's own ``read(size)`` waits for
    all ``size`` bytes). pyserial errors become transport errors.

    Parameters
    ----------
    port:
        An open pyserial port (``serial.Serial`` or a ``serial_for_url`` result).
    url:
        What it was opened from.
    on_close:
        Called after the port closes (a simulator behind it stops).

    >>> t = open_serial("loop://", timeout=0.1)
    >>> t.write(b"ping"), t.read(100)
    (4, b'ping')
    >>> t.close()
    """

    def __init__(self, port: Any, url: str, *, on_close: Callable[[], None] | None = None) -> None:
        self.port = port
        self.url = url
        self._on_close = on_close
        self.closed = False
        self._posix = isinstance(port, _posix_serial_class())

    def identity(self) -> dict[str, str]:
        """The port's device path (or pyserial URL) and the USB ids pyserial lists for it
        (none for a pty)."""
        from hil.transports.identity import serial_port_identity

        path = self.port.port
        return serial_port_identity(path) if isinstance(path, str) else {}

    @property
    def timeout(self) -> float:
        """Seconds one read may wait."""
        return float(self.port.timeout)

    @timeout.setter
    def timeout(self, value: float) -> None:
        self.port.timeout = value

    def read(self, size: int) -> bytes:
        """Up to ``size`` bytes as soon as any arrive; ``b""`` after the timeout."""
        import serial

        fd = self._posix_fd()
        if fd is not None:
            return self._read_fd(fd, size)
        try:
            waiting = self.port.in_waiting
            if waiting:
                return bytes(self.port.read(min(waiting, size)))
            first = bytes(self.port.read(1))
            if not first or size == 1:
                return first
            waiting = self.port.in_waiting
            return first + bytes(self.port.read(min(waiting, size - 1))) if waiting else first
        except (serial.SerialException, OSError) as error:
            raise TransportClosedError(f"{self.url}: link lost while reading ({error})") from error

    def _posix_fd(self) -> int | None:
        """The descriptor of an open POSIX serial port (device or pty), else None."""
        if not self._posix:
            return None
        fd = getattr(self.port, "fd", None)
        return fd if isinstance(fd, int) and getattr(self.port, "is_open", False) else None

    def _read_fd(self, fd: int, size: int) -> bytes:
        """One ``select`` and one ``read`` of the non-blocking descriptor: at 4 MB/s the
        reader calls this about 1500 times a second, and pyserial's ``in_waiting`` then
        ``read`` take five system calls (each a GIL hand-over) where two do."""
        try:
            ready, _, _ = select.select([fd], [], [], self.port.timeout)
            if not ready:
                return b""
            data = os.read(fd, size)
        except (BlockingIOError, InterruptedError):
            return b""
        except (OSError, ValueError) as error:
            raise TransportClosedError(f"{self.url}: link lost while reading ({error})") from error
        if not data:
            # Readable but empty: a hung-up device (pyserial raises the same way).
            raise TransportClosedError(f"{self.url}: link lost while reading (hang-up)")
        return data

    def write(self, data: bytes) -> int:
        """Send all of ``data``."""
        import serial

        try:
            written = self.port.write(data)
        except serial.SerialTimeoutException as error:
            raise TransportTimeoutError(f"{self.url}: write timed out ({error})") from error
        except (serial.SerialException, OSError) as error:
            raise TransportClosedError(f"{self.url}: link lost while writing ({error})") from error
        return len(data) if written is None else int(written)

    def close(self) -> None:
        """Close the port (and whatever serves it); idempotent."""
        if self.closed:
            return
        self.closed = True
        with contextlib.suppress(Exception):
            self.port.close()
        if self._on_close is not None:
            self._on_close()


def _posix_serial_class() -> type:
    """pyserial's POSIX port class (a class nothing is an instance of elsewhere)."""
    try:
        from serial.serialposix import Serial
    except ImportError:  # pragma: no cover - Windows
        return type("NoPosixSerial", (), {})
    return Serial


def open_serial(
    url: str,
    *,
    baudrate: int = 115200,
    timeout: float = 0.05,
    on_close: Callable[[], None] | None = None,
    dtr: bool | None = None,
    rts: bool | None = None,
) -> SerialTransport:
    """Open a pyserial URL or device path as a :class:`SerialTransport`.

    ``dtr``/``rts``: the level of that modem line, set before the port opens so pyserial
    applies it as it opens (``None``: pyserial's default, raised). An Arduino Uno or Nano
    resets on a raised DTR; ``dtr=False`` keeps it running (see docs/grbl-stage.md for the
    brief pulse some operating systems give at open regardless).

    >>> t = open_serial("loop://", timeout=0.1, dtr=False, rts=False)
    >>> t.port.dtr, t.port.rts
    (False, False)
    >>> t.close()
    """
    import serial

    try:
        port = serial.serial_for_url(
            url, baudrate=baudrate, timeout=timeout, write_timeout=5.0, do_not_open=True
        )
        if dtr is not None:
            port.dtr = dtr
        if rts is not None:
            port.rts = rts
        port.open()
    except (serial.SerialException, OSError, ValueError) as error:
        if on_close is not None:
            on_close()
        raise TransportOpenError(
            f"cannot open {url!r}: {error}; check the device path, that no other program holds"
            " the port, and your permission (dialout group)"
        ) from error
    return SerialTransport(port, url, on_close=on_close)
