"""Put a sans-IO simulated device behind a real pseudo-terminal.

:class:`PtyEndpoint` opens a pty pair with :func:`os.openpty`, makes the slave raw with
:func:`tty.setraw` *before* anybody opens it (so no echo, no line editing, no CR/LF
translation ever touches the bytes), and runs a background thread that pumps bytes between
the master side and the device. A driver opens :attr:`PtyEndpoint.port_name` like any serial
port (``serial.serial_for_url(port_name)``).

The device contract (:class:`SansIODevice`)
-------------------------------------------
``receive_data(data: bytes) -> None``
    Bytes the host wrote, in order, in chunks of any size.
``data_to_send() -> bytes``
    Bytes for the host produced since the last call (the device forgets them).
``tick() -> None``
    Bring the device up to its own clock's present (finish moves, fire timers). The device
    owns its clock: give it :func:`time.monotonic` for real-time pacing, or a manual clock
    that the test advances (injected-clock mode); the endpoint never reads the time itself.
``connection_made() -> None`` and ``connection_lost() -> None`` (optional)
    A host opened the slave / the last host closed it (or died): a pty master sees a hang-up
    (``POLLHUP``/``EIO``) when no process holds the slave open.

All device calls are made from the pump thread while holding :attr:`PtyEndpoint.lock`; to
inspect or poke the device from another thread, hold the same lock. Every call must return
quickly and never block.

Examples
--------
>>> import serial
>>> class Echo:
...     def __init__(self): self.buf = b""
...     def receive_data(self, data): self.buf += data.upper()
...     def data_to_send(self): out, self.buf = self.buf, b""; return out
...     def tick(self): pass
>>> with PtyEndpoint(Echo()) as ep:
...     port = serial.serial_for_url(ep.port_name, timeout=2)
...     _ = port.write(b"abc\\r\\n")
...     port.read(5)
...     port.close()
b'ABC\\r\\n'
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import threading
import time
import tty
from types import TracebackType
from typing import Protocol


class SansIODevice(Protocol):
    """What a simulated device offers to :class:`PtyEndpoint` (see the module docstring)."""

    def receive_data(self, data: bytes) -> None: ...

    def data_to_send(self) -> bytes: ...

    def tick(self) -> None: ...


def tick_wait_s(next_tick: float, now: float) -> float:
    """Seconds the pump may sleep before the tick due at ``next_tick`` (s, monotonic): the
    exact remainder, never rounded down to zero while the tick is still ahead (a pump that
    waited zero would spin a core until the tick).

    >>> tick_wait_s(10.0004, 10.0) > 0, tick_wait_s(9.9, 10.0)
    (True, 0.0)
    """
    return max(0.0, next_tick - now)


class PtyEndpoint:
    """A raw pty whose master side is served by ``device`` from a background thread.

    Parameters
    ----------
    device:
        The sans-IO device (contract in the module docstring).
    poll_interval:
        Longest wait (s) between two ``tick`` calls; also the back-off while no host has
        the port open.
    """

    def __init__(self, device: SansIODevice, *, poll_interval: float = 0.002) -> None:
        self.device = device
        self.poll_interval = poll_interval
        self.lock = threading.RLock()
        self._master, slave = os.openpty()
        tty.setraw(slave)
        self.port_name = os.ttyname(slave)
        # Close our slave descriptor: the master then sees a hang-up whenever no host holds
        # the port, which is how a killed host is detected. The raw settings stay with the pty.
        os.close(slave)
        os.set_blocking(self._master, False)
        self._pending = bytearray()
        self._stop = threading.Event()
        self._host_present = False
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="pty-endpoint", daemon=True)

    def start(self) -> PtyEndpoint:
        """Start the pump thread (returns self)."""
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the pump thread and close the master side (the host sees a hang-up)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        with contextlib.suppress(OSError):
            os.close(self._master)
        if self._error is not None:
            raise RuntimeError(f"pty endpoint pump failed: {self._error!r}") from self._error

    @property
    def host_present(self) -> bool:
        """Whether a host currently holds the port open."""
        return self._host_present

    def __enter__(self) -> PtyEndpoint:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # ------------------------------------------------------------------ pump
    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as error:  # reported by close(); a dead pump must not be silent
            self._error = error

    def _loop(self) -> None:
        # The device ticks every poll_interval; output is written whenever the pty can take
        # it. Waiting for writability matters: a pty buffer holds only a few KB, so a loop that
        # waited for host input or the next tick before writing again would cap the stream
        # at one buffer per tick. select, not poll: its timeout has microsecond resolution,
        # so the pump sleeps exactly until the next tick (poll's milliseconds either spin
        # through the last one or tick up to a millisecond late, which starved the DAC FIFO).
        fd = self._master
        next_tick = time.monotonic()
        while not self._stop.is_set():
            writers = [fd] if self._pending else []
            readable, _, broken = select.select(
                [fd], writers, [fd], tick_wait_s(next_tick, time.monotonic())
            )
            hung_up = False
            if readable:
                # A master whose slave is closed reads as ready and then fails with EIO.
                hung_up |= self._read()
            if broken:
                hung_up = True
            self._set_host_present(not hung_up)
            now = time.monotonic()
            if now >= next_tick:
                next_tick = now + self.poll_interval
                with self.lock:
                    self.device.tick()
                    self._pending += self.device.data_to_send()
            else:
                with self.lock:
                    self._pending += self.device.data_to_send()
            self._write()
            if hung_up:
                # A hung-up master polls ready at once; back off instead of spinning.
                self._stop.wait(self.poll_interval)

    def _read(self) -> bool:
        """Read what the host wrote; return True if the host has hung up."""
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return False
        except OSError as error:
            if error.errno == errno.EIO:
                return True
            raise
        if data:
            self._set_host_present(True)
            with self.lock:
                self.device.receive_data(data)
        return not data

    def _write(self) -> None:
        while self._pending:
            try:
                sent = os.write(self._master, self._pending)
            except BlockingIOError:
                return  # the host is not reading; keep the bytes for later
            except OSError as error:
                if error.errno == errno.EIO:
                    return
                raise
            del self._pending[:sent]

    def _set_host_present(self, present: bool) -> None:
        if present == self._host_present:
            return
        self._host_present = present
        hook = "connection_made" if present else "connection_lost"
        with self.lock:
            callback = getattr(self.device, hook, None)
            if callback is not None:
                callback()
