"""Put a sans-IO simulated device behind a real pseudo-terminal.

:class:`PtyEndpoint` opens a pty pair with :func:`os.openpty`, makes the slave raw with
:func:`tty.setraw` *before* anybody opens it (so no echo, no line editing, no CR/LF
translation ever touches the bytes), and serves the master side from two background threads:
an I/O thread that moves bytes between the pty and two in-memory queues whenever the pty is
readable or writable, and a device thread that feeds the host's bytes to the device, ticks it
and queues its output. A driver opens :attr:`PtyEndpoint.port_name` like any serial
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

All device calls are made from the device thread while holding :attr:`PtyEndpoint.lock`; to
inspect or poke the device from another thread, hold the same lock. A call may take a while
(a simulated world computing a whole tick): the host's bytes keep flowing both ways
meanwhile, as a UART with its own FIFOs keeps moving bytes while firmware computes. Input
and connection changes reach the device in arrival order; output leaves in the order the
device produced it (:attr:`PtyEndpoint.output_backlog` is what the host has not taken yet).

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
from collections import deque
from collections.abc import Callable
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
    """A raw pty whose master side is served by ``device`` from two background threads.

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
        # The device thread hands output to the I/O thread through ``_outgoing`` and wakes
        # it through a pipe (it may sit in select); the I/O thread hands host bytes and
        # connection changes to the device thread through ``_incoming`` in arrival order.
        self._io_lock = threading.Lock()
        self._outgoing = bytearray()
        self._incoming: deque[bytes | bool] = deque()
        self._wake_io_r, self._wake_io_w = os.pipe()
        os.set_blocking(self._wake_io_r, False)
        os.set_blocking(self._wake_io_w, False)
        self._wake_device = threading.Event()
        self._stop = threading.Event()
        self._host_present = False
        self._error: BaseException | None = None
        self._closed = False
        self._threads = (
            threading.Thread(target=self._run, args=(self._io_loop,), name="pty-io", daemon=True),
            threading.Thread(
                target=self._run, args=(self._device_loop,), name="pty-device", daemon=True
            ),
        )

    def start(self) -> PtyEndpoint:
        """Start serving (returns self)."""
        for thread in self._threads:
            thread.start()
        return self

    def close(self) -> None:
        """Stop both threads and close the master side (the host sees a hang-up)."""
        self._stop.set()
        self._wake_io()
        self._wake_device.set()
        for thread in self._threads:
            if thread.is_alive():
                thread.join(timeout=5.0)
        if not self._closed and not any(t.is_alive() for t in self._threads):
            # A thread still inside a device call keeps its descriptors: closed, their
            # numbers could be reused by another pty before it touches them again.
            self._closed = True
            for fd in (self._master, self._wake_io_r, self._wake_io_w):
                with contextlib.suppress(OSError):
                    os.close(fd)
        if self._error is not None:
            raise RuntimeError(f"pty endpoint pump failed: {self._error!r}") from self._error

    @property
    def host_present(self) -> bool:
        """Whether a host currently holds the port open."""
        return self._host_present

    @property
    def output_backlog(self) -> int:
        """Bytes the device has produced that the host has not taken yet (beyond what the
        pty itself buffers)."""
        with self._io_lock:
            return len(self._outgoing)

    def __enter__(self) -> PtyEndpoint:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # ------------------------------------------------------------------ threads
    def _run(self, loop: Callable[[], None]) -> None:
        try:
            loop()
        except BaseException as error:  # reported by close(); a dead pump must not be silent
            if self._error is None:
                self._error = error
            self._stop.set()  # the other thread stops too: half a device is no device
            self._wake_io()
            self._wake_device.set()

    def _wake_io(self) -> None:
        with contextlib.suppress(BlockingIOError, OSError):
            os.write(self._wake_io_w, b"\0")  # a full pipe already holds a wake-up

    def _device_loop(self) -> None:
        # Device calls (which may be slow: a simulated world computing a whole tick) run
        # here, never in the I/O thread: while a tick computes, the I/O thread goes on
        # moving bytes both ways. With one thread doing both, a tick longer than the poll
        # interval let out only what the pty buffers (about 14 KB) per tick; a simulated
        # board whose world took 0.2 s per tick queued 0.5 MB of ADC data, its CREDIT
        # messages queued behind it, and the host could not refill the DAC FIFO in time.
        next_tick = time.monotonic()
        while not self._stop.is_set():
            # Event.wait sleeps to the microsecond: a wait rounded to whole milliseconds
            # ticked up to a millisecond late at 1 MS/s and starved the DAC FIFO.
            self._wake_device.wait(tick_wait_s(next_tick, time.monotonic()))
            self._wake_device.clear()  # before taking the input: a later arrival re-sets it
            with self._io_lock:
                # What the pty holds now goes in before the service pass: this device shares
                # the CPU with its host, and after a stall of this process the host's bytes
                # that arrived meanwhile must reach it before its watchdog judges the host
                # silent (a real board hears them as they arrive).
                self._take_pending()
                incoming = list(self._incoming)
                self._incoming.clear()
            with self.lock:
                for item in _joined(incoming):
                    if isinstance(item, bool):
                        hook = getattr(
                            self.device, "connection_made" if item else "connection_lost", None
                        )
                        if hook is not None:
                            hook()
                    else:
                        self.device.receive_data(item)
                now = time.monotonic()
                if now >= next_tick:
                    next_tick = now + self.poll_interval
                    self.device.tick()
                out = self.device.data_to_send()
            if out:
                with self._io_lock:
                    self._outgoing += out
                self._wake_io()

    def _io_loop(self) -> None:
        # select, not poll: its timeout has microsecond resolution (the back-off below).
        fd, wake = self._master, self._wake_io_r
        while not self._stop.is_set():
            with self._io_lock:
                writers = [fd] if self._outgoing else []
            # A host opening the port shows no event on the master: until one is present,
            # look again every poll interval (a hang-up, though, reads ready at once).
            timeout = None if self._host_present else self.poll_interval
            readable, writable, broken = select.select([fd, wake], writers, [fd], timeout)
            if wake in readable:
                with contextlib.suppress(BlockingIOError):
                    os.read(wake, 4096)
            hung_up = bool(broken)
            if fd in readable:
                # A master whose slave is closed reads as ready and then fails with EIO.
                hung_up |= self._read()
            if writable and not hung_up:
                self._write()
            self._set_host_present(not hung_up)
            if hung_up:
                # A hung-up master selects ready at once; back off instead of spinning.
                self._stop.wait(self.poll_interval)

    def _read(self) -> bool:
        """Read what the host wrote into the device's input; True if the host hung up."""
        with self._io_lock:  # one reader at a time, appending as it reads: input in order
            try:
                data = os.read(self._master, 65536)
            except BlockingIOError:
                return False
            except OSError as error:
                if error.errno == errno.EIO:
                    return True
                raise
            if not data:
                return True
            self._arrived(data)
        self._wake_device.set()
        return False

    def _arrived(self, data: bytes) -> None:
        """Append host bytes to the input (called holding ``_io_lock``); bytes mean a host."""
        if not self._host_present:
            self._host_present = True
            self._incoming.append(True)
        self._incoming.append(data)

    def _take_pending(self) -> None:
        """Append to the input what the pty holds now (called holding ``_io_lock``); a hang-up
        or an empty pty ends it (the I/O thread reports a hang-up)."""
        while True:
            try:
                data = os.read(self._master, 65536)
            except OSError:  # BlockingIOError: nothing more; EIO: the host hung up
                return
            if not data:
                return
            self._arrived(data)

    def _write(self) -> None:
        """Write as much pending output as the pty takes now."""
        with self._io_lock:
            chunk = bytes(self._outgoing[:65536])
        try:
            sent = os.write(self._master, chunk)
        except BlockingIOError:
            return  # the host is not reading; keep the bytes for later
        except OSError as error:
            if error.errno == errno.EIO:
                return
            raise
        with self._io_lock:
            del self._outgoing[:sent]  # only this thread takes from the front

    def _set_host_present(self, present: bool) -> None:
        if present == self._host_present:
            return
        self._host_present = present
        with self._io_lock:
            self._incoming.append(present)
        self._wake_device.set()


def _joined(items: list[bytes | bool]) -> list[bytes | bool]:
    """Runs of consecutive byte chunks joined into one, connection changes kept in place.

    >>> _joined([True, b"ab", b"c", False, b"d"])
    [True, b'abc', False, b'd']
    """
    out: list[bytes | bool] = []
    run: list[bytes] = []
    for item in items:
        if isinstance(item, bool):
            if run:
                out.append(b"".join(run))
                run = []
            out.append(item)
        else:
            run.append(item)
    if run:
        out.append(b"".join(run))
    return out
