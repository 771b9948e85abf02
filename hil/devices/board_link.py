"""The I/O under the board driver: :class:`BoardLink`, and its threaded form.

The driver (:class:`~hil.devices.board.Board`) holds the protocol session and the DAC
feeder and does no I/O scheduling of its own; a link carries it. A link holds the transport,
the frames encoded but not yet written, the session lock, and decides who reads the link and
feeds the DAC and how a wait passes:

- :class:`ThreadedBoardLink`: a reader and a writer thread over a real transport, waits on
  the wall clock, reconnects (the driver's policy) from the reader thread when the link drops;
- :class:`~hil.devices.board_link_virtual.VirtualTimeBoardLink`: no threads, one service
  ticked by a :class:`~hil.devices.clock.VirtualClock`, waits slept on that clock.

The driver chooses the link once, when it is made; from then on it calls only the methods of
:class:`BoardLink`, and the link calls back only through :class:`LinkHooks`.

Locking: every frame is encoded under the one session lock (:attr:`BoardLink.lock`), which
also guards the protocol state, and queued (:meth:`BoardLink.queue`), so frames leave in
sequence order; the write itself happens outside that lock, one writer at a time
(:meth:`BoardLink.flush`), so a link that is slow to take a DAC burst never holds up the
reader.
"""

from __future__ import annotations

import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

from hil.acquisition import SampleRing
from hil.devices.board_errors import BoardError
from hil.devices.board_log import LOG
from hil.devices.clock import Clock
from hil.transports import (
    Transport,
    TransportClosedError,
    TransportError,
    TransportTimeoutError,
)

#: Bytes asked of the transport per read.
READ_SIZE = 1 << 16
#: Longest idle sleep of the writer thread (s): notifications wake it sooner; the cap bounds
#: the effect of a missed one without waking it hundreds of times a second.
WRITER_IDLE_S = 0.05
#: The writer's and a lost link's short pause before looking again (s).
_RETRY_S = 0.005


@dataclass(frozen=True)
class LinkHooks:
    """What a link asks of the driver it carries (the driver's session and DAC feeder).

    ``receive`` is called holding the session lock (a reentrant lock: the driver may take it
    again); the other hooks take it themselves where they touch the session.
    """

    url: Callable[[], str]
    """Where the board is, for messages."""
    receive: Callable[[bytes], str | None]
    """Handle bytes read from the link (called holding the session lock); returns why the
    link is lost (the board closed the session), or None."""
    link_lost: Callable[[str], None]
    """Record that the link was lost, and why."""
    refusal: Callable[[], BaseException | None]
    """The handshake's refusal (an incompatible board) that every wait raises, or None."""
    feed_dac: Callable[[], bool]
    """Send DAC frames within the credit; True if any went out."""
    keepalive_if_due: Callable[[], None]
    """Send a KEEPALIVE if one is due."""
    next_keepalive_s: Callable[[], float | None]
    """Clock time the next KEEPALIVE is due (s), or None when keepalives are off."""
    dac_pending: Callable[[], bool]
    """True while DAC samples are waiting and the board grants credit for them."""
    reconnect: Callable[[], None]
    """Reopen a lost link with the driver's policy (raises when it gives up)."""


