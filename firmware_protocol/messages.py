"""Message definitions: type ids, field layouts, validation, payload encoding and decoding.

Each message is a frozen dataclass. Its wire layout is declared once, in ``LAYOUT`` (the
fixed little-endian part, in order) and ``TAIL`` (the variable part, if any); the schema hash,
``SPEC.md``'s tables and the codecs all derive from these declarations. Fields marked
``derived`` are computed from the tail (counts, lengths) and are not constructor arguments.

Field values are checked when a message is constructed, so an out-of-range value raises
:class:`~firmware_protocol.errors.FieldValueError` (naming the field, the value and the
allowed range) before anything is encoded. A received payload that fails the same checks
raises :class:`~firmware_protocol.errors.RemoteProtocolError`.

Extension rule (minor versions): bytes after the end of a payload's known layout are ignored,
so a later minor version may append fields.
"""

from __future__ import annotations

import functools
import struct
from dataclasses import dataclass, fields
from enum import IntEnum, IntFlag
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from firmware_protocol.constants import MAX_FRAME_LEN, MAX_PAYLOAD_LEN
from firmware_protocol.enums import Alarm, LogLevel, NakCode, Role, SampleFormat
from firmware_protocol.errors import FieldValueError, RemoteProtocolError
from firmware_protocol.samples import channel_count, pack_samples, unpack_samples

_WIRE_CODES = {"u8": "B", "u16": "H", "u32": "I", "u64": "Q", "i16": "h"}
_WIRE_RANGES = {
    "u8": (0, (1 << 8) - 1),
    "u16": (0, (1 << 16) - 1),
    "u32": (0, (1 << 32) - 1),
    "u64": (0, (1 << 64) - 1),
    "i16": (-(1 << 15), (1 << 15) - 1),
}
_WIRE_SIZES = {"u8": 1, "u16": 2, "u32": 4, "u64": 8, "i16": 2}


@dataclass(frozen=True)
class Field:
    """One fixed-size field of a payload layout.

    ``low``/``high`` bound the value (inclusive; default: the wire type's range); ``enum``
    restricts it to a coded set; ``derived`` fields are computed by the message (counts,
    lengths, reserved zeros) rather than passed to its constructor.
    """

    name: str
    wire: str
    unit: str = ""
    low: int | None = None
    high: int | None = None
    enum: type[IntEnum] | type[IntFlag] | None = None
    derived: bool = False
    doc: str = ""

    @property
    def size(self) -> int:
        """Size on the wire, bytes."""
        return _WIRE_SIZES[self.wire]

    @functools.cached_property
    def bounds(self) -> tuple[int, int]:
        """Inclusive (low, high) allowed range (read for every field of every frame)."""
        wire_low, wire_high = _WIRE_RANGES[self.wire]
        return (
            wire_low if self.low is None else self.low,
            wire_high if self.high is None else self.high,
        )

    def allowed_text(self) -> str:
        """The allowed values in words, for error messages and ``SPEC.md``."""
        if self.enum is NakCode:
            return "1 .. 255 (codes a firmware does not know are kept as numbers)"
        if self.enum is not None and self.enum is not Alarm:
            return "one of " + ", ".join(f"{m.value} ({m.name})" for m in self.enum)
        low, high = self.bounds
        unit = f" {self.unit}" if self.unit else ""
        return f"{low} .. {high}{unit}"


@dataclass(frozen=True)
class Tail:
    """The variable-length part after the fixed fields: its name and its length rule."""

    name: str
    rule: str


