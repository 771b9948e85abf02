"""The sans-IO protocol endpoint: bytes in, events out; events in, bytes out.

A :class:`Connection` never reads or writes anything itself. The host driver runs
``Connection(Role.HOST)`` over a real transport; the simulated board runs
``Connection(Role.DEVICE)``. The typical loop::

    conn.receive_data(transport.read())          # b"" means the stream ended
    while (event := conn.next_event()) is not NEED_DATA:
        handle(event)
    transport.write(conn.send(Keepalive(500)))

Errors are split by who broke the rule (h11): ``send`` raises
:class:`~firmware_protocol.errors.LocalProtocolError` and encodes nothing when this side tries
something illegal; ``next_event`` raises
:class:`~firmware_protocol.errors.RemoteProtocolError` when the peer sent an intact frame that
breaks the protocol (the frame is consumed and the state is unchanged, so the caller may log
and go on, or close). Damaged bytes are not errors: they come out as
:class:`~firmware_protocol.events.FrameError` events and the reader resyncs.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from firmware_protocol.constants import (
    FLAG_OPTIONAL,
    MAX_FRAME_LEN,
    PROTOCOL_MAJOR,
    PROTOCOL_MINOR,
    SEQ_MODULO,
)
from firmware_protocol.enums import NakCode, Role
from firmware_protocol.errors import (
    IncompatiblePeerError,
    LocalProtocolError,
    RefusedFrame,
    RemoteProtocolError,
)
from firmware_protocol.events import (
    NEED_DATA,
    ConnectionClosed,
    Event,
    FrameError,
    SequenceGap,
    UnknownMessage,
    _NeedData,
)
from firmware_protocol.framing import Frame, FrameDecoder, encode_frame
from firmware_protocol.messages import (
    MESSAGE_TYPES,
    Ack,
    AdcData,
    Capabilities,
    Configure,
    Credit,
    DacData,
    Hello,
    Message,
    Nak,
    Start,
    Stop,
    Version,
)
from firmware_protocol.schema import SCHEMA_HASH
from firmware_protocol.states import (
    COMMAND_NAMES,
    State,
    illegal_message,
    message_kind,
    next_state,
)
from firmware_protocol.stats import ProtocolStats
from firmware_protocol.versioning import incompatibility


class Connection:
    """One end of a host <-> board link, as a state machine over bytes.

    Parameters
    ----------
    role:
        ``Role.HOST`` or ``Role.DEVICE``.
    protocol_version:
        ``(major, minor)`` this side speaks; default this package's version. Other values are
        for tests that play an old or new peer.
    schema_hash:
        This side's schema hash (CRC seed of non-handshake frames); default this package's.
    max_frame_len:
        Largest decoded frame this side accepts, bytes.

    Attributes
    ----------
    state:
        The session :class:`~firmware_protocol.states.State`.
    stats:
        Receive-side :class:`~firmware_protocol.stats.ProtocolStats`.
    dac_credit:
        DAC sample frames the host may still send (granted by CREDIT, spent by DAC_DATA,
        reset to 0 on CONFIGURE and on reaching STOPPED). Both ends keep the same count.
    configuration:
        The acknowledged :class:`Configure`, or None.
    peer_version, peer_hello, capabilities:
        What the handshake told this side (device VERSION / host HELLO / CAPABILITIES).
    refusal:
        On the DEVICE, why the host's HELLO is incompatible (after sending VERSION the device
        returns to IDLE and waits for another HELLO), else None.

    Examples
    --------
    >>> host, board = Connection(Role.HOST), Connection(Role.DEVICE)
    >>> board.receive_data(host.send(Hello(2, 0, SCHEMA_HASH)))
    >>> board.next_event()
    Hello(protocol_major=2, protocol_minor=0, schema_hash=...)
    >>> host.state, board.state
    (<State.HELLO_SENT: 'HELLO_SENT'>, <State.HELLO_SENT: 'HELLO_SENT'>)
    >>> board.next_event()
    NEED_DATA
    """

    def __init__(
        self,
        role: Role,
        *,
        protocol_version: tuple[int, int] = (PROTOCOL_MAJOR, PROTOCOL_MINOR),
        schema_hash: int = SCHEMA_HASH,
        max_frame_len: int = MAX_FRAME_LEN,
    ) -> None:
        self.role = Role(role)
        self.peer_role = Role.DEVICE if self.role is Role.HOST else Role.HOST
        self.protocol_version = protocol_version
        self.schema_hash = schema_hash
        self.state = State.IDLE
        self.stats = ProtocolStats()
        self._decoder = FrameDecoder(
            schema_hash=schema_hash, max_frame_len=max_frame_len, stats=self.stats
        )
        self._tx_seq = 0
        self._rx_expected: int | None = None
        self._queued: deque[Event] = deque()
        self._eof = False
        self._pending: dict[int, int] = {}  # command type id -> seq awaiting ACK/NAK
        self._configuring: Configure | None = None
        self.dac_credit = 0
        self.configuration: Configure | None = None
        self.peer_version: Version | None = None
        self.peer_hello: Hello | None = None
        self.capabilities: Capabilities | None = None
        self.refusal: str | None = None
        self.peer_max_frame_len = MAX_FRAME_LEN

    @property
    def last_received_seq(self) -> int | None:
        """Sequence number of the last intact frame received (None before the first).

        A device quotes it as ``ref_seq`` when it answers the command it just decoded (ACK,
        NAK), including a NAK for a frame whose content raised RemoteProtocolError.
        """
        if self._rx_expected is None:
            return None
        return (self._rx_expected - 1) % SEQ_MODULO

    # --- sending ---------------------------------------------------------------------------

    def make_hello(self) -> Hello:
        """The HELLO this side sends: its own protocol version and schema hash."""
        return Hello(*self.protocol_version, self.schema_hash)

    def make_version(
        self, firmware: tuple[int, int, int] = (0, 0, 0), board_serial: int = 0
    ) -> Version:
        """The VERSION this board sends: its protocol version, schema hash and firmware."""
        return Version(*self.protocol_version, self.schema_hash, *firmware, board_serial)

    def send(self, event: Message | ConnectionClosed) -> bytes:
        """Encode one message (or close); raises LocalProtocolError if it is illegal now.

        Returns the bytes to write (``b""`` for :class:`ConnectionClosed`). The sequence
        number is assigned here, +1 per frame.
        """
        if isinstance(event, ConnectionClosed):
            self.state = State.CLOSED
            return b""
        if not isinstance(event, Message):
            raise LocalProtocolError(
                f"cannot send {type(event).__name__}: only messages and ConnectionClosed are"
                " sent; FrameError, SequenceGap and UnknownMessage are receive-side events"
            )
        if event.SENDER is not self.role:
            raise LocalProtocolError(
                f"{self.role.name} cannot send {event.NAME}: only the {event.SENDER.name} sends it"
            )
        kind = message_kind(event, self._pending)
        problem = self._violation(event, self.role, kind)
        if problem:
            raise LocalProtocolError(problem)
        flags = FLAG_OPTIONAL if event.OPTIONAL else 0
        seq = self._tx_seq
        wire = encode_frame(
            event.TYPE_ID,
            event.encode_payload(),
            seq,
            flags=flags,
            schema_hash=self.schema_hash,
            version=self.protocol_version,
            max_frame_len=self.peer_max_frame_len,
        )
        self._tx_seq = (seq + 1) % SEQ_MODULO
        self._apply(event, self.role, seq, kind)
        return wire

    # --- receiving -------------------------------------------------------------------------

    def receive_data(self, data: bytes) -> None:
        """Buffer received bytes; ``b""`` means the byte stream ended (EOF)."""
        if not data:
            self._eof = True
            return
        self._decoder.feed(data)

    def next_event(self) -> Event | _NeedData:
        """The next event, or :data:`NEED_DATA` when the buffered bytes hold no complete one.

        Raises RemoteProtocolError (or its subclass IncompatiblePeerError) for an intact
        frame that breaks the protocol; the frame is consumed.
        """
        if self._queued:
            return self._queued.popleft()
        if self.state is State.CLOSED:
            return ConnectionClosed()
        item = self._decoder.next_frame()
        while self._stale(item):
            self.stats.stale_frames += 1
            item = self._decoder.next_frame()
        if item is None:
            if self._eof:
                self.state = State.CLOSED
                return ConnectionClosed()
            return NEED_DATA
        if isinstance(item, FrameError):
            return item
        if self.role is Role.DEVICE and item.type_id == Hello.TYPE_ID:
            self._rx_expected = None  # a HELLO numbers a new session from its own seq
        gap = self._check_sequence(item.seq)
        try:
            event = self._handle(item)
        except RemoteProtocolError:
            self.stats.remote_errors += 1
            if gap is not None:
                self._queued.append(gap)
            raise
        if gap is not None:
            self._queued.append(event)
            return gap
        return event

    def _stale(self, item: Frame | FrameError | None) -> bool:
        """HOST side, between its HELLO and the VERSION answering it: an intact frame of
        another type is of the old session, sent before the device read the HELLO (SPEC
        5.1); it is dropped unseen, without an error and without a sequence check."""
        return (
            self.role is Role.HOST
            and self.state is State.HELLO_SENT
            and isinstance(item, Frame)
            and item.type_id != Version.TYPE_ID
        )

    def _check_sequence(self, seq: int) -> SequenceGap | None:
        expected = self._rx_expected
        self._rx_expected = (seq + 1) % SEQ_MODULO
        if expected is None or seq == expected:
            return None
        missed = (seq - expected) % SEQ_MODULO
        self.stats.sequence_gaps += 1
        self.stats.missed_frames += missed
        return SequenceGap(expected, seq, missed)

    def _handle(self, frame: Frame) -> Event:
        cls = MESSAGE_TYPES.get(frame.type_id)
        if cls is None:
            self.stats.unknown_messages += 1
            return UnknownMessage(frame.type_id, frame.seq, frame.flags, frame.payload)
        refuse = self._refusal_for(frame)
        if not cls.HANDSHAKE and frame.protocol_major != self.protocol_version[0]:
            raise refuse(
                NakCode.BAD_PAYLOAD,
                f"{self.peer_role.name} sent {cls.NAME} in a protocol"
                f" {frame.protocol_major}.x frame, this side speaks"
                f" {self.protocol_version[0]}.x; redo the handshake",
            )
        if cls.SENDER is not self.peer_role:
            raise refuse(
                NakCode.BAD_STATE,
                f"{self.peer_role.name} sent {cls.NAME}, which only the {cls.SENDER.name}"
                " sends; the peer is misconfigured (both ends playing the same role?)",
            )
        if cls.SENDER is Role.HOST and next_state(self.state, Role.HOST, cls.NAME) is None:
            # The state decides before the payload (SPEC 2.2): a command legal here is
            # answered as that command even when its payload is bad.
            raise refuse(
                NakCode.BAD_STATE, illegal_message(self.state, Role.HOST, cls.NAME, local=False)
            )
        try:
            message = cls.decode_payload(frame.payload)
        except RemoteProtocolError as error:
            if cls in (Configure, Start):
                self._enter_command(cls, frame.seq)
            raise refuse(NakCode.BAD_PAYLOAD, str(error)) from None
        kind = message_kind(message, self._pending)
        problem = self._violation(message, self.peer_role, kind)
        if problem:
            over_credit = isinstance(message, DacData) and self._credit_problem(message, False)
            code = NakCode.CREDIT_EXCEEDED if over_credit == problem else NakCode.BAD_PAYLOAD
            raise refuse(code, problem)
        if isinstance(message, Version):
            self._check_board_version(message)
        self._apply(message, self.peer_role, frame.seq, kind)
        return message

    def _refusal_for(self, frame: Frame) -> Callable[[NakCode, str], RemoteProtocolError]:
        """A maker of the error for a refused ``frame``: on the DEVICE a :class:`RefusedFrame`
        (the NAK to send), on the HOST a plain RemoteProtocolError (hosts send no NAK)."""

        def make(code: NakCode, text: str) -> RemoteProtocolError:
            if self.role is Role.DEVICE:
                return RefusedFrame(text, code=code, ref_seq=frame.seq, ref_type=frame.type_id)
            return RemoteProtocolError(text)

        return make

    def _enter_command(self, cls: type[Message], seq: int) -> None:
        """Move into the state of a command whose payload is bad, so its NAK answers it."""
        target = next_state(self.state, self.peer_role, cls.NAME)
        assert target is not None  # the state was checked first
        self._pending[cls.TYPE_ID] = seq
        if cls is Configure:
            self._configuring = None
            self.configuration = None
            self.dac_credit = 0
        self.state = target

    def _check_board_version(self, version: Version) -> None:
        """HOST side: refuse a board of another major version or schema."""
        board = (version.protocol_major, version.protocol_minor)
        reason = incompatibility(
            host_version=self.protocol_version,
            host_schema=self.schema_hash,
            board_version=board,
            board_schema=version.schema_hash,
        )
        if reason:
            # The board went back to IDLE after telling its version (SPEC 5.1); so does the
            # host, from where a HELLO (to a board flashed meanwhile) is legal again.
            self.state = State.IDLE
            self.peer_version = version
            raise IncompatiblePeerError(
                reason,
                local_version=self.protocol_version,
                peer_version=board,
                local_schema=self.schema_hash,
                peer_schema=version.schema_hash,
            )

    # --- rules shared by both directions ---------------------------------------------------

    def _violation(self, message: Message, sender: Role, kind: str) -> str | None:
        """Why ``sender`` may not emit ``message`` (of :func:`message_kind` ``kind``) now, or
        None. Same rules both ways."""
        local = sender is self.role
        if next_state(self.state, sender, kind) is None:
            return illegal_message(self.state, sender, kind, local=local)
        if isinstance(message, Ack) and message.ref_type in COMMAND_NAMES:
            # A NAK quoting anything but the awaited command is a refusal (NAK:OTHER).
            pending = self._pending.get(message.ref_type)
            if pending != message.ref_seq:
                name = COMMAND_NAMES[message.ref_type]
                return (
                    f"{message.NAME} refers to {name} seq {message.ref_seq}, but the {name}"
                    f" awaiting a reply has seq {pending}; replies must quote the command's seq"
                )
        if local and isinstance(message, Hello | Version):
            own = (message.protocol_major, message.protocol_minor, message.schema_hash)
            mine = (*self.protocol_version, self.schema_hash)
            if own != mine:
                return (
                    f"{message.NAME} states protocol {own[0]}.{own[1]} schema 0x{own[2]:08x} but"
                    f" this Connection speaks {mine[0]}.{mine[1]} schema 0x{mine[2]:08x};"
                    " build it with make_hello() / make_version()"
                )
        if isinstance(message, DacData):
            return self._data_problem(message, "dac") or self._credit_problem(message, local)
        if isinstance(message, AdcData):
            return self._data_problem(message, "adc")
        return None

    def _data_problem(self, message: DacData | AdcData, side: str) -> str | None:
        config = self.configuration
        if config is None:
            return f"{message.NAME} without an acknowledged CONFIGURE"
        if side == "dac":
            mask, fmt = config.dac_channel_mask, config.dac_format
        else:
            mask, fmt = config.adc_channel_mask, config.adc_format
        if message.channel_mask != mask or message.sample_format != fmt:
            return (
                f"{message.NAME} has channel_mask 0x{message.channel_mask:04x} and format"
                f" {message.sample_format.name}, but the configuration says 0x{mask:04x} and"
                f" {fmt.name}; send data as configured or CONFIGURE again"
            )
        return None

    def _credit_problem(self, message: DacData, local: bool) -> str | None:
        if message.sample_count <= self.dac_credit:
            return None
        if local:
            return (
                f"DAC_DATA of {message.sample_count} samples exceeds the {self.dac_credit}"
                " samples of credit the device granted; send fewer samples or wait for CREDIT"
            )
        return (
            f"HOST sent DAC_DATA of {message.sample_count} samples with only"
            f" {self.dac_credit} samples of credit; answer NAK CREDIT_EXCEEDED"
        )

    def _apply(self, message: Message, sender: Role, seq: int, kind: str) -> None:
        """Move the state and the bookkeeping after a legal message (sent or received) of
        :func:`message_kind` ``kind`` (as :meth:`_violation` checked it)."""
        target = next_state(self.state, sender, kind)
        assert target is not None  # checked by _violation
        if isinstance(message, Hello):
            self._restart_session(sender)
        if isinstance(message, Configure | Start | Stop):
            self._pending[message.TYPE_ID] = seq
        if isinstance(message, Configure):
            self._configuring = message
            self.configuration = None
        elif isinstance(message, Ack | Nak) and kind != "NAK:OTHER":
            # Only the reply to the awaited command settles it: a NAK:OTHER (a CONFIGURE
            # refused BAD_STATE while STREAMING) changes nothing (SPEC 5.2 check 4).
            self._pending.pop(message.ref_type, None)
            if message.ref_type == Configure.TYPE_ID:
                self.configuration = self._configuring if isinstance(message, Ack) else None
                self._configuring = None
        elif isinstance(message, Credit):
            self.dac_credit += message.credit_samples
        elif isinstance(message, DacData):
            self.dac_credit -= message.sample_count
        elif isinstance(message, Hello) and sender is not self.role:
            self.peer_hello = message
            self.refusal = incompatibility(
                host_version=(message.protocol_major, message.protocol_minor),
                host_schema=message.schema_hash,
                board_version=self.protocol_version,
                board_schema=self.schema_hash,
            )
        elif isinstance(message, Version) and sender is not self.role:
            self.peer_version = message
        elif isinstance(message, Capabilities) and sender is not self.role:
            self.capabilities = message
            self.peer_max_frame_len = message.max_frame_len
        if target is not self.state and target in (State.CONFIGURING, State.STOPPED):
            self.dac_credit = 0
        self.state = target
        if isinstance(message, Version) and sender is self.role and self.refusal:
            # The board told an incompatible host its version; it waits for another HELLO.
            self.state = State.IDLE

    def _restart_session(self, sender: Role) -> None:
        """A HELLO opens a new session: commands, configuration and credit are forgotten,
        and the device numbers its frames from 0 again (SPEC 2.6)."""
        self._pending.clear()
        self._configuring = None
        self.configuration = None
        self.dac_credit = 0
        self.refusal = None
        if sender is self.role:
            self._rx_expected = None  # the host hears the device's seq from 0 again
        else:
            self._tx_seq = 0