class BoardLink(ABC):
    """One interface for the I/O under the board driver (see the module docstring).

    Shared by every form: the transport and whether it is up, the session lock and its
    condition, the queue of encoded frames and its flush, and one read of the link handed to
    the driver (:meth:`pump_once`). Each form says how the reading and the DAC feeding run
    (:meth:`open`, :meth:`close`) and how a wait passes (:meth:`wait`,
    :meth:`wait_for_samples`), on its :attr:`clock`.
    """

    def __init__(self, clock: Clock, hooks: LinkHooks) -> None:
        self.clock = clock
        self.hooks = hooks
        #: The session lock: held around every change of the protocol session and the queue.
        self.lock = threading.RLock()
        #: Waiters on the session (credit, replies, SYNC, errors) wait on it.
        self.cond = threading.Condition(self.lock)
        self.transport: Transport | None = None
        #: The transport is connected and not known lost.
        self.up = False
        self._outgoing = bytearray()  # encoded frames not yet written, in sequence order
        self._write_lock = threading.Lock()  # held by the one thread writing (see flush)
        self._closing = threading.Event()

    @property
    def closing(self) -> bool:
        """The link is being closed: a reconnect in progress gives up."""
        return self._closing.is_set()

    # ------------------------------------------------------------------ per form
    @abstractmethod
    def open(self, connect: Callable[[], None]) -> None:
        """Run ``connect()`` (open the transport and handshake) and from then on read the
        link and feed the DAC in the background. If ``connect`` raises, nothing runs."""

    @abstractmethod
    def close(self) -> None:
        """Stop the background reading and feeding (the transport stays for the driver)."""

    @abstractmethod
    def wait(
        self,
        done: Callable[[], bool],
        timeout_s: float,
        what: str,
        progress: Callable[[], int] | None = None,
    ) -> None:
        """Return once ``done()`` holds (checked under the session lock).

        Raises the driver's refusal, TransportTimeoutError after ``timeout_s`` (naming
        ``what``), TransportClosedError if the link is lost meanwhile. With ``progress`` (a
        count that grows while the awaited thing is on its way: the samples of a DAC preload
        sent), the timeout counts from its last growth: a starved host or a slow board that
        still takes samples waits on, a stuck one fails after ``timeout_s``.
        """

    @abstractmethod
    def wait_for_samples(self, ring: SampleRing, end_index: int, timeout_s: float) -> bool:
        """Wait until ``ring`` holds samples up to ``end_index``; False after ``timeout_s``."""

    # ------------------------------------------------------------------ shared
    def connect(self, transport: Transport) -> None:
        """Use ``transport`` from now on; frames queued for an old one are dropped (they
        belong to the old session). Called holding the session lock."""
        with self.lock:
            self.transport = transport
            self._outgoing.clear()
            self.up = True

    def disconnect(self) -> Transport | None:
        """Forget the transport (the caller closes it); returns it."""
        with self.lock:
            transport, self.transport = self.transport, None
            self.up = False
        return transport

    def queue(self, frames: bytes) -> None:
        """Queue encoded frames for the next :meth:`flush` (called holding the lock)."""
        self._outgoing += frames

    @property
    def queued(self) -> bool:
        """Frames are queued and not yet written."""
        return bool(self._outgoing)

    def wake(self) -> None:
        """Wake whoever waits on the session (a reply, credit, a new DAC source)."""
        with self.cond:
            self.cond.notify_all()

    def flush(self) -> None:
        """Write the queued frames in sequence order, without holding the session lock.

        Frames are encoded (sequence numbers, credit) under the lock and queued; the write,
        which blocks while the link is full (a 64 KB DAC burst: milliseconds), happens
        outside it, so the reader keeps taking ADC data meanwhile. One thread writes at a
        time and keeps writing until the queue is empty; a sender that finds a write in
        progress leaves its bytes to that thread. The write lock is released under the
        session lock once the queue is seen empty, so no queued byte is ever left behind.
        """
        if not self._write_lock.acquire(blocking=False):
            return
        held = True
        try:
            while True:
                with self.lock:
                    data = bytes(self._outgoing)
                    self._outgoing.clear()
                    transport = self.transport
                    if not data or transport is None:
                        self._write_lock.release()
                        held = False
                        return
                transport.write(data)
        finally:
            if held:
                self._write_lock.release()

    def pump_once(self) -> bool:
        """Read once and hand what arrived to the driver; False if the link is lost."""
        transport = self.transport
        if transport is None or not self.up:
            return False
        try:
            data = transport.read(READ_SIZE)
        except TransportError as error:
            self.lost(str(error))
            return False
        if not data:
            return True
        with self.cond:
            why = self.hooks.receive(data)
            if why is not None:
                self.lost(why)
                return False
        return True

    def lost(self, why: str) -> None:
        """The link dropped: mark it down and have the driver record it (once per loss)."""
        if not self.up:
            return
        self.up = False
        LOG.debug("board %s: link lost: %s", self.hooks.url(), why)
        self.hooks.link_lost(why)