class Message:
    """Base of every message type; subclasses are frozen dataclasses."""

    TYPE_ID: ClassVar[int]
    NAME: ClassVar[str]
    SENDER: ClassVar[Role]
    LAYOUT: ClassVar[tuple[Field, ...]] = ()
    TAIL: ClassVar[Tail | None] = None
    OPTIONAL: ClassVar[bool] = False
    """Sent with the OPTIONAL flag: a peer that does not know the type ignores it."""
    HANDSHAKE: ClassVar[bool] = False
    """CRC-seeded with the handshake seed, layout frozen across all protocol versions."""
    DOC: ClassVar[str] = ""
    _STRUCT: ClassVar[struct.Struct]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls._STRUCT = struct.Struct("<" + "".join(_WIRE_CODES[f.wire] for f in cls.LAYOUT))

    def __post_init__(self) -> None:
        for spec in self.LAYOUT:
            if spec.derived:
                continue
            value = getattr(self, spec.name)
            object.__setattr__(self, spec.name, self._checked(spec, value))
        self._check_tail()

    def _checked(self, spec: Field, value: Any) -> Any:
        # Every frame is checked on both sides: the field is named only in an error.
        if type(value) is int and spec.enum is None:  # the usual field: a plain int in range
            low, high = spec.bounds
            if low <= value <= high:
                return value
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise FieldValueError(self._where(spec), value, f"an integer, {spec.allowed_text()}")
        given = value
        low, high = spec.bounds
        value = int(value)
        if not low <= value <= high:
            raise FieldValueError(self._where(spec), value, spec.allowed_text(), spec.doc)
        if spec.enum is Alarm:
            return Alarm(value)
        if spec.enum is not None:
            if type(given) is spec.enum:
                return given  # already one of its members
            try:
                return spec.enum(value)
            except ValueError:
                if spec.enum is NakCode:
                    return value  # a code from a later minor version: kept as a number
                raise FieldValueError(
                    self._where(spec), value, spec.allowed_text(), spec.doc
                ) from None
        return value

    def _where(self, spec: Field) -> str:
        """``Message.field``, as errors name a field."""
        return f"{type(self).__name__}.{spec.name}"

    def _check_tail(self) -> None:
        """Subclasses with a tail check its length here."""

    def _tail_bytes(self) -> bytes:
        return b""

    def encode_payload(self) -> bytes:
        """The payload bytes: the fixed fields little-endian, then the tail."""
        values = [getattr(self, f.name) for f in self.LAYOUT]
        return self._STRUCT.pack(*values) + self._tail_bytes()

    @classmethod
    def decode_payload(cls, payload: bytes | memoryview) -> Message:
        """Parse a payload; raises :class:`RemoteProtocolError` when it is malformed."""
        fixed_size = cls._STRUCT.size
        if len(payload) < fixed_size:
            raise RemoteProtocolError(
                f"{cls.NAME} payload is {len(payload)} bytes, shorter than its"
                f" {fixed_size}-byte fixed part; the peer's firmware is broken or mismatched"
            )
        names = (f.name for f in cls.LAYOUT)
        values = dict(zip(names, cls._STRUCT.unpack_from(payload), strict=True))
        try:
            return cls._from_wire(values, memoryview(payload)[fixed_size:])
        except FieldValueError as error:
            raise RemoteProtocolError(f"peer sent a bad {cls.NAME}: {error}") from error

    @classmethod
    def _from_wire(cls, values: dict[str, int], tail: memoryview) -> Message:
        kwargs = {f.name: values[f.name] for f in cls.LAYOUT if not f.derived}
        return cls(**kwargs)

    def field_values(self) -> dict[str, Any]:
        """Constructor arguments as plain JSON-friendly values (bytes as hex)."""
        out: dict[str, Any] = {}
        for item in fields(self):  # type: ignore[arg-type]
            value = getattr(self, item.name)
            if isinstance(value, bytes):
                value = value.hex()
            elif isinstance(value, tuple):
                value = list(value)
            elif isinstance(value, int):
                value = int(value)
            out[item.name] = value
        return out


def _text_tail(cls_name: str, text: str, limit: int) -> bytes:
    raw = text.encode("utf-8")
    if len(raw) > limit:
        raise FieldValueError(f"{cls_name}.text", f"<{len(raw)} UTF-8 bytes>", f"<= {limit} bytes")
    return raw


def _take(tail: memoryview, length: int, what: str) -> bytes:
    if len(tail) < length:
        raise RemoteProtocolError(
            f"{what} needs {length} bytes but the payload has {len(tail)} left;"
            " the peer's firmware is broken or mismatched"
        )
    return bytes(tail[:length])


