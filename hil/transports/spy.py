"""``spy://``: wrap any transport and dump its traffic, with timestamps and direction.

One line per 16 bytes: seconds since the spy opened, ``TX`` (host to device) or ``RX``,
the offset within that read/write, the bytes in hex and in ASCII (``.`` for the rest)::

    0.000153 TX 0000  02 01 01 01 01 07 01 01 ...            ................
"""

from __future__ import annotations

import time
from typing import TextIO

from hil.transports.base import Transport


def hexdump_lines(data: bytes, width: int = 16) -> list[tuple[int, str, str]]:
    """``(offset, hex, ascii)`` per ``width`` bytes.

    >>> hexdump_lines(b"ok\\x00\\xff")
    [(0, '6f 6b 00 ff', 'ok..')]
    """
    rows = []
    for offset in range(0, len(data), width):
        chunk = data[offset : offset + width]
        text = "".join(chr(b) if 32 <= b < 127 else "." for b in chunk)
        rows.append((offset, chunk.hex(" "), text))
    return rows


class SpyTransport:
    """A transport that logs every byte through ``inner`` to ``log``.

    >>> import io
    >>> from hil.transports.serial_transport import open_serial
    >>> log = io.StringIO()
    >>> spy = SpyTransport(open_serial("loop://", timeout=0.1), log, clock=lambda: 0.0)
    >>> _ = spy.write(b"hi"); spy.read(10)
    b'hi'
    >>> print(log.getvalue(), end="")
    0.000000 TX 0000  68 69                                            hi
    0.000000 RX 0000  68 69                                            hi
    >>> spy.close()
    """

    def __init__(
        self,
        inner: Transport,
        log: TextIO,
        *,
        owns_log: bool = False,
        clock: object = None,
    ) -> None:
        self.inner = inner
        self.url = f"spy://{inner.url}"
        self._log = log
        self._owns_log = owns_log
        self._clock = clock if callable(clock) else time.monotonic
        self._t0 = float(self._clock())

    @property
    def timeout(self) -> float:
        """The inner transport's read timeout, s."""
        return self.inner.timeout

    @timeout.setter
    def timeout(self, value: float) -> None:
        self.inner.timeout = value

    def identity(self) -> dict[str, str]:
        """What the inner transport resolved to (:func:`~hil.transports.identity.port_identity`)."""
        from hil.transports.identity import port_identity

        return port_identity(self.inner)

    def _dump(self, direction: str, data: bytes) -> None:
        t = float(self._clock()) - self._t0
        for offset, hexes, text in hexdump_lines(data):
            self._log.write(f"{t:.6f} {direction} {offset:04x}  {hexes:<48} {text}\n")
        self._log.flush()

    def read(self, size: int) -> bytes:
        """Read through the inner transport and log what came."""
        data = self.inner.read(size)
        if data:
            self._dump("RX", data)
        return data

    def write(self, data: bytes) -> int:
        """Log, then write through the inner transport."""
        self._dump("TX", bytes(data))
        return self.inner.write(data)

    def close(self) -> None:
        """Close the inner transport and the log file (if the spy opened it)."""
        try:
            self.inner.close()
        finally:
            if self._owns_log:
                self._log.close()
