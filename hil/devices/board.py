"""Transducer board driver: :class:`Board`, the HOST role of :mod:`firmware_protocol`.

The board is reached through any transport URL (:mod:`hil.transports`: a serial port,
``usb://VID:PID``, ``sim://board``, ``spy://...``) or a ready transport object. The driver:

- handshakes (HELLO -> VERSION, CAPABILITIES) and refuses a board of another protocol major
  version or schema hash with a message that says what to update;
- checks :class:`~hil.devices.board_settings.BoardSettings` against the board's capabilities
  *before* sending CONFIGURE;
- puts ADC frames into a :class:`~hil.acquisition.SampleRing` by sample index, detects gaps
  by sequence number and by sample index, and records them (and board alarms, frame errors,
  reconnects) as sample-indexed annotations;
- feeds the DAC from a callable or a block generator (e.g.
  :class:`hil.signals.synthesis.BlockSynthesizer`, through a
  :class:`~hil.devices.board_dac_feeder.DacFeeder`) within the credit the board grants, and
  sends keepalives; if the host fell behind the board (the DAC FIFO ran dry), it skips the
  samples whose time has passed rather than sending them late;
- fits SYNC pairs into a sample-index <-> host-time map (:attr:`Board.clock_fit`);
- reconnects with exponential backoff when the link drops, and resumes streaming;
- stops transmission (STOP) when a ``with Board(...)`` block exits by an exception,
  Ctrl-C included.

The I/O is its link's (:mod:`hil.devices.board_link`), chosen once when the driver is made:
reader and writer threads on the wall clock, or on virtual time a service of the
:class:`~hil.devices.clock.VirtualClock` (:mod:`hil.devices.board_link_virtual`). The driver
holds the protocol session and the DAC feeder; it encodes frames under the link's session
lock and hands them to the link to write.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
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
from hil.devices.board_dac_feeder import DacFeeder, DacSource, ResumedSource
from hil.devices.board_errors import BoardCommandError, BoardError
from hil.devices.board_link import BoardLink, LinkHooks, ThreadedBoardLink
from hil.devices.board_link_virtual import VirtualTimeBoardLink
from hil.devices.board_log import LOG, log_frame, log_state
from hil.devices.board_settings import BoardSettings
from hil.devices.clock import Clock, MonotonicClock, VirtualClock
from hil.errors import ConfigError
from hil.transports import (
    Transport,
    TransportClosedError,
    TransportError,
    open_transport,
)

__all__ = ["Board", "BoardCommandError", "BoardError", "DacSource", "ReconnectPolicy"]

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
_DAC_BURST_FRAMES = 8  # DAC frames sent per write (8 x 8 KB)


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
        self.ring_seconds = ring_seconds
        self.keepalive_ms = keepalive_ms
        self.reconnect_policy = reconnect if reconnect is not None else ReconnectPolicy()
        self._reconnect_enabled = bool(reconnect is not None or self._url or transport_factory)
        self.start_lead_s = start_lead_s
        self.start_attempts = start_attempts
        self.command_timeout_s = command_timeout_s

        hooks = LinkHooks(
            url=lambda: self.url,
            receive=self._receive,
            link_lost=self._link_lost,
            refusal=lambda: self._refusal,
            feed_dac=self._feed_dac,
            keepalive_if_due=self._keepalive_if_due,
            next_keepalive_s=self._next_keepalive_s,
            dac_pending=self._dac_pending,
            reconnect=self._reconnect,
        )
        # The one place the I/O mode is chosen: the driver below talks to either link alike.
        self._link: BoardLink = (
            VirtualTimeBoardLink(virtual_time, hooks)
            if virtual_time is not None
            else ThreadedBoardLink(clock or MonotonicClock(), hooks)
        )
        self._clock: Clock = self._link.clock
        self._conn = Connection(Role.HOST)
        self._replies: dict[int, Ack | Nak] = {}
        self._refusal: IncompatiblePeerError | None = None
        self._feeder: DacFeeder | None = None
        self._streaming = False
        self._configured: Configure | None = None
        self._last_sync: tuple[int, float] | None = None
        self._next_keepalive = 0.0

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
        return self._link.transport

    def open(self) -> Board:
        """Open the transport, handshake, and have the link read it and feed the DAC from
        then on (reader and writer threads, or on virtual time the clock's service)."""
        cobs.warm_up()  # not inside the first ADC frame
        try:
            self._link.open(lambda: self._handshake(self._open_transport(first=True)))
        except BaseException:
            self._close_transport()
            raise
        return self

    def close(self) -> None:
        """Stop transmission if streaming, stop the link's work and close the transport."""
        if self._streaming and self._link.up:
            with contextlib.suppress(BoardError, TransportError, RemoteProtocolError):
                self.stop()
        self._link.close()
        self._close_transport()

    def __enter__(self) -> Board:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is not None and self._link.up:
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
        transport = self._link.disconnect()
        if transport is not None and transport is not self._injected:
            with contextlib.suppress(Exception):
                transport.close()

    # ------------------------------------------------------------------ sending
    def _send(self, message: Message) -> None:
        with self._link.lock:
            if self._link.transport is None:
                raise TransportClosedError(f"{self.url}: not connected")
            before = self._conn.state
            self._link.queue(self._conn.send(message))
            log_frame(self.url, "->", message)
            log_state(self.url, before, self._conn.state)
        self._link.flush()

    def _command(self, message: Configure | Start | Stop) -> Ack:
        with self._link.lock:
            self._replies.pop(message.TYPE_ID, None)
            self._send(message)
        self._link.wait(
            lambda: message.TYPE_ID in self._replies, self.command_timeout_s, message.NAME
        )
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
        with self._link.lock:  # the writer must never see a half-replaced session
            self._link.connect(transport)  # frames of the old session are dropped
            self._conn = Connection(Role.HOST)
            self._refusal = None
            self._send(self._conn.make_hello())
        try:
            self._link.wait(
                lambda: self._conn.state is State.READY, self.command_timeout_s, "VERSION"
            )
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
        self._link.wait(lambda: self._last_sync is not None, self.command_timeout_s, "SYNC")
        assert self._last_sync is not None and self._configured is not None
        index, host_t = self._last_sync
        elapsed = max(0.0, self._clock.now() - host_t)
        return index + round(elapsed * self._configured.sample_rate_hz)

    def start(
        self, source: DacSource | None = None, *, preload_timeout_s: float | None = None
    ) -> int:
        """Start streaming; returns the board sample index of the first sample.

        With a DAC ``source`` the DAC buffer is preloaded (within the granted credit) before
        START, so playback begins without an underrun; the preload fails after
        ``preload_timeout_s`` (real seconds; default :attr:`command_timeout_s`: the credit
        it waits for is the board's answer to CONFIGURE) with no sample sent. Sample ``k`` of
        the source plays at the returned index ``+ k``; a callable source is asked
        ``source(k, n)`` for samples ``k .. k+n-1`` (consecutive, from 0).

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
            feeder = DacFeeder(source, config.dac_format, channel_count(config.dac_channel_mask), 0)
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
                preload_s = (
                    self.command_timeout_s if preload_timeout_s is None else preload_timeout_s
                )
                self._preload(feeder, first, preload_s)
            try:
                self._command(Start(first))
            except BoardCommandError as error:
                if error.nak is None or error.nak.code != NakCode.START_INDEX_PASSED:
                    raise
                refusals.append(f"at {first} with a {lead_s:g} s lead ({error.nak.detail})")
                with self._link.lock:
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

    def _preload(self, feeder: DacFeeder, first: int, timeout_s: float) -> None:
        """Fill the board's DAC buffer from ``feeder`` for a start at ``first``: from its
        sample 0 (again, if an earlier attempt was refused) up to the granted credit."""
        with feeder.lock:
            feeder.restart_at(first)
        with self._link.lock:
            self._feeder = feeder
            self._link.wake()
        # Fails only after timeout_s with no sample sent: a loaded host or a slow board
        # that still takes samples completes its preload, however long it takes.
        self._link.wait(
            lambda: feeder.exhausted or (self._conn.dac_credit == 0 and feeder.next_index > first),
            timeout_s,
            "DAC preload (credit)",
            progress=lambda: feeder.next_index,
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
        virtual time, virtual seconds); False if ``timeout_s`` passed first."""
        ring = self.ring
        if ring is None:
            raise BoardError("configure() the board first", url=self.url)
        return self._link.wait_for_samples(ring, end_index, timeout_s)

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
    def _receive(self, data: bytes) -> str | None:
        """Handle bytes read from the link (the link holds the session lock); returns why
        the link is lost (the board closed the session), or None."""
        self._conn.receive_data(data)
        # Only what a waiter on the condition can be waiting for (credit, replies, SYNC,
        # status, errors) wakes it: ADC data has the ring's own condition, and waking the
        # writer for every read (about 1000 a second at 4 MB/s) costs more CPU than the data.
        wake = False
        while True:
            before = self._conn.state
            try:
                event = self._conn.next_event()
            except IncompatiblePeerError as error:
                self._refusal = error
                self._link.wake()
                return None
            except RemoteProtocolError as error:
                self.remote_errors += 1
                self._annotate(AnnotationKind.PROTOCOL_ERROR, 0, str(error))
                continue
            if event is NEED_DATA:
                break
            if isinstance(event, ConnectionClosed):
                return "the board closed the session"
            if isinstance(event, AdcData):
                self._on_adc(event)
                continue
            log_frame(self.url, "<-", event)
            log_state(self.url, before, self._conn.state)
            wake = True
            self._handle(event)
        if wake:
            self._link.wake()
        return None

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

    # ------------------------------------------------------------------ DAC and keepalives
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
            with self._link.lock:
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
            with self._link.lock:
                transport = self._link.transport
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
                    self._link.queue(self._conn.send(message))
                    feeder.next_index += block.shape[0]
                feeder.sent(blocks)
                self.dac_samples_sent += needed
                self._link.wake()
        # One write per burst: fewer system calls and lock hand-overs at 4 MB/s.
        self._link.flush()
        return True

    def _skip_late_dac(self, feeder: DacFeeder, config: Configure) -> None:
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

    def _dac_pending(self) -> bool:
        """DAC samples are waiting and the board grants credit for them."""
        feeder = self._feeder
        return feeder is not None and not feeder.exhausted and self._conn.dac_credit > 0

    def _keepalive_if_due(self) -> None:
        if self.keepalive_ms is None:
            return
        now = self._clock.now()
        if now < self._next_keepalive:
            return
        with self._link.lock:
            if self._conn.state in _KEEPALIVE_STATES:
                self._send(Keepalive(self.keepalive_ms))
        self._next_keepalive = now + self.keepalive_ms / 4000.0

    def _next_keepalive_s(self) -> float | None:
        """Clock time the next KEEPALIVE is due (s), or None when none are sent."""
        return None if self.keepalive_ms is None else self._next_keepalive

    # ------------------------------------------------------------------ reconnect
    def _link_lost(self, why: str) -> None:
        """The link dropped (the link calls this once per loss)."""
        self._annotate(AnnotationKind.DISCONNECT, 0, why)

    def _reconnect(self) -> None:
        """Reopen the link with backoff; resume configuration and streaming (called by a
        threaded link's reader when the link is lost)."""
        if self._link.closing:
            return
        if not self._reconnect_enabled:
            raise TransportClosedError(f"{self.url}: link lost and reconnect is off")
        was_streaming = self._streaming
        feeder, self._feeder = self._feeder, None
        self._close_transport()
        last: BaseException | None = None
        for attempt, delay in enumerate(self.reconnect_policy.delays(), start=1):
            if self._link.closing:
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

    def _resume(self, feeder: DacFeeder | None) -> None:
        """Start again after a reconnect; the DAC source continues where it was."""
        expected = self.gaps.expected
        source: Any = None
        if feeder is not None:
            source = ResumedSource(feeder)
        self.start(source)
        if expected is not None:
            self.gaps.reset(expected)  # the span lost while away shows up as a GAP
            if self.ring is not None:
                # Lost before the first frame came: the ring still expects the first start.
                self.ring.expect(expected)