class ThreadedBoardLink(BoardLink):
    """A reader and a writer thread over a real transport; waits on the wall clock.

    The reader owns all receiving and reconnects (the driver's policy) when the link drops.
    The writer feeds the DAC within the credit and sends keepalives; it sleeps while there
    is nothing to send, until credit, a new source, a reply or a stop notifies it, or the
    next keepalive is due. A thread that fails leaves its error for the next wait to raise.
    ``clock`` times the keepalives, the backoff and the host's SYNC stamps; wait timeouts
    are real seconds: waiting for bytes is waiting for I/O, which a clock cannot speed up.
    """

    def __init__(self, clock: Clock, hooks: LinkHooks) -> None:
        super().__init__(clock, hooks)
        self._reader: threading.Thread | None = None
        self._writer: threading.Thread | None = None
        self._thread_error: BaseException | None = None

    def open(self, connect: Callable[[], None]) -> None:
        self._thread_error = None
        connect()  # pumps the link itself: no reader runs yet
        self._closing.clear()
        self._reader = threading.Thread(target=self._guard(self._read_loop), daemon=True)
        self._writer = threading.Thread(target=self._guard(self._write_loop), daemon=True)
        self._reader.name, self._writer.name = "board-reader", "board-writer"
        self._reader.start()
        self._writer.start()

    def close(self) -> None:
        self._closing.set()
        self.wake()
        for thread in (self._reader, self._writer):
            if thread is not None and thread is not threading.current_thread():
                thread.join(timeout=5.0)
        self._reader = self._writer = None

    def wait(
        self,
        done: Callable[[], bool],
        timeout_s: float,
        what: str,
        progress: Callable[[], int] | None = None,
    ) -> None:
        """See :meth:`BoardLink.wait`; ``timeout_s`` is real seconds. Without a reader
        thread (the handshake of :meth:`open`), or on it (a reconnect), the waiter pumps the
        link itself."""
        deadline = time.monotonic() + timeout_s
        moved = progress() if progress is not None else 0
        pumping = self._reader is None or threading.current_thread() is self._reader
        while True:
            with self.cond:
                if done():
                    return
                if progress is not None and progress() != moved:
                    moved, deadline = progress(), time.monotonic() + timeout_s
                refusal = self.hooks.refusal()
                if refusal is not None:
                    raise refusal
                if self._thread_error is not None:
                    url = self.hooks.url()
                    raise BoardError(f"{url}: reader failed", url=url) from self._thread_error
                if time.monotonic() >= deadline:
                    url = self.hooks.url()
                    LOG.debug("board %s: timed out after %s s waiting for %s", url, timeout_s, what)
                    raise TransportTimeoutError(
                        f"{url}: no {what} within {timeout_s} s; check that the board is"
                        " powered, the URL is right, and nothing else holds the port"
                    )
                if not pumping:
                    self.cond.wait(0.01)
            if pumping and not self.pump_once():
                raise TransportClosedError(
                    f"{self.hooks.url()}: link lost while waiting for {what}"
                )

    def wait_for_samples(self, ring: SampleRing, end_index: int, timeout_s: float) -> bool:
        return ring.wait_for(end_index, timeout_s)

    def _guard(self, loop: Callable[[], None]) -> Callable[[], None]:
        def run() -> None:
            try:
                loop()
            except BaseException as error:  # reported by the next wait of the user
                self._thread_error = error
                with self.cond:
                    self.up = False
                    self.cond.notify_all()

        return run

    def _read_loop(self) -> None:
        while not self._closing.is_set():
            if not self.pump_once():
                self.hooks.reconnect()

    def _write_loop(self) -> None:
        while not self._closing.is_set():
            if not self.up:
                self._closing.wait(_RETRY_S)
                continue
            try:
                sent = self.hooks.feed_dac()
                self.hooks.keepalive_if_due()
            except TransportError:
                self._closing.wait(_RETRY_S)  # the reader sees the loss and reconnects
                continue
            if not sent:
                with self.cond:
                    self.cond.wait(self._idle_s())

    def _idle_s(self) -> float:
        """How long the writer may sleep when it has nothing to send: until the next
        keepalive is due, at most :data:`WRITER_IDLE_S`."""
        due = self.hooks.next_keepalive_s()
        if due is None:
            return WRITER_IDLE_S
        return min(WRITER_IDLE_S, max(0.0, due - self.clock.now()))
