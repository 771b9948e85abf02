"""Events that are not messages: what the reader reports besides decoded messages.

:meth:`Connection.next_event` returns a :class:`~firmware_protocol.messages.Message`, one of
the events here, or the :data:`NEED_DATA` sentinel.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Final

from firmware_protocol.enums import NakCode
from firmware_protocol.messages import Message, Nak


class _NeedData:
    """Sentinel: no complete event yet; call ``receive_data`` with more bytes."""

    _instance: _NeedData | None = None

    def __new__(cls) -> _NeedData:
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "NEED_DATA"


NEED_DATA: Final = _NeedData()
"""Returned by ``next_event`` when the buffered bytes hold no complete frame."""


class FrameErrorKind(Enum):
    """Which check a damaged frame failed."""

    COBS = "cobs"
    OVERSIZE = "oversize"
    CRC = "crc"
    BAD_HEADER = "bad_header"


@dataclass(frozen=True)
class FrameError:
    """Bytes between two delimiters were dropped; the reader resynced at the next 0x00.

    ``size`` is the number of encoded bytes dropped (delimiters excluded).
    """

    kind: FrameErrorKind
    size: int
    detail: str


@dataclass(frozen=True)
class SequenceGap:
    """The peer's sequence number jumped: ``missed`` frames (mod 65536) never arrived intact.

    Reported just before the message whose frame carried ``received``.
    """

    expected: int
    received: int
    missed: int


@dataclass(frozen=True)
class UnknownMessage:
    """An intact frame of a message type this side does not know (e.g. from a newer minor).

    The HOST reports it and goes on. The DEVICE answers ``event.nak()`` unless ``optional``
    (the sender set the OPTIONAL flag, meaning "ignore me if you do not know me").
    """

    type_id: int
    seq: int
    flags: int
    payload: bytes

    @property
    def optional(self) -> bool:
        """True if the sender flagged the message as ignorable."""
        return bool(self.flags & 0x01)

    def nak(self) -> Nak:
        """The NAK UNKNOWN_MESSAGE a device sends in reply."""
        return Nak(self.seq, self.type_id, NakCode.UNKNOWN_MESSAGE, "unknown message type")


@dataclass(frozen=True)
class ConnectionClosed:
    """The byte stream ended (``receive_data(b"")``) or this side closed the connection."""


Event = Message | FrameError | SequenceGap | UnknownMessage | ConnectionClosed
"""Everything ``next_event`` can return besides :data:`NEED_DATA`."""
