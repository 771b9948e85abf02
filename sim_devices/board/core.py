"""The simulated board firmware: the DEVICE role of the real protocol on a sample clock.

:class:`SimulatedBoard` is a sans-IO device (the contract of
:class:`sim_devices.pty_endpoint.PtyEndpoint`: ``receive_data``, ``data_to_send``, ``tick``,
``connection_made``, ``connection_lost``). It runs ``Connection(Role.DEVICE)`` of
:mod:`firmware_protocol`, so every byte it sends is what real firmware must send.

Sample clock: ``index = base_index + floor((now - base_time) * rate)``, with ``now`` from the
injected clock (s), computed in integer nanoseconds as SPEC 5.3 states. The clock runs from
power-up and never goes back: a CONFIGURE with a new rate re-bases it at the current index,
a new session (HELLO, host reconnect) keeps it. The board follows SPEC section 5 exactly; the
golden conversations (``firmware_protocol/golden_conversations.json``) pin its output.

While STREAMING, each :meth:`tick` plays the DAC FIFO over the samples elapsed since the last
tick, passes the DAC output through the *world* (:mod:`.worlds`) and sends what the ADC
captured as ADC_DATA frames, every index exactly once, in blocks of at most
:attr:`adc_frame_samples`. Credit is granted as the DAC FIFO frees space; SYNC and STATUS go
out periodically; the watchdog stops the stream when host frames stop after a KEEPALIVE.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from firmware_protocol import (
    NEED_DATA,
    Ack,
    AdcData,
    Alarm,
    Configure,
    Connection,
    ConnectionClosed,
    Credit,
    DacData,
    Hello,
    Keepalive,
    Message,
    Nak,
    NakCode,
    RefusedFrame,
    RemoteProtocolError,
    Role,
    SampleFormat,
    Start,
    State,
    Status,
    Stop,
    Sync,
    UnknownMessage,
    channel_count,
)
from sim_devices.board.dac_fifo import DacFifo
from sim_devices.board.faults import FaultPlan
from sim_devices.board.scaling import from_full_scale_clipped, to_full_scale
from sim_devices.board.spec import BoardSpec
from sim_devices.board.worlds import LoopbackWorld, World

_FRAME_OVERHEAD = 12 + 14  # header + CRC, then the fixed part of ADC_DATA (bytes)
_CREDIT_STATES = (State.CONFIGURED, State.STREAMING, State.STOPPED)
_SESSION_STATES = (
    *_CREDIT_STATES,
    State.READY,
    State.CONFIGURING,
    State.STARTING,
    State.STOPPING,
)
_NS = 1_000_000_000


@dataclass(frozen=True)
class BoardSnapshot:
    """What the simulated board is doing (for tests and the CLI)."""

    state: State
    sample_index: int
    """Board sample clock now (samples)."""
    produced_index: int | None
    """Next ADC index to capture while streaming, else None (samples)."""
    dac_buffer_level: int
    dac_underruns: int
    adc_overruns: int
    watchdog_armed: bool
    host_frames: int
    dac_samples_received: int
    adc_samples_sent: int


# ADC frames computed by one call of the world (see _capture_until).
_WORLD_FRAMES = 8


class SimulatedBoard:
    """Simulated DAC/ADC board firmware (sans-IO; see the module docstring).

    Parameters
    ----------
    spec:
        Channels, formats, rates, buffers and identity (default :class:`BoardSpec`).
    clock:
        ``now()`` in seconds: :func:`time.monotonic` for real-time pacing (default) or an
        injected clock (:class:`sim_devices.stage.clock.ManualClock`) that tests advance.
    world:
        What the ADC captures from the DAC output (default: a zero-delay loopback cable).
    faults:
        Fault plan to draw injected faults from (default: none pending).
    """

    _next_sync: float
    """Board time of the next SYNC, ns (inf before a handshake)."""
    _next_status: float
    """Board time of the next STATUS, ns (inf before a handshake)."""

    def __init__(
        self,
        spec: BoardSpec | None = None,
        *,
        clock: Callable[[], float] | None = None,
        world: World | None = None,
        faults: FaultPlan | None = None,
    ) -> None:
        self.spec = spec or BoardSpec()
        self.clock = clock or time.monotonic
        self.world: World = world if world is not None else LoopbackWorld()
        self.faults = faults or FaultPlan()
        self.dac_underruns = 0
        self.adc_overruns = 0
        #: ADC values clipped at conversion since power-up (every channel), the count behind
        #: the ADC_CLIPPING alarm that STATUS reports.
        self.adc_clipped_samples = 0
        self.dac_samples_received = 0
        self.adc_samples_sent = 0
        self.host_frames = 0
        self.sessions = 0
        self._rate = self.spec.sample_rates_hz[0]
        self._base_index = 0
        self._base_ns = self._power_up_ns = self._now_ns()
        self._out = bytearray()
        self._layout_for: Configure | None = None
        self._layout = (1, 1, SampleFormat.INT16, 0)
        self._new_session()

    # --- sans-IO device contract ---------------------------------------------------------
    def receive_data(self, data: bytes) -> None:
        """Bytes from the host, any chunking."""
        if self.faults.unplugged or not data:
            return
        self.conn.receive_data(data)
        self._drain()

    def data_to_send(self) -> bytes:
        """Bytes for the host produced since the last call."""
        out = bytes(self._out)
        self._out.clear()
        return b"" if self.faults.unplugged else out

    def tick(self) -> None:
        """Bring the board up to its clock's present: capture, watchdog, sync, status, credit."""
        if self.faults.unplugged or self.conn.state not in _SESSION_STATES:
            return
        now = self._now_ns()
        self._check_watchdog(now)
        if self._capturing:
            self._capture_until(self._index_at(now))
        if now >= self._next_sync:
            self._send_sync(now)
        if now >= self._next_status:
            self._send_status(now, Alarm.NONE)
            self._next_status = now + round(self.spec.status_interval_s * _NS)
        self._grant_credit()

    def quiet_until_ns(self, awaited_index: int | None, max_bytes: int) -> int:
        """Board time (ns) before which :meth:`tick` has nothing to do but, while capturing,
        capture samples below ``awaited_index`` and send them, at most ``max_bytes`` of them:
        a tick skipped before it does its capture, identically, at the next tick (the ADC
        frames are cut differently, the samples are the same). Now (:meth:`_now_ns`) when
        something is due or pending: bytes to send, a fault, no session, or a capture
        running while no index is awaited (``awaited_index`` None).

        Due are: the next SYNC and STATUS and the watchdog's deadline; while capturing also
        the first instant the DAC FIFO may have freed enough to grant credit (each played
        index frees at most one sample), the instant the sample clock reaches
        ``awaited_index``, and the instant the capture would exceed ``max_bytes``. While no
        capture runs nothing plays, so the credit to grant changes only with host bytes
        (which the host's next service follows): due now if it is due at all.
        """
        now = self._now_ns()
        config, fifo = self.conn.configuration, self._fifo
        if self._out or self.faults.any_pending or self.conn.state not in _SESSION_STATES:
            return now
        due = [self._next_sync, self._next_status]
        if self._watchdog_ns is not None:
            due.append(self._last_host + self._watchdog_ns + 1)  # it fires after the deadline
        threshold = max(1, self.spec.dac_buffer_samples // 8)
        if not self._capturing:
            if fifo is not None and self.conn.state in _CREDIT_STATES:
                free = self.spec.dac_buffer_samples - fifo.level - self.conn.dac_credit
                if free >= threshold:
                    return now
            first = min(due)
            return now if math.isinf(first) else max(now, int(first))
        if awaited_index is None or config is None or fifo is None:
            return now
        due.append(self._ns_at_index(awaited_index))
        free = self.spec.dac_buffer_samples - fifo.level - self.conn.dac_credit
        due.append(self._ns_at_index(self._produced + max(0, threshold - free)))
        per_frame, _, _, wire = self._adc_layout(config)
        frames = max_bytes // 2 // wire  # half: room for a SYNC or STATUS beside them
        due.append(self._ns_at_index(self._produced + frames * per_frame))
        return max(now, int(min(due)))

    def _ns_at_index(self, index: int) -> int:
        """The first board time (ns) at which the sample clock reads ``index`` or more
        (the inverse of :meth:`_index_at`, exact in integers)."""
        ahead = index - self._base_index
        return self._base_ns + max(0, -(-ahead * _NS // self._rate))

    def connection_made(self) -> None:
        """A host opened the link: start a fresh session (the sample clock keeps running)."""
        self._new_session()

    def connection_lost(self) -> None:
        """The host went away: stop output and forget the session."""
        self._new_session()

    # --- inspection ----------------------------------------------------------------------
    def sample_index(self, now: float | None = None) -> int:
        """The board sample clock at ``now`` (s; default: the clock's present), samples."""
        return self._index_at(self._now_ns() if now is None else round(now * _NS))

    def _now_ns(self) -> int:
        """The clock's present as integer nanoseconds (board time)."""
        return round(self.clock() * _NS)

    def _index_at(self, t_ns: int) -> int:
        """SPEC 5.3: the sample index at board time ``t_ns``, exact integer arithmetic."""
        whole, part = divmod(t_ns - self._base_ns, _NS)
        return self._base_index + whole * self._rate + (part * self._rate) // _NS

    @property
    def adc_frame_samples(self) -> int:
        """Most sample frames per ADC_DATA frame in the current configuration."""
        config = self.conn.configuration
        if config is None:
            return 1
        return self._adc_layout(config)[0]

    def _adc_layout(self, config: Configure) -> tuple[int, int, SampleFormat, int]:
        """The ADC stream of ``config``: sample frames per ADC_DATA frame, channels, sample
        format, and the wire bytes of a full frame (COBS included). Kept for the
        configuration object last asked about (a configuration is immutable)."""
        if config is not self._layout_for:
            n_adc = channel_count(config.adc_channel_mask)
            fmt = SampleFormat(config.adc_format)
            per_frame = (self.spec.max_frame_len - _FRAME_OVERHEAD) // (n_adc * fmt.size)
            wire = per_frame * n_adc * fmt.size + _FRAME_OVERHEAD
            wire += wire // 254 + 2  # COBS: a code byte per 254, the delimiters
            self._layout, self._layout_for = (per_frame, n_adc, fmt, wire), config
        return self._layout

    def snapshot(self) -> BoardSnapshot:
        """The board's state now."""
        return BoardSnapshot(
            state=self.conn.state,
            sample_index=self.sample_index(),
            produced_index=self._produced if self._capturing else None,
            dac_buffer_level=self._fifo.level if self._fifo else 0,
            dac_underruns=self.dac_underruns,
            adc_overruns=self.adc_overruns,
            watchdog_armed=self._watchdog_ns is not None,
            host_frames=self.host_frames,
            dac_samples_received=self.dac_samples_received,
            adc_samples_sent=self.adc_samples_sent,
        )

    # --- session -------------------------------------------------------------------------
    def _new_session(self) -> None:
        spec = self.spec
        self.conn = Connection(
            Role.DEVICE,
            protocol_version=spec.protocol_version,
            schema_hash=spec.schema_hash,
            max_frame_len=spec.max_frame_len,
        )
        self.sessions += 1
        self._out.clear()
        self._fifo: DacFifo | None = None
        self._dac_end: int | None = None
        self._produced = 0
        self._capturing = False
        self._in_underrun = False
        self._latched = Alarm.NONE
        self._overrun_left = 0
        self._watchdog_ns: int | None = None
        self._last_host = self._now_ns()
        self._next_sync = math.inf
        self._next_status = math.inf
        self._dac_gain = 1.0
        self._adc_gain = 1.0

    def _send(self, message: Message) -> None:
        wire = self.conn.send(message)
        if isinstance(message, AdcData) and self.faults.frame_fault_pending:
            wire = self.faults.damage(wire)
        self._out += wire

    def _drain(self) -> None:
        while True:
            try:
                event = self.conn.next_event()
            except RemoteProtocolError as error:
                self._refuse(error)
                continue
            if event is NEED_DATA or isinstance(event, ConnectionClosed):
                return
            if isinstance(event, Message):
                self.host_frames += 1
                self._last_host = self._now_ns()
                self._handle(event)
            elif isinstance(event, UnknownMessage) and self._in_session():
                self._last_host = self._now_ns()
                if not event.optional:
                    self._send(event.nak())
            # FrameError / SequenceGap: counted in conn.stats; a board just goes on.

    def _in_session(self) -> bool:
        return self.conn.state in _SESSION_STATES

    def _refuse(self, error: RemoteProtocolError) -> None:
        """SPEC 5.2: answer an intact but refused host frame with one NAK quoting it; in
        IDLE (before a handshake) stay silent."""
        if not isinstance(error, RefusedFrame) or not self._in_session():
            return
        self._last_host = self._now_ns()
        self._send(Nak(error.ref_seq, error.ref_type, NakCode(error.code), _detail(str(error))))
        if self.conn.configuration is None:  # a refused CONFIGURE unconfigures (SPEC 5.2)
            self._stop_output()
            self._fifo = None

    def _handle(self, message: Message) -> None:
        if isinstance(message, Hello):
            self._hello()
        elif isinstance(message, Configure):
            self._configure(message)
        elif isinstance(message, Start):
            self._start(message)
        elif isinstance(message, Stop):
            if self._capturing:
                self._capture_until(self.sample_index())
            self._send(Ack(self.conn.last_received_seq or 0, Stop.TYPE_ID))
            self._stop_output()
            self._grant_credit()
        elif isinstance(message, Keepalive):
            self._watchdog_ns = message.watchdog_timeout_ms * 1_000_000
        elif isinstance(message, DacData):
            self._queue_dac(message)

    def _hello(self) -> None:
        """SPEC 5.1: (re)start the session: output off, buffer empty, watchdog disarmed."""
        self._stop_output()
        self._fifo = None
        self._watchdog_ns = None
        self._latched = Alarm.NONE
        self._send(self.conn.make_version(self.spec.firmware, self.spec.board_serial))
        if self.conn.refusal is None:
            self._send(self.spec.capabilities())
            now = self._now_ns()
            self._next_sync = now
            self._next_status = now
        else:
            self._next_sync = self._next_status = math.inf

    def _send_sync(self, now: int) -> None:
        # SPEC 5.3: board time counts from power-up, whatever the injected clock's zero.
        self._send(Sync(self._index_at(now), now - self._power_up_ns))
        self._next_sync = now + round(self.spec.sync_interval_s * _NS)

    def _configure(self, config: Configure) -> None:
        spec = self.spec
        seq = self.conn.last_received_seq or 0
        problem: tuple[NakCode, str] | None = None
        if config.sample_rate_hz not in spec.sample_rates_hz:
            problem = (NakCode.UNSUPPORTED_RATE, f"rates: {list(spec.sample_rates_hz)} Hz")
        elif config.dac_channel_mask >> spec.dac_channels or config.adc_channel_mask >> (
            spec.adc_channels
        ):
            problem = (
                NakCode.UNSUPPORTED_CHANNELS,
                f"{spec.dac_channels} DAC and {spec.adc_channels} ADC channels",
            )
        elif config.dac_format not in spec.formats or config.adc_format not in spec.formats:
            problem = (
                NakCode.UNSUPPORTED_FORMAT,
                "formats: " + ", ".join(f.name for f in spec.formats),
            )
        elif not all(
            spec.gain_min_cdb <= g <= spec.gain_max_cdb
            for g in (config.dac_gain_cdb, config.adc_gain_cdb)
        ):
            problem = (
                NakCode.GAIN_OUT_OF_RANGE,
                f"{spec.gain_min_cdb} .. {spec.gain_max_cdb} cdB",
            )
        self._stop_output()
        self._fifo = None
        if problem:
            self._send(Nak(seq, Configure.TYPE_ID, *problem))
            return
        now = self._now_ns()
        self._base_index = self._index_at(now)
        self._base_ns = now
        self._rate = config.sample_rate_hz
        self._dac_gain = 10.0 ** (config.dac_gain_cdb / 2000.0)
        self._adc_gain = 10.0 ** (config.adc_gain_cdb / 2000.0)
        self._send(Ack(seq, Configure.TYPE_ID))
        self._fifo = DacFifo(channel_count(config.dac_channel_mask))
        self._send_sync(now)
        self._grant_credit()

    def _start(self, start: Start) -> None:
        seq = self.conn.last_received_seq or 0
        now_index = self.sample_index()
        if start.start_sample_index < now_index:
            detail = f"clock is at {now_index}; start at a later index"
            self._send(Nak(seq, Start.TYPE_ID, NakCode.START_INDEX_PASSED, detail))
            return
        self._produced = start.start_sample_index
        self._capturing = True
        self._in_underrun = False
        if self._fifo is not None:
            self._fifo.drop_before(start.start_sample_index)
        reset = getattr(self.world, "reset", None)
        if callable(reset):
            reset()
        self._send(Ack(seq, Start.TYPE_ID))

    def _stop_output(self) -> None:
        self._capturing = False
        self._in_underrun = False
        self._dac_end = None
        if self._fifo is not None:
            self._fifo.clear()

    def _queue_dac(self, data: DacData) -> None:
        """SPEC 5.4: refuse an overlap; drop samples already played; queue the rest."""
        config = self.conn.configuration
        if self._fifo is None or config is None:
            return
        first, n = data.first_sample_index, data.sample_count
        if self._dac_end is not None and first < self._dac_end:
            detail = (
                f"DAC_DATA at {first} overlaps data accepted up to {self._dac_end};"
                " send each index once"
            )
            seq = self.conn.last_received_seq or 0
            self._send(Nak(seq, DacData.TYPE_ID, NakCode.BAD_PAYLOAD, _detail(detail)))
            return
        self._dac_end = first + n
        block = to_full_scale(data.samples(), SampleFormat(config.dac_format))
        if self._dac_gain != 1.0:
            block *= self._dac_gain
        late = min(n, self._produced - first) if self._capturing else 0
        if late > 0:
            self._fifo.late_samples += late
            block, first = block[late:], first + late
        if block.shape[0]:
            if self._fifo.end_index != first and self._fifo.runs >= self.spec.dac_runs:
                # SPEC 5.2 6(d): its indices count as accepted (they play zero), nothing queued.
                detail = f"{self.spec.dac_runs} runs of DAC indices queued; close a gap first"
                seq = self.conn.last_received_seq or 0
                self._send(Nak(seq, DacData.TYPE_ID, NakCode.BUSY, _detail(detail)))
                return
            self._fifo.push(first, block)
        self.dac_samples_received += n

    def _grant_credit(self) -> None:
        fifo = self._fifo
        if fifo is None or self.conn.state not in _CREDIT_STATES:
            return
        free = self.spec.dac_buffer_samples - fifo.level - self.conn.dac_credit
        if free >= max(1, self.spec.dac_buffer_samples // 8):
            self._send(Credit(free))

    # --- the sample path -----------------------------------------------------------------
    def _capture_until(self, end: int) -> None:
        config = self.conn.configuration
        fifo = self._fifo
        if config is None or fifo is None:
            return
        step, n_adc, fmt, _ = self._adc_layout(config)
        while self._produced < end:
            first = self._produced
            # The world computes up to _WORLD_FRAMES frames in one call (its per-call cost
            # is large for an acoustic channel); the ADC data still leaves frame by frame.
            span = min(end - first, step * _WORLD_FRAMES)
            if self.faults.dac_underrun_samples:
                fifo.discard(self.faults.dac_underrun_samples)
                self.faults.dac_underrun_samples = 0
                self.faults.counters.dac_underruns += 1
            dac, covered = fifo.play(first, span)
            self._count_underruns(covered)
            world_out = np.asarray(self.world(dac, first), dtype=np.float64)
            if world_out.shape == (span, n_adc) and self._adc_gain == 1.0:
                adc_all = world_out  # read only below: no copy needed
            else:
                adc_all = np.zeros((span, n_adc))
                k = min(world_out.shape[1], n_adc)
                adc_all[:, :k] = world_out[:, :k]
                if self._adc_gain != 1.0:
                    adc_all *= self._adc_gain
            counts, clipped = from_full_scale_clipped(adc_all, fmt)
            if clipped:
                self.adc_clipped_samples += clipped
                self._latched |= Alarm.ADC_CLIPPING
            for offset in range(0, span, step):
                n = min(step, span - offset)
                lost = self._take_overrun(n)
                self._produced = first + offset + n
                if lost < n:
                    self._send(
                        AdcData.from_array(
                            first + offset + lost,
                            config.adc_channel_mask,
                            fmt,
                            counts[offset + lost : offset + n],
                        )
                    )
                    self.adc_samples_sent += n - lost

    def _count_underruns(self, covered: npt.NDArray[np.bool_]) -> None:
        """SPEC 5.4: each maximal run of indices with no DAC sample is one underrun."""
        if covered.size == 0:
            return
        if covered.all():  # the usual block: every index had its DAC sample
            self._in_underrun = False
            return
        missing = ~covered
        before = np.concatenate(([not self._in_underrun], covered[:-1]))
        starts = int(np.count_nonzero(missing & before))
        if starts:
            self.dac_underruns += starts
            self._latched |= Alarm.DAC_UNDERRUN
        self._in_underrun = bool(missing[-1])

    def _take_overrun(self, n: int) -> int:
        if self._overrun_left == 0 and self.faults.adc_overrun_samples:
            self._overrun_left = self.faults.adc_overrun_samples
            self.faults.adc_overrun_samples = 0
            self.faults.counters.adc_overruns += 1
            self.adc_overruns += 1
            self._latched |= Alarm.ADC_OVERRUN
        lost = min(n, self._overrun_left)
        self._overrun_left -= lost
        return lost

    def _send_status(self, now: int, alarms: Alarm) -> None:
        """STATUS at board time ``now`` (ns); latched alarms are reported and cleared."""
        alarms |= self._latched
        if self._capturing and self._in_underrun:
            alarms |= Alarm.DAC_UNDERRUN
        self._latched = Alarm.NONE
        self._send(
            Status(
                sample_index=self._index_at(now),
                dac_buffer_level=self._fifo.level if self._fifo else 0,
                adc_buffer_level=0,
                dac_underruns=self.dac_underruns % (1 << 32),
                adc_overruns=self.adc_overruns % (1 << 32),
                temperature_cdeg=round(self.spec.temperature_c * 100),
                alarms=alarms,
            )
        )

    def _check_watchdog(self, now: int) -> None:
        """SPEC 5.7: fire at the first service after the deadline (or a forced fault)."""
        if self._watchdog_ns is None:
            return
        deadline = self._last_host + self._watchdog_ns
        forced = self.faults.watchdog_now
        if not forced and now <= deadline:
            return
        self.faults.watchdog_now = False
        self.faults.counters.watchdog_expiries += 1
        expiry = now if forced else deadline
        if self._capturing:
            self._capture_until(self._index_at(expiry))
        self._watchdog_ns = None
        self._stop_output()
        self._send_status(expiry, Alarm.WATCHDOG_EXPIRED)


def _detail(text: str) -> str:
    """A NAK detail: the text cut to at most 255 UTF-8 bytes at a character boundary."""
    return text.encode("utf-8")[:255].decode("utf-8", "ignore")