# --- handshake -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Hello(Message):
    """HOST -> DEVICE: opens the session and states the host's protocol version and schema."""

    protocol_major: int
    protocol_minor: int
    schema_hash: int

    TYPE_ID = 0x01
    NAME = "HELLO"
    SENDER = Role.HOST
    HANDSHAKE = True
    LAYOUT = (
        Field("protocol_major", "u8"),
        Field("protocol_minor", "u8"),
        Field("schema_hash", "u32", doc="CRC-32 of the canonical message definitions"),
    )


@dataclass(frozen=True)
class Version(Message):
    """DEVICE -> HOST: answers HELLO with the board's protocol, schema and firmware version."""

    protocol_major: int
    protocol_minor: int
    schema_hash: int
    firmware_major: int
    firmware_minor: int
    firmware_patch: int
    board_serial: int

    TYPE_ID = 0x02
    NAME = "VERSION"
    SENDER = Role.DEVICE
    HANDSHAKE = True
    LAYOUT = (
        Field("protocol_major", "u8"),
        Field("protocol_minor", "u8"),
        Field("schema_hash", "u32"),
        Field("firmware_major", "u8"),
        Field("firmware_minor", "u8"),
        Field("firmware_patch", "u16"),
        Field("board_serial", "u32"),
    )


@dataclass(frozen=True)
class Capabilities(Message):
    """DEVICE -> HOST: what the board can do; sent right after VERSION."""

    dac_channels: int
    adc_channels: int
    formats: int
    dac_buffer_samples: int
    adc_buffer_samples: int
    max_frame_len: int
    gain_min_cdb: int
    gain_max_cdb: int
    sample_rates_hz: tuple[int, ...]

    TYPE_ID = 0x03
    NAME = "CAPABILITIES"
    SENDER = Role.DEVICE
    LAYOUT = (
        Field("dac_channels", "u8", "channels", 1, 16),
        Field("adc_channels", "u8", "channels", 1, 16),
        Field("formats", "u8", "bit mask", 1, 7, doc="bit (code - 1) set per SampleFormat"),
        Field("n_rates", "u8", "rates", 1, 32, derived=True),
        Field("dac_buffer_samples", "u32", "sample frames", 1),
        Field("adc_buffer_samples", "u32", "sample frames", 1),
        Field("max_frame_len", "u16", "bytes", 64, MAX_FRAME_LEN),
        Field("gain_min_cdb", "i16", "0.01 dB", -12000, 12000),
        Field("gain_max_cdb", "i16", "0.01 dB", -12000, 12000),
    )
    TAIL = Tail("sample_rates_hz", "n_rates x u32, Hz")

    @property
    def n_rates(self) -> int:
        """Number of supported sample rates."""
        return len(self.sample_rates_hz)

    def _check_tail(self) -> None:
        rates = tuple(self.sample_rates_hz)
        object.__setattr__(self, "sample_rates_hz", rates)
        if not 1 <= len(rates) <= 32:
            raise FieldValueError("Capabilities.sample_rates_hz", rates, "1 .. 32 rates")
        for rate in rates:
            if isinstance(rate, bool) or not isinstance(rate, int) or not 1 <= rate < 1 << 32:
                raise FieldValueError("Capabilities.sample_rates_hz", rate, "1 .. 4294967295 Hz")
        if self.gain_min_cdb > self.gain_max_cdb:
            raise FieldValueError(
                "Capabilities.gain_min_cdb",
                self.gain_min_cdb,
                f"<= gain_max_cdb ({self.gain_max_cdb})",
            )

    def _tail_bytes(self) -> bytes:
        return struct.pack(f"<{len(self.sample_rates_hz)}I", *self.sample_rates_hz)

    @property
    def sample_formats(self) -> tuple[SampleFormat, ...]:
        """The formats whose bit is set in ``formats``."""
        return tuple(f for f in SampleFormat if self.formats & f.mask_bit)

    @classmethod
    def _from_wire(cls, values: dict[str, int], tail: memoryview) -> Message:
        n = values["n_rates"]
        raw = _take(tail, 4 * n, f"CAPABILITIES with n_rates = {n}")
        kwargs = {f.name: values[f.name] for f in cls.LAYOUT if not f.derived}
        return cls(**kwargs, sample_rates_hz=struct.unpack(f"<{n}I", raw))


