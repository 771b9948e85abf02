"""pyserial ports (device paths, ``loop://``, ``socket://``, ptys) as transports."""

from __future__ import annotations

import contextlib
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


def open_serial(
    url: str,
    *,
    baudrate: int = 115200,
    timeout: float = 0.05,
    on_close: Callable[[], None] | None = None,
) -> SerialTransport:
    """Open a pyserial URL or device path as a :class:`SerialTransport`."""
    import serial

    try:
        port = serial.serial_for_url(url, baudrate=baudrate, timeout=timeout, write_timeout=5.0)
    except (serial.SerialException, OSError, ValueError) as error:
        if on_close is not None:
            on_close()
        raise TransportOpenError(
            f"cannot open {url!r}: {error}; check the device path, that no other program holds"
            " the port, and your permission (dialout group)"
        ) from error
    return SerialTransport(port, url, on_close=on_close)
