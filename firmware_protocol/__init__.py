"""The wire protocol between the host and the transducer board: bytes in, events out.

No I/O anywhere in this package; see ``SPEC.md`` beside this file. The host driver runs
``Connection(Role.HOST)`` over a real transport and the simulated board runs
``Connection(Role.DEVICE)`` of the same code.
"""

from firmware_protocol.connection import Connection
from firmware_protocol.constants import (
    FLAG_OPTIONAL,
    MAX_FRAME_LEN,
    MAX_PAYLOAD_LEN,
    PROTOCOL_MAJOR,
    PROTOCOL_MINOR,
)
from firmware_protocol.enums import Alarm, LogLevel, NakCode, Role, SampleFormat
from firmware_protocol.errors import (
    FieldValueError,
    IncompatiblePeerError,
    LocalProtocolError,
    ProtocolError,
    RefusedFrame,
    RemoteProtocolError,
)
from firmware_protocol.events import (
    NEED_DATA,
    ConnectionClosed,
    Event,
    FrameError,
    FrameErrorKind,
    SequenceGap,
    UnknownMessage,
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
    Keepalive,
    Log,
    Message,
    Nak,
    Start,
    Status,
    Stop,
    Sync,
    Version,
)
from firmware_protocol.samples import channel_count, pack_samples, unpack_samples
from firmware_protocol.schema import SCHEMA_HASH
from firmware_protocol.states import TRANSITIONS, State
from firmware_protocol.stats import ProtocolStats

__all__ = [
    "FLAG_OPTIONAL",
    "MAX_FRAME_LEN",
    "MAX_PAYLOAD_LEN",
    "MESSAGE_TYPES",
    "NEED_DATA",
    "PROTOCOL_MAJOR",
    "PROTOCOL_MINOR",
    "SCHEMA_HASH",
    "TRANSITIONS",
    "Ack",
    "AdcData",
    "Alarm",
    "Capabilities",
    "Configure",
    "Connection",
    "ConnectionClosed",
    "Credit",
    "DacData",
    "Event",
    "FieldValueError",
    "Frame",
    "FrameDecoder",
    "FrameError",
    "FrameErrorKind",
    "Hello",
    "IncompatiblePeerError",
    "Keepalive",
    "LocalProtocolError",
    "Log",
    "LogLevel",
    "Message",
    "Nak",
    "NakCode",
    "ProtocolError",
    "ProtocolStats",
    "RefusedFrame",
    "RemoteProtocolError",
    "Role",
    "SampleFormat",
    "SequenceGap",
    "Start",
    "State",
    "Status",
    "Stop",
    "Sync",
    "UnknownMessage",
    "Version",
    "channel_count",
    "encode_frame",
    "pack_samples",
    "unpack_samples",
]


def __getattr__(name: str) -> object:
    """The transport errors that moved to :mod:`hil.errors` (see
    :mod:`firmware_protocol.errors`)."""
    from firmware_protocol import errors

    if name in errors.MOVED_TO_HOST:
        return getattr(errors, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