# --- commands --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Configure(Message):
    """HOST -> DEVICE: sample rate, channels, formats and gains; answered by ACK or NAK.

    On receipt the device drops its previous configuration: an ACK means the new one is
    applied, a NAK leaves the device unconfigured (state READY).
    """

    sample_rate_hz: int
    dac_channel_mask: int
    adc_channel_mask: int
    dac_format: SampleFormat
    adc_format: SampleFormat
    dac_gain_cdb: int = 0
    adc_gain_cdb: int = 0

    TYPE_ID = 0x10
    NAME = "CONFIGURE"
    SENDER = Role.HOST
    LAYOUT = (
        Field("sample_rate_hz", "u32", "Hz", 1, 100_000_000, doc="one of CAPABILITIES' rates"),
        Field("dac_channel_mask", "u16", "bit mask", 1, doc="bit n selects DAC channel n"),
        Field("adc_channel_mask", "u16", "bit mask", 1, doc="bit n selects ADC channel n"),
        Field("dac_format", "u8", enum=SampleFormat),
        Field("adc_format", "u8", enum=SampleFormat),
        Field("dac_gain_cdb", "i16", "0.01 dB", -12000, 12000),
        Field("adc_gain_cdb", "i16", "0.01 dB", -12000, 12000),
    )


@dataclass(frozen=True)
class Start(Message):
    """HOST -> DEVICE: start DAC output and ADC capture at a sample index of the board clock."""

    start_sample_index: int

    TYPE_ID = 0x11
    NAME = "START"
    SENDER = Role.HOST
    LAYOUT = (Field("start_sample_index", "u64", "samples", doc="board sample clock index"),)


@dataclass(frozen=True)
class Stop(Message):
    """HOST -> DEVICE: stop output and capture now and drop the DAC samples held; the device
    flushes and ACKs."""

    TYPE_ID = 0x12
    NAME = "STOP"
    SENDER = Role.HOST


@dataclass(frozen=True)
class Keepalive(Message):
    """HOST -> DEVICE: arms the watchdog; with no host frame for the timeout the board stops."""

    watchdog_timeout_ms: int

    TYPE_ID = 0x13
    NAME = "KEEPALIVE"
    SENDER = Role.HOST
    LAYOUT = (Field("watchdog_timeout_ms", "u16", "ms", 1),)


# --- sample data -----------------------------------------------------------------------------

_DATA_LAYOUT = (
    Field("first_sample_index", "u64", "samples", doc="board sample clock index of frame 0"),
    Field("sample_count", "u16", "sample frames", 1, derived=True),
    Field("channel_mask", "u16", "bit mask", 1, doc="bit n selects channel n"),
    Field("sample_format", "u8", enum=SampleFormat),
    Field("reserved", "u8", derived=True, doc="0; ignored on receipt"),
)
_DATA_FIXED = sum(f.size for f in _DATA_LAYOUT)


