"""Transducer board driver: :class:`Board`, the HOST role of :mod:`firmware_protocol`.

The board is reached through any transport URL (:mod:`hil.transports`: a serial port,
``usb://VID:PID``, ``sim://board``, ``spy://...``) or a ready transport object. The driver:

- handshakes (HELLO -> VERSION, CAPABILITIES) and refuses a board of another protocol major
  version or schema hash with a message that says what to update;
- checks :class:`~hil.devices.board_settings.BoardSettings` against the board's capabilities
  *before* sending CONFIGURE;
- runs a reader thread that puts ADC frames into a :class:`~hil.acquisition.SampleRing` by
  sample index, detects gaps by sequence number and by sample index, and records them (and
  board alarms, frame errors, reconnects) as sample-indexed annotations;
- runs a writer thread that feeds the DAC from a callable or a block generator (e.g.
  :class:`hil.signals.synthesis.BlockSynthesizer`) within the credit the board grants, and
  sends keepalives; if the host fell behind the board (the DAC FIFO ran dry), it skips the
  samples whose time has passed rather than sending them late;
- fits SYNC pairs into a sample-index <-> host-time map (:attr:`Board.clock_fit`);
- reconnects with exponential backoff when the link drops, and resumes streaming;
- stops transmission (STOP) when a ``with Board(...)`` block exits by an exception,
  Ctrl-C included.

Threads: the reader owns all receiving. Every frame is encoded under the one lock that also
guards the protocol state and queued, so frames leave in sequence order; the write itself
happens outside that lock (one writer at a time), so a link that is slow to take a DAC burst
never holds up the reader.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt

from firmware_protocol import (
    MAX_FRAME_LEN,
    NEED_DATA,
    Ack,
    AdcData,
    Alarm,
    Capabilities,
    Configure,
    Connection,
    ConnectionClosed,
    Credit,
    DacData,
    FrameError,
    IncompatiblePeerError,
    Keepalive,
    Log,
    Message,
    Nak,
    NakCode,
    RemoteProtocolError,
    Role,
    SampleFormat,
    SequenceGap,
    Start,
    State,
    Status,
    Stop,
    Sync,
    UnknownMessage,
    Version,
    channel_count,
    cobs,
)
from hil.acquisition import (
    Annotation,
    AnnotationKind,
    AnnotationLog,
    SampleClockFit,
    SampleGapDetector,
    SampleRing,
)
from hil.acquisition.annotations import ADC_CLIPPING_TEXT
from hil.devices.board_log import LOG, log_frame, log_state
from hil.devices.board_settings import BoardSettings, to_wire_samples
from hil.devices.clock import Clock, MonotonicClock, VirtualClock
from hil.errors import ConfigError, DeviceError, DeviceRefused
from hil.transports import (
    Transport,
    TransportClosedError,
    TransportError,
    TransportTimeoutError,
    open_transport,
)

_DAC_STATES = (State.CONFIGURED, State.STARTING, State.STREAMING, State.STOPPED)
_KEEPALIVE_STATES = (
    State.READY,
    State.CONFIGURING,
    State.CONFIGURED,
    State.STARTING,
    State.STREAMING,
    State.STOPPING,
    State.STOPPED,
)
_FRAME_OVERHEAD = 12 + 14  # header + CRC, then the fixed part of DAC_DATA (bytes)
_READ_SIZE = 1 << 16
_DAC_BURST_FRAMES = 8  # DAC frames sent per write (8 x 8 KB)
# Longest idle sleep of the writer (s): it used to poll every 5 ms, 200 wake-ups a second.
_WRITER_IDLE_S = 0.05

DacSource = Callable[[int, int], npt.ArrayLike] | Iterable[npt.ArrayLike]
"""A callable ``source(k, n) -> block`` (samples ``k .. k+n-1`` of the transmission, numbered
from 0 at the index :meth:`Board.start` returns; not board indices) or an iterable of
blocks. Blocks are (n,)
(played on every channel) or (n, dac_channels); floats are full scale (+-1.0), integers are
counts of the DAC format. An object with ``read(n)`` (BlockSynthesizer) is accepted too."""


class BoardError(DeviceError):
    """Base class of run-time board failures (not configuration mistakes)."""


class BoardCommandError(BoardError, DeviceRefused):
    """The board refused a command (NAK) or did not answer it."""

    def __init__(self, message: str, nak: Nak | None = None, *, url: str | None = None) -> None:
        super().__init__(message, url=url)
        self.nak = nak


@dataclass(frozen=True)
class ReconnectPolicy:
    """How to reconnect after the link drops: exponential backoff, bounded attempts.

    Delays are ``first_delay_s * factor**k`` capped at ``max_delay_s`` (clock seconds).
    """

    first_delay_s: float = 0.05
    factor: float = 2.0
    max_delay_s: float = 2.0
    max_attempts: int = 10

    def delays(self) -> Iterator[float]:
        """The waits before each attempt, s.

        >>> [round(d, 2) for d in ReconnectPolicy(0.1, 2.0, 0.5, 5).delays()]
        [0.1, 0.2, 0.4, 0.5, 0.5]
        """
        delay = self.first_delay_s
        for _ in range(self.max_attempts):
            yield min(delay, self.max_delay_s)
            delay *= self.factor


class _DacFeeder:
    """Turns a DAC source into wire sample blocks of any requested length.

    Sample ``k`` of the transmission plays at board index ``first + k``; a callable source
    is asked ``source(k, n)`` by that sample number. Until :meth:`started`, the blocks sent
    are kept, so a START the board refused can be retried later with the same samples
    (:meth:`restart_at`). ``lock`` is held by whoever takes from or moves the feeder (the
    writer thread, a retried start).
    """

    def __init__(self, source: Any, fmt: SampleFormat, channels: int, first: int) -> None:
        self.fmt = fmt
        self.channels = channels
        self.next_index = first
        self.lock = threading.Lock()
        # Sample number of the next sample the source produces: ahead of the next one sent
        # by what is taken but not yet sent, so a burst asks for fresh samples.
        self._source_index = 0
        self._call: Callable[[int, int], npt.ArrayLike] | None = None
        self._iter: Iterator[npt.ArrayLike] | None = None
        self._indexed = False  # a source(k, n) callable: samples asked by number
        if hasattr(source, "read") and callable(source.read):
            self._call = lambda first, n: source.read(n)
        elif callable(source):
            self._call = source
            self._indexed = True
        else:
            self._iter = iter(source)
        self._pending: npt.NDArray[Any] | None = None
        self._sent: list[npt.NDArray[Any]] | None = []  # None once started
        self.exhausted = False

    def sent(self, blocks: list[npt.NDArray[Any]]) -> None:
        """Record blocks that went to the board (kept until :meth:`started`)."""
        if self._sent is not None:
            self._sent.extend(blocks)

    def started(self) -> None:
        """The board accepted START: what was sent need not be kept any longer."""
        self._sent = None

    def restart_at(self, first: int) -> None:
        """Send everything again from sample 0, at board index ``first`` (the board dropped
        what it had: its START was refused and it was stopped)."""
        if self._sent is None:
            raise RuntimeError("restart_at() after started(): the sent samples are gone")
        rest = [] if self._pending is None else [self._pending]
        if self._sent or rest:
            self._pending = np.concatenate(self._sent + rest)
        self._sent = []
        self.next_index = first
        if self._pending is not None and self._pending.shape[0]:
            self.exhausted = False  # the source may have ended; what it gave is sent again

    def take(self, n: int) -> npt.NDArray[Any] | None:
        """Up to ``n`` wire samples (rows), or None when the source has ended."""
        if self._pending is None or self._pending.shape[0] == 0:
            if self._call is not None:
                raw = self._call(self._source_index, n)
            else:
                assert self._iter is not None
                try:
                    raw = next(self._iter)
                except StopIteration:
                    self.exhausted = True
                    return None
            self._pending = to_wire_samples(raw, self.fmt, self.channels)
            self._source_index += self._pending.shape[0]
        block, self._pending = self._pending[:n], self._pending[n:]
        return block

    def skip(self, n: int) -> None:
        """Drop the next ``n`` samples unsent (their time has passed on the board)."""
        pending = 0 if self._pending is None else self._pending.shape[0]
        from_pending = min(n, pending)
        if self._pending is not None:
            self._pending = self._pending[from_pending:]
        rest = n - from_pending
        if self._indexed:
            self._source_index += rest  # asked by index: nothing to render
            rest = 0
        while rest > 0:  # a sequential source: read and drop
            block = self.take(rest)
            if block is None:
                break
            rest -= block.shape[0]
        self.next_index += n

    def put_back(self, block: npt.NDArray[Any]) -> None:
        """Return samples that could not be sent (credit was reset)."""
        rest = self._pending if self._pending is not None else block[:0]
        self._pending = np.concatenate((block, rest))


class Board:
    """Driver of the DAC/ADC transducer board (see the module docstring).

    Parameters
    ----------
    transport:
        A transport URL (``serial:///dev/ttyACM0``, ``usb://1209:ca50``, ``sim://board``) or
        an open transport object (not closed by the driver).
    settings:
        What :meth:`configure` asks for (validated on assignment).
    clock:
        Clock for waits, backoff and host timestamps (default: the wall clock).
    ring_seconds:
        Seconds of ADC samples the ring buffer holds.
    keepalive_ms:
        Watchdog timeout asked of the board (ms); keepalives go out 4 times per timeout.
        None sends none (the board's watchdog stays unarmed).
    reconnect:
        Backoff policy after a link drop, or None to raise instead.
    transport_factory:
        Opens a fresh transport for reconnects (default: reopen the URL).
    transport_options:
        Keyword options for :func:`hil.transports.open_transport`.
    start_lead_s:
        How far ahead of the board clock :meth:`start` schedules the first sample (s).
    start_attempts:
        How many times :meth:`start` tries, doubling the lead each time, when the board
        refuses START because its index has passed (1 .. 10).
    command_timeout_s:
        Clock seconds to wait for a reply.
    virtual_time:
        Run on this virtual clock (an in-process simulated board on virtual time) instead of
        the wall clock: no reader and writer threads; at every tick of the clock the link is
        read and handled, the DAC fed and a keepalive sent if due, and the driver's waits
        sleep on it. A link lost on virtual time stays lost (a DISCONNECT annotation).
    """

    def __init__(
        self,
        transport: str | Transport,
        *,
        settings: BoardSettings | None = None,
        clock: Clock | None = None,
        ring_seconds: float = 4.0,
        keepalive_ms: int | None = 1000,
        reconnect: ReconnectPolicy | None = None,
        transport_factory: Callable[[], Transport] | None = None,
        transport_options: dict[str, Any] | None = None,
        start_lead_s: float = 0.2,
        start_attempts: int = 3,
        command_timeout_s: float = 5.0,
        virtual_time: VirtualClock | None = None,
    ) -> None:
        if virtual_time is not None and clock is not None and clock is not virtual_time:
            raise ConfigError(
                "clock", clock, "the virtual_time clock or None", "give only virtual_time"
            )
        if keepalive_ms is not None and not 1 <= keepalive_ms <= 65535:
            raise ConfigError("keepalive_ms", keepalive_ms, "1 .. 65535 ms, or None")
        if not ring_seconds > 0:
            raise ConfigError("ring_seconds", ring_seconds, "> 0 s")
        if not 0 < start_lead_s <= 10:
            raise ConfigError("start_lead_s", start_lead_s, "in (0, 10] s")
        if isinstance(start_attempts, bool) or start_attempts not in range(1, 11):
            raise ConfigError("start_attempts", start_attempts, "an integer in 1 .. 10")
        self.settings = settings or BoardSettings()
        self._url = transport if isinstance(transport, str) else None
        self._injected = None if isinstance(transport, str) else transport
        self._factory = transport_factory
        self._transport_options = transport_options or {}
        self._clock: Clock = virtual_time or clock or MonotonicClock()
        self._virtual = virtual_time
        self._detach_service: Callable[[], None] | None = None
        #: The sample index wait_for_samples waits for on virtual time (see _quiet_until_ns).
        self._awaited_index: int | None = None
        self.ring_seconds = ring_seconds
        self.keepalive_ms = keepalive_ms
        self.reconnect_policy = reconnect if reconnect is not None else ReconnectPolicy()
        self._reconnect_enabled = bool(reconnect is not None or self._url or transport_factory)
        self.start_lead_s = start_lead_s
        self.start_attempts = start_attempts
        self.command_timeout_s = command_timeout_s

        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        self._write_lock = threading.Lock()  # held by the one thread writing (see _flush)
        self._outgoing = bytearray()  # encoded frames not yet written, in sequence order
        self._transport: Transport | None = None
        self._conn = Connection(Role.HOST)
        self._replies: dict[int, Ack | Nak] = {}
        self._refusal: IncompatiblePeerError | None = None
        self._stop_threads = threading.Event()
        self._reader: threading.Thread | None = None
        self._writer: threading.Thread | None = None
        self._link_up = False
        self._feeder: _DacFeeder | None = None
        self._streaming = False
        self._configured: Configure | None = None
        self._last_sync: tuple[int, float] | None = None
        self._next_keepalive = 0.0
        self._thread_error: BaseException | None = None

        self.annotations = AnnotationLog()
        self.gaps = SampleGapDetector()
        self.ring: SampleRing | None = None
        self.clock_fit: SampleClockFit | None = None
        self.last_status: Status | None = None
        #: STATUS reports with ADC_CLIPPING set (each: >= 1 clipped sample since the last).
        self.adc_clipping_reports = 0
        self.version: Version | None = None
        self.capabilities: Capabilities | None = None
        self.log_lines: list[str] = []
        self.start_index: int | None = None
        self.reconnects = 0
        self.frame_errors = 0
        self.sequence_gaps = 0
        self.missed_frames = 0
        self.samples_received = 0
        self.dac_samples_sent = 0
        self.dac_samples_skipped = 0
        """DAC samples never sent because their time had passed (see _skip_late_dac)."""
        self.unknown_messages = 0
        self.remote_errors = 0

    # ------------------------------------------------------------------ lifecycle
    @property
    def url(self) -> str:
        """Where the board is (for messages)."""
        if self._url is not None:
            return self._url
        return str(getattr(self._injected, "url", "<injected transport>"))

    @property
    def state(self) -> State:
        """The protocol session state."""
        return self._conn.state

    @property
    def transport(self) -> Transport | None:
        """The transport in use (None when closed or between reconnects)."""
        return self._transport

    def open(self) -> Board:
        """Open the transport, handshake, and start the reader and writer threads (on
        virtual time: attach their work to the clock)."""
        self._thread_error = None
        cobs.warm_up()  # not inside the first ADC frame
        if self._virtual is not None:
            self._detach_service = self._virtual.attach(self._service, self._quiet_until_ns)
        try:
            self._handshake(self._open_transport(first=True))
        except BaseException:
            self._close_transport()
            self._detach()
            raise
        self._stop_threads.clear()
        if self._virtual is not None:
            return self
        self._reader = threading.Thread(target=self._guard(self._read_loop), daemon=True)
        self._writer = threading.Thread(target=self._guard(self._write_loop), daemon=True)
        self._reader.name, self._writer.name = "board-reader", "board-writer"
        self._reader.start()
        self._writer.start()
        return self

    def close(self) -> None:
        """Stop transmission if streaming, stop the threads and close the transport."""
        if self._streaming and self._link_up:
            with contextlib.suppress(BoardError, TransportError, RemoteProtocolError):
                self.stop()
        self._stop_threads.set()
        with self._cond:
            self._cond.notify_all()
        for thread in (self._reader, self._writer):
            if thread is not None and thread is not threading.current_thread():
                thread.join(timeout=5.0)
        self._reader = self._writer = None
        self._detach()
        self._close_transport()

    def _detach(self) -> None:
        if self._detach_service is not None:
            self._detach_service()
            self._detach_service = None

    def _service(self) -> None:
        """One turn of the reader's and the writer's work on virtual time (see
        ``virtual_time``): what the link holds read and handled, the DAC fed within the
        credit, a keepalive sent if due."""
        if not self._link_up or not self._pump_once():
            return
        try:
            while self._feed_dac():
                pass
            self._keepalive_if_due()
        except TransportError as error:
            self._link_lost(str(error))

    def _quiet_until_ns(self) -> int | None:
        """Virtual time (ns) before which :meth:`_service` may be skipped, or None (every
        tick). Only while :meth:`wait_for_samples` waits on a link that says how long its
        device has nothing but samples below the awaited index to send (the simulated
        board's ``quiet_until_ns``): the skipped ticks' samples then arrive, the same, at
        the next service, before the wait can end. A keepalive due, DAC samples to send
        within credit, or frames not yet written end the quiet."""
        transport, awaited = self._transport, self._awaited_index
        quiet = getattr(transport, "quiet_until_ns", None)
        if awaited is None or quiet is None or not self._link_up or self._outgoing:
            return None
        feeder = self._feeder
        if feeder is not None and not feeder.exhausted and self._conn.dac_credit > 0:
            return None
        until = int(quiet(awaited, _READ_SIZE))
        if self.keepalive_ms is not None:
            # Due at the first tick whose time reaches it: never later than this.
            until = min(until, math.floor(self._next_keepalive * 1e9) - 1)
        return until

    def __enter__(self) -> Board:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is not None and self._link_up:
            # Any failure inside the block (Ctrl-C included) stops the transmitter first.
            self._feeder = None
            with contextlib.suppress(Exception):
                if self.state in (State.CONFIGURED, State.STARTING, State.STREAMING):
                    self._send(Stop())
        self.close()

    def _open_transport(self, first: bool) -> Transport:
        if self._factory is not None and not first:
            return self._factory()
        if self._url is not None:
            return open_transport(self._url, **self._transport_options)
        if self._injected is not None and first:
            return self._injected
        if self._factory is not None:
            return self._factory()
        raise TransportClosedError(
            f"{self.url}: the link dropped and an injected transport cannot be reopened;"
            " pass transport_factory= to reconnect"
        )

    def _close_transport(self) -> None:
        with self._lock:
            transport, self._transport = self._transport, None
            self._link_up = False
        if transport is not None and transport is not self._injected:
            with contextlib.suppress(Exception):
                transport.close()

    def _guard(self, loop: Callable[[], None]) -> Callable[[], None]:
        def run() -> None:
            try:
                loop()
            except BaseException as error:  # reported by the next call from the user
                self._thread_error = error
                with self._cond:
                    self._link_up = False
                    self._cond.notify_all()

        return run

    # ------------------------------------------------------------------ sending
    def _send(self, message: Message) -> None:
        with self._lock:
            if self._transport is None:
                raise TransportClosedError(f"{self.url}: not connected")
            before = self._conn.state
            self._outgoing += self._conn.send(message)
            log_frame(self.url, "->", message)
            log_state(self.url, before, self._conn.state)
        self._flush()

    def _flush(self) -> None:
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
                with self._lock:
                    data = bytes(self._outgoing)
                    self._outgoing.clear()
                    transport = self._transport
                    if not data or transport is None:
                        self._write_lock.release()
                        held = False
                        return
                transport.write(data)
        finally:
            if held:
                self._write_lock.release()

    def _wait(self, done: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Wait until ``done()``; pump the link ourselves if no reader thread runs.

        Timeouts are real seconds: waiting for bytes is waiting for I/O, which an injected
        clock cannot speed up; on virtual time they are virtual seconds, slept on the clock
        (which services the link meanwhile).
        """
        if self._virtual is not None:
            self._wait_virtual(self._virtual, done, timeout_s, what)
            return
        deadline = time.monotonic() + timeout_s
        pumping = self._reader is None or threading.current_thread() is self._reader
        while True:
            with self._cond:
                if done():
                    return
                if self._refusal is not None:
                    raise self._refusal
                if self._thread_error is not None:
                    raise BoardError(
                        f"{self.url}: reader failed", url=self.url
                    ) from self._thread_error
                if time.monotonic() >= deadline:
                    LOG.debug(
                        "board %s: timed out after %s s waiting for %s", self.url, timeout_s, what
                    )
                    raise TransportTimeoutError(
                        f"{self.url}: no {what} within {timeout_s} s; check that the board is"
                        " powered, the URL is right, and nothing else holds the port"
                    )
                if not pumping:
                    self._cond.wait(0.01)
            if pumping and not self._pump_once():
                raise TransportClosedError(f"{self.url}: link lost while waiting for {what}")

    def _wait_virtual(
        self, clock: VirtualClock, done: Callable[[], bool], timeout_s: float, what: str
    ) -> None:
        def settled() -> bool:
            if self._refusal is not None:
                raise self._refusal
            return done() or not self._link_up

        if not clock.wait_until(settled, timeout_s):
            LOG.debug(
                "board %s: timed out after %s s of virtual time waiting for %s",
                self.url,
                timeout_s,
                what,
            )
            raise TransportTimeoutError(
                f"{self.url}: no {what} within {timeout_s} s of virtual time; the simulated"
                " board did not answer"
            )
        if not done():
            raise TransportClosedError(f"{self.url}: link lost while waiting for {what}")

    def _command(self, message: Configure | Start | Stop) -> Ack:
        with self._cond:
            self._replies.pop(message.TYPE_ID, None)
            self._send(message)
        self._wait(lambda: message.TYPE_ID in self._replies, self.command_timeout_s, message.NAME)
        reply = self._replies.pop(message.TYPE_ID)
        if isinstance(reply, Nak):
            raise BoardCommandError(
                f"{self.url}: board refused {message.NAME} with {reply.code!r}"
                f" ({reply.detail or 'no detail'}); check the settings against the board's"
                " capabilities",
                reply,
                url=self.url,
            )
        return reply

    # ------------------------------------------------------------------ commands
    def _handshake(self, transport: Transport) -> None:
        with self._lock:  # the writer thread must never see a half-replaced session
            self._transport = transport
            self._conn = Connection(Role.HOST)
            self._outgoing.clear()  # frames of the old session must not reach the new one
            self._refusal = None
            self._link_up = True
            self._send(self._conn.make_hello())
        try:
            self._wait(lambda: self._conn.state is State.READY, self.command_timeout_s, "VERSION")
        except IncompatiblePeerError as error:
            raise IncompatiblePeerError(
                f"{self.url}: {error}",
                local_version=error.local_version,
                peer_version=error.peer_version,
                local_schema=error.local_schema,
                peer_schema=error.peer_schema,
            ) from None
        self.version = self._conn.peer_version
        self.capabilities = self._conn.capabilities
        if self.keepalive_ms is not None:
            self._send(Keepalive(self.keepalive_ms))
            self._next_keepalive = self._clock.now() + self.keepalive_ms / 4000.0

    def configure(self, settings: BoardSettings | None = None) -> None:
        """Check ``settings`` (default :attr:`settings`) against the board, then CONFIGURE.

        Raises ConfigError before anything is sent if the board cannot do them.
        """
        self._configure(settings or self.settings, fresh=True)

    def _configure(self, settings: BoardSettings, *, fresh: bool) -> None:
        """CONFIGURE; ``fresh`` starts a new ring, fit and gap record (not on reconnect)."""
        if self.capabilities is None:
            raise BoardError(
                "the board is not open: call open() or use 'with Board(...)'", url=self.url
            )
        settings.check_against(self.capabilities)
        message = settings.to_configure()
        self._feeder = None
        self._streaming = False
        self._last_sync = None
        self._command(message)
        self.settings = settings
        self._configured = message
        if not fresh and self.ring is not None:
            return
        capacity = max(1, round(self.ring_seconds * settings.sample_rate_hz))
        dtype = {SampleFormat.INT16: np.int16, SampleFormat.INT24: np.int32}.get(
            settings.adc_format, np.float32
        )
        self.ring = SampleRing(capacity, settings.adc_channels, dtype)
        self.clock_fit = SampleClockFit(float(settings.sample_rate_hz))
        self.gaps.reset()

    def board_index_now(self) -> int:
        """Estimate of the board sample clock now, from the latest SYNC (samples)."""
        self._wait(lambda: self._last_sync is not None, self.command_timeout_s, "SYNC")
        assert self._last_sync is not None and self._configured is not None
        index, host_t = self._last_sync
        elapsed = max(0.0, self._clock.now() - host_t)
        return index + round(elapsed * self._configured.sample_rate_hz)

    def start(self, source: DacSource | None = None, *, preload_timeout_s: float = 1.0) -> int:
        """Start streaming; returns the board sample index of the first sample.

        With a DAC ``source`` the DAC buffer is preloaded (within the granted credit) before
        START, so playback begins without an underrun. Sample ``k`` of the source plays at
        the returned index ``+ k``; a callable source is asked ``source(k, n)`` for samples
        ``k .. k+n-1`` (consecutive, from 0).

        The first sample is scheduled :attr:`start_lead_s` after the board clock. If the
        board refuses START because that index has passed (the preload took longer than the
        lead: a loaded host), the driver stops the board (which empties its DAC buffer),
        doubles the lead and starts again with the same samples, up to
        :attr:`start_attempts` times; a retried start is annotated (``START_RETRY``).
        """
        config = self._configured
        if config is None:
            raise BoardError("configure() the board before start()", url=self.url)
        rate = config.sample_rate_hz
        feeder = None
        if source is not None:
            feeder = _DacFeeder(
                source, config.dac_format, channel_count(config.dac_channel_mask), 0
            )
        refusals: list[str] = []
        for attempt in range(self.start_attempts):
            lead_s = self.start_lead_s * 2**attempt
            first = self.board_index_now() + round(lead_s * rate)
            self.start_index = first
            self.gaps.reset(first)
            if self.ring is not None:
                # Samples lost at the very start are then a gap like any other, not a
                # stream that begins later than the run reads it from.
                self.ring.expect(first)
            if feeder is not None:
                self._preload(feeder, first, preload_timeout_s)
            try:
                self._command(Start(first))
            except BoardCommandError as error:
                if error.nak is None or error.nak.code != NakCode.START_INDEX_PASSED:
                    raise
                refusals.append(f"at {first} with a {lead_s:g} s lead ({error.nak.detail})")
                with self._cond:
                    self._feeder = None  # the writer stops feeding this attempt
                self._command(Stop())  # the board drops the samples it holds for it
                continue
            if feeder is not None:
                with feeder.lock:
                    feeder.started()
            self._streaming = True
            if refusals:
                self._annotate(
                    AnnotationKind.START_RETRY,
                    len(refusals),
                    f"START refused {len(refusals)} time(s) as its index had passed ("
                    + "; ".join(refusals)
                    + f"); started at {first} with a {lead_s:g} s lead",
                    first,
                )
            return first
        raise BoardCommandError(
            f"{self.url}: board refused START {len(refusals)} times because its start index"
            f" had passed ({'; '.join(refusals)}): the host took longer than the start lead"
            " to preload the DAC. Raise start_lead_s, or give the host more CPU time (close"
            " other programs, use a faster source)",
            url=self.url,
        )

    def _preload(self, feeder: _DacFeeder, first: int, timeout_s: float) -> None:
        """Fill the board's DAC buffer from ``feeder`` for a start at ``first``: from its
        sample 0 (again, if an earlier attempt was refused) up to the granted credit."""
        with feeder.lock:
            feeder.restart_at(first)
        with self._cond:
            self._feeder = feeder
            self._cond.notify_all()
        self._wait(
            lambda: feeder.exhausted or (self._conn.dac_credit == 0 and feeder.next_index > first),
            timeout_s,
            "DAC preload (credit)",
        )

    def stop(self) -> None:
        """Stop transmission and capture (STOP, wait for its ACK)."""
        self._feeder = None
        self._streaming = False
        if self.state in (State.CONFIGURED, State.STARTING, State.STREAMING, State.STOPPED):
            self._command(Stop())

    # ------------------------------------------------------------------ data access
    def wait_for_samples(self, end_index: int, timeout_s: float = 5.0) -> bool:
        """Block until the ring holds samples up to ``end_index`` (real seconds; on
        virtual time, virtual seconds)."""
        ring = self.ring
        if ring is None:
            raise BoardError("configure() the board first", url=self.url)
        if self._virtual is not None:
            self._awaited_index = end_index
            try:
                return self._virtual.wait_until(
                    lambda: ring.end_index is not None and ring.end_index >= end_index, timeout_s
                )
            finally:
                self._awaited_index = None
        return ring.wait_for(end_index, timeout_s)

    def read(self, first: int, n: int) -> npt.NDArray[Any]:
        """ADC samples ``first .. first+n-1`` (n, adc_channels) from the ring."""
        if self.ring is None:
            raise BoardError("configure() the board first", url=self.url)
        return self.ring.read(first, n)

    @property
    def protocol_stats(self) -> dict[str, int]:
        """The host side's receive counters (frames, errors, gaps)."""
        return self._conn.stats.as_dict()

    # ------------------------------------------------------------------ receiving
    def _read_loop(self) -> None:
        while not self._stop_threads.is_set():
            if not self._pump_once():
                self._reconnect()

    def _pump_once(self) -> bool:
        """Read once and handle what arrived; False if the link is lost."""
        transport = self._transport
        if transport is None or not self._link_up:
            return False
        try:
            data = transport.read(_READ_SIZE)
        except TransportError as error:
            self._link_lost(str(error))
            return False
        if not data:
            return True
        with self._cond:
            self._conn.receive_data(data)
            # Only what a waiter on the condition can be waiting for (credit, replies, SYNC,
            # status, errors) wakes it: ADC data has the ring's own condition, and waking
            # the writer for every read (about 1000 a second at 4 MB/s) cost more CPU than
            # the data itself.
            wake = False
            while True:
                before = self._conn.state
                try:
                    event = self._conn.next_event()
                except IncompatiblePeerError as error:
                    self._refusal = error
                    self._cond.notify_all()
                    return True
                except RemoteProtocolError as error:
                    self.remote_errors += 1
                    self._annotate(AnnotationKind.PROTOCOL_ERROR, 0, str(error))
                    continue
                if event is NEED_DATA:
                    break
                if isinstance(event, ConnectionClosed):
                    self._link_lost("the board closed the session")
                    return False
                if isinstance(event, AdcData):
                    self._on_adc(event)
                    continue
                log_frame(self.url, "<-", event)
                log_state(self.url, before, self._conn.state)
                wake = True
                self._handle(event)
            if wake:
                self._cond.notify_all()
        return True

    def _annotate(
        self, kind: AnnotationKind, length: int, detail: str, at: int | None = None
    ) -> None:
        index = at if at is not None else (self.gaps.expected or 0)
        self.annotations.add(Annotation(index, kind, length, detail))

    def _handle(self, event: object) -> None:
        if isinstance(event, AdcData):
            self._on_adc(event)
        elif isinstance(event, Credit):
            pass  # the Connection keeps the count; the writer is notified by the caller
        elif isinstance(event, Sync):
            now = self._clock.now()
            self._last_sync = (event.sample_index, now)
            if self.clock_fit is not None:
                self.clock_fit.add(event.sample_index, now)
        elif isinstance(event, Status):
            self._on_status(event)
        elif isinstance(event, Ack | Nak):
            if event.ref_type in (Configure.TYPE_ID, Start.TYPE_ID, Stop.TYPE_ID):
                self._replies[event.ref_type] = event
            else:
                text = f"board NAKed frame seq {event.ref_seq} type 0x{event.ref_type:02x}"
                self._annotate(AnnotationKind.PROTOCOL_ERROR, 0, f"{text}: {event!r}")
        elif isinstance(event, FrameError):
            self.frame_errors += 1
            self._annotate(AnnotationKind.FRAME_ERROR, 0, f"{event.kind.value}: {event.detail}")
        elif isinstance(event, SequenceGap):
            self.sequence_gaps += 1
            self.missed_frames += event.missed
            self._annotate(
                AnnotationKind.SEQUENCE_GAP,
                event.missed,
                f"seq {event.expected} expected, {event.received} received",
            )
        elif isinstance(event, Log):
            self.log_lines.append(f"{event.level.name}: {event.text}")
        elif isinstance(event, UnknownMessage):
            self.unknown_messages += 1

    def _on_adc(self, event: AdcData) -> None:
        block = event.samples()
        n = block.shape[0]
        note = self.gaps.check(event.first_sample_index, n)
        if note is not None:
            self.annotations.add(note)
        if self.ring is not None and self.ring.write(event.first_sample_index, block):
            self.samples_received += n

    def _on_status(self, status: Status) -> None:
        before = self.last_status
        self.last_status = status
        if before is not None and status.dac_underruns != before.dac_underruns:
            count = (status.dac_underruns - before.dac_underruns) % (1 << 32)
            self._annotate(
                AnnotationKind.DAC_UNDERRUN, 0, f"{count} DAC underrun(s)", status.sample_index
            )
        if before is not None and status.adc_overruns != before.adc_overruns:
            count = (status.adc_overruns - before.adc_overruns) % (1 << 32)
            self._annotate(
                AnnotationKind.ADC_OVERRUN, 0, f"{count} ADC overrun(s)", status.sample_index
            )
        if status.alarms & Alarm.ADC_CLIPPING:
            # SPEC 5.8: the board latched it since the last STATUS; each report is an alarm.
            self.adc_clipping_reports += 1
            self._annotate(
                AnnotationKind.ALARM,
                0,
                f"{ADC_CLIPPING_TEXT} since the last STATUS: the hydrophone input reached full"
                " scale; lower the drive amplitude or the receive gain",
                status.sample_index,
            )
        if status.alarms & Alarm.WATCHDOG_EXPIRED:
            self._streaming = False
            self._feeder = None
            self._annotate(
                AnnotationKind.WATCHDOG,
                0,
                "board watchdog expired: transmission stopped",
                status.sample_index,
            )

    # ------------------------------------------------------------------ writer
    def _write_loop(self) -> None:
        while not self._stop_threads.is_set():
            if not self._link_up:
                self._stop_threads.wait(0.005)
                continue
            try:
                sent = self._feed_dac()
                self._keepalive_if_due()
            except TransportError:
                self._stop_threads.wait(0.005)  # the reader sees the loss and reconnects
                continue
            if not sent:
                with self._cond:
                    self._cond.wait(self._writer_idle_s())

    def _writer_idle_s(self) -> float:
        """How long the writer may sleep when it has nothing to send: until the next
        keepalive is due, at most :data:`_WRITER_IDLE_S`. Credit, a new DAC source, a reply
        and a stop all notify it; the cap only bounds the effect of a missed notification."""
        if self.keepalive_ms is None:
            return _WRITER_IDLE_S
        due = self._next_keepalive - self._clock.now()
        return min(_WRITER_IDLE_S, max(0.0, due))

    def _frame_samples(self, config: Configure) -> int:
        size = channel_count(config.dac_channel_mask) * SampleFormat(config.dac_format).size
        limit = self._conn.peer_max_frame_len or MAX_FRAME_LEN
        return (limit - _FRAME_OVERHEAD) // size

    def _feed_dac(self) -> bool:
        """Send DAC frames within the credit (up to a burst, in one write); True if any."""
        feeder, config = self._feeder, self._configured
        if feeder is None or config is None or feeder.exhausted:
            return False
        with feeder.lock:  # a retried start() may be moving it back to sample 0
            self._skip_late_dac(feeder, config)
            with self._lock:
                credit = self._conn.dac_credit if self._conn.state in _DAC_STATES else 0
            per_frame = self._frame_samples(config)
            blocks: list[npt.NDArray[Any]] = []
            while credit > 0 and len(blocks) < _DAC_BURST_FRAMES:
                block = feeder.take(min(credit, per_frame))
                if block is None or block.shape[0] == 0:
                    break
                blocks.append(block)
                credit -= block.shape[0]
            if not blocks:
                return False
            mask, fmt = config.dac_channel_mask, config.dac_format
            with self._lock:
                transport = self._transport
                needed = sum(b.shape[0] for b in blocks)
                if (
                    self._feeder is not feeder
                    or self._conn.state not in _DAC_STATES
                    or self._conn.dac_credit < needed
                    or transport is None
                ):
                    feeder.put_back(np.concatenate(blocks))
                    return False
                for block in blocks:
                    message = DacData.from_array(feeder.next_index, mask, fmt, block)
                    self._outgoing += self._conn.send(message)
                    feeder.next_index += block.shape[0]
                feeder.sent(blocks)
                self.dac_samples_sent += needed
                self._cond.notify_all()
        # One write per burst: fewer system calls and lock hand-overs at 4 MB/s.
        self._flush()
        return True

    def _skip_late_dac(self, feeder: _DacFeeder, config: Configure) -> None:
        """After the host fell behind (the board's DAC FIFO ran dry: the ADC stream is past
        the next DAC sample to send), jump the feeder :attr:`start_lead_s` ahead of the ADC
        stream, as :meth:`start` schedules the first sample, instead of sending samples whose
        time has passed: the board would drop them as late, and a host only just faster
        than real time would never catch up (the transmission would stay silent). The
        samples played stay those of their board indices, so the waveform keeps its
        schedule; the silent span shows as the board's DAC underrun."""
        ring = self.ring
        held = ring.end_index if ring is not None else None
        if not self._streaming or held is None:
            return
        # The ADC samples received so far: the board has converted (and played) at least up
        # to there. Not its clock from SYNC: a board (or a simulation) whose conversion lags
        # its clock has not played those indices yet, and skipping them would gap the DAC.
        if feeder.next_index >= held:
            return
        target = held + round(self.start_lead_s * config.sample_rate_hz)
        skipped = target - feeder.next_index
        at = feeder.next_index
        feeder.skip(skipped)
        self.dac_samples_skipped += skipped
        self._annotate(
            AnnotationKind.DAC_UNDERRUN,
            skipped,
            f"host behind the board: skipped {skipped} DAC samples whose time had passed",
            at,
        )

    def _keepalive_if_due(self) -> None:
        if self.keepalive_ms is None:
            return
        now = self._clock.now()
        if now < self._next_keepalive:
            return
        with self._lock:
            if self._conn.state in _KEEPALIVE_STATES:
                self._send(Keepalive(self.keepalive_ms))
        self._next_keepalive = now + self.keepalive_ms / 4000.0

    # ------------------------------------------------------------------ reconnect
    def _link_lost(self, why: str) -> None:
        if not self._link_up:
            return
        self._link_up = False
        LOG.debug("board %s: link lost: %s", self.url, why)
        self._annotate(AnnotationKind.DISCONNECT, 0, why)

    def _reconnect(self) -> None:
        """Reopen the link with backoff; resume configuration and streaming."""
        if self._stop_threads.is_set():
            return
        if not self._reconnect_enabled:
            raise TransportClosedError(f"{self.url}: link lost and reconnect is off")
        was_streaming = self._streaming
        feeder, self._feeder = self._feeder, None
        self._close_transport()
        last: BaseException | None = None
        for attempt, delay in enumerate(self.reconnect_policy.delays(), start=1):
            if self._stop_threads.is_set():
                return
            self._clock.sleep(delay)
            try:
                self._handshake(self._open_transport(first=False))
                if self._configured is not None:
                    self._configure(self.settings, fresh=False)
                    if was_streaming:
                        self._resume(feeder)
            except (TransportError, BoardError) as error:
                last = error
                LOG.debug("board %s: reconnect attempt %d failed: %s", self.url, attempt, error)
                self._close_transport()
                continue
            self.reconnects += 1
            LOG.debug("board %s: reconnected after %d attempt(s)", self.url, attempt)
            self._annotate(
                AnnotationKind.RECONNECT, attempt, f"reconnected after {attempt} attempt(s)"
            )
            return
        raise TransportClosedError(
            f"{self.url}: could not reconnect after {self.reconnect_policy.max_attempts}"
            f" attempts ({last}); check the cable and power, then open the board again"
        )

    def _resume(self, feeder: _DacFeeder | None) -> None:
        """Start again after a reconnect; the DAC source continues where it was."""
        expected = self.gaps.expected
        source: Any = None
        if feeder is not None:
            source = _ResumedSource(feeder)
        self.start(source)
        if expected is not None:
            self.gaps.reset(expected)  # the span lost while away shows up as a GAP
            if self.ring is not None:
                # Lost before the first frame came: the ring still expects the first start.
                self.ring.expect(expected)


class _ResumedSource:
    """The remaining samples of a feeder, as a sequential source (an iterable of blocks) for
    a new start: skipping late samples reads and drops them, so every later sample still
    plays at its own place, and the source's end is passed on."""

    _BLOCK = 4096  # samples per block taken from the old feeder

    def __init__(self, feeder: _DacFeeder) -> None:
        self._feeder = feeder

    def __iter__(self) -> Iterator[npt.NDArray[Any]]:
        while (block := self._feeder.take(self._BLOCK)) is not None and block.shape[0]:
            yield block