class _SampleData(Message):
    """Shared layout and helpers of DAC_DATA and ADC_DATA."""

    first_sample_index: int
    channel_mask: int
    sample_format: SampleFormat
    data: bytes

    LAYOUT = _DATA_LAYOUT
    TAIL = Tail("samples", "sample_count x channels x format size bytes, interleaved")
    reserved: ClassVar[int] = 0

    @property
    def channels(self) -> int:
        """Number of channels (bits set in ``channel_mask``)."""
        return channel_count(self.channel_mask)

    @property
    def sample_count(self) -> int:
        """Sample frames (instants) in this message; each has one sample per channel."""
        return len(self.data) // (self.channels * SampleFormat(self.sample_format).size)

    def _check_tail(self) -> None:
        name = type(self).__name__
        data = self.data
        if not isinstance(data, bytes):
            data = bytes(data)
            object.__setattr__(self, "data", data)
        frame_bytes = self.channels * SampleFormat(self.sample_format).size
        most = (MAX_PAYLOAD_LEN - _DATA_FIXED) // frame_bytes
        if len(data) == 0 or len(data) % frame_bytes or len(data) // frame_bytes > most:
            raise FieldValueError(
                f"{name}.data",
                f"<{len(data)} bytes>",
                f"1 .. {most} whole sample frames of {frame_bytes} bytes"
                f" ({self.channels} channels x {self.sample_format.name}) to fit the"
                f" {MAX_FRAME_LEN}-byte frame limit",
                "split the block into several messages",
            )

    def _tail_bytes(self) -> bytes:
        return self.data

    def samples(self) -> npt.NDArray[Any]:
        """The samples as a (sample_count, channels) array (int16, int32 or float32)."""
        return unpack_samples(self.data, self.channels, self.sample_format)

    @classmethod
    def from_array(
        cls,
        first_sample_index: int,
        channel_mask: int,
        sample_format: SampleFormat | int,
        samples: npt.ArrayLike,
    ) -> Any:
        """Build the message from a (frames, channels) array; see :func:`pack_samples`."""
        array = np.asarray(samples)
        if array.ndim == 2 and array.shape[1] != channel_count(channel_mask):
            raise FieldValueError(
                f"{cls.__name__}.samples.shape[1]",
                array.shape[1],
                f"{channel_count(channel_mask)} (bits set in channel_mask 0x{channel_mask:04x})",
            )
        return cls(
            first_sample_index, channel_mask, sample_format, pack_samples(array, sample_format)
        )  # type: ignore[call-arg]

    @classmethod
    def _from_wire(cls, values: dict[str, int], tail: memoryview) -> Message:
        try:
            size = SampleFormat(values["sample_format"]).size
        except ValueError:
            raise RemoteProtocolError(
                f"peer sent a bad {cls.NAME}: sample_format = {values['sample_format']} is not"
                f" one of {', '.join(f'{f.value} ({f.name})' for f in SampleFormat)}"
            ) from None
        length = values["sample_count"] * channel_count(values["channel_mask"]) * size
        data = _take(tail, length, f"{cls.NAME} with sample_count = {values['sample_count']}")
        return cls(
            values["first_sample_index"], values["channel_mask"], values["sample_format"], data
        )  # type: ignore[call-arg]


@dataclass(frozen=True)
class DacData(_SampleData):
    """HOST -> DEVICE: samples to play, starting at ``first_sample_index``; costs credit."""

    first_sample_index: int
    channel_mask: int
    sample_format: SampleFormat
    data: bytes

    TYPE_ID = 0x20
    NAME = "DAC_DATA"
    SENDER = Role.HOST


@dataclass(frozen=True)
class AdcData(_SampleData):
    """DEVICE -> HOST: captured samples, the first one taken at ``first_sample_index``."""

    first_sample_index: int
    channel_mask: int
    sample_format: SampleFormat
    data: bytes

    TYPE_ID = 0x21
    NAME = "ADC_DATA"
    SENDER = Role.DEVICE


@dataclass(frozen=True)
class Credit(Message):
    """DEVICE -> HOST: grants more DAC sample frames; the host must not send beyond its total."""

    credit_samples: int

    TYPE_ID = 0x22
    NAME = "CREDIT"
    SENDER = Role.DEVICE
    LAYOUT = (Field("credit_samples", "u32", "sample frames", 1, doc="added to the credit"),)


# --- monitoring ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Status(Message):
    """DEVICE -> HOST: buffer levels, error counters, temperature and alarms."""

    sample_index: int
    dac_buffer_level: int
    adc_buffer_level: int
    dac_underruns: int
    adc_overruns: int
    temperature_cdeg: int
    alarms: Alarm = Alarm.NONE

    TYPE_ID = 0x30
    NAME = "STATUS"
    SENDER = Role.DEVICE
    LAYOUT = (
        Field("sample_index", "u64", "samples", doc="board sample clock when measured"),
        Field("dac_buffer_level", "u32", "sample frames"),
        Field("adc_buffer_level", "u32", "sample frames"),
        Field(
            "dac_underruns",
            "u32",
            "count",
            doc="runs of consecutive unplayed DAC indices, cumulative since power-up (5.4)",
        ),
        Field(
            "adc_overruns",
            "u32",
            "count",
            doc="runs of consecutive lost ADC indices, cumulative since power-up (5.4)",
        ),
        Field("temperature_cdeg", "i16", "0.01 degC"),
        Field("alarms", "u16", "bit mask", enum=Alarm),
    )


@dataclass(frozen=True)
class Sync(Message):
    """DEVICE -> HOST: pairs a sample index of the board clock with the board's time."""

    sample_index: int
    board_time_ns: int

    TYPE_ID = 0x31
    NAME = "SYNC"
    SENDER = Role.DEVICE
    LAYOUT = (
        Field("sample_index", "u64", "samples"),
        Field(
            "board_time_ns",
            "u64",
            "ns",
            doc="board time at that sample: ns since the board powered up (5.3)",
        ),
    )


@dataclass(frozen=True)
class Log(Message):
    """DEVICE -> HOST: a line of firmware log text (UTF-8); sent with the OPTIONAL flag."""

    level: LogLevel
    text: str

    TYPE_ID = 0x32
    NAME = "LOG"
    SENDER = Role.DEVICE
    OPTIONAL = True
    LAYOUT = (Field("level", "u8", enum=LogLevel), Field("text_len", "u16", "bytes", derived=True))
    TAIL = Tail("text", "text_len bytes, UTF-8")

    @property
    def text_len(self) -> int:
        """Length of the UTF-8 text, bytes."""
        return len(self.text.encode("utf-8"))

    def _check_tail(self) -> None:
        _text_tail("Log", self.text, MAX_PAYLOAD_LEN - 3)

    def _tail_bytes(self) -> bytes:
        return self.text.encode("utf-8")

    @classmethod
    def _from_wire(cls, values: dict[str, int], tail: memoryview) -> Message:
        raw = _take(tail, values["text_len"], "LOG text")
        return cls(values["level"], raw.decode("utf-8", errors="replace"))  # type: ignore[arg-type]


# --- replies ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Ack(Message):
    """DEVICE -> HOST: the command with sequence number ``ref_seq`` was accepted."""

    ref_seq: int
    ref_type: int

    TYPE_ID = 0x40
    NAME = "ACK"
    SENDER = Role.DEVICE
    LAYOUT = (
        Field("ref_seq", "u16", doc="seq of the acknowledged frame"),
        Field("ref_type", "u8", doc="message type of the acknowledged frame"),
    )


@dataclass(frozen=True)
class Nak(Message):
    """DEVICE -> HOST: the frame with sequence number ``ref_seq`` was refused, and why."""

    ref_seq: int
    ref_type: int
    code: NakCode
    detail: str = ""

    TYPE_ID = 0x41
    NAME = "NAK"
    SENDER = Role.DEVICE
    LAYOUT = (
        Field("ref_seq", "u16", doc="seq of the refused frame"),
        Field("ref_type", "u8", doc="message type of the refused frame"),
        Field("code", "u8", low=1, enum=NakCode),
        Field("detail_len", "u8", "bytes", derived=True),
    )
    TAIL = Tail("detail", "detail_len bytes, UTF-8")

    @property
    def detail_len(self) -> int:
        """Length of the UTF-8 detail text, bytes."""
        return len(self.detail.encode("utf-8"))

    def _check_tail(self) -> None:
        raw = self.detail.encode("utf-8")
        if len(raw) > 255:
            raise FieldValueError("Nak.detail", f"<{len(raw)} UTF-8 bytes>", "<= 255 bytes")

    def _tail_bytes(self) -> bytes:
        return self.detail.encode("utf-8")

    @classmethod
    def _from_wire(cls, values: dict[str, int], tail: memoryview) -> Message:
        raw = _take(tail, values["detail_len"], "NAK detail")
        text = raw.decode("utf-8", errors="replace")
        return cls(values["ref_seq"], values["ref_type"], values["code"], text)  # type: ignore[arg-type]


MESSAGE_TYPES: dict[int, type[Message]] = {
    cls.TYPE_ID: cls
    for cls in (
        Hello,
        Version,
        Capabilities,
        Configure,
        Start,
        Stop,
        Keepalive,
        DacData,
        AdcData,
        Credit,
        Status,
        Sync,
        Log,
        Ack,
        Nak,
    )
}
"""Every message class of protocol 1.0 by type id."""

HANDSHAKE_TYPE_IDS: frozenset[int] = frozenset(t for t, c in MESSAGE_TYPES.items() if c.HANDSHAKE)
"""Type ids whose frames use the handshake CRC seed (HELLO, VERSION)."""
