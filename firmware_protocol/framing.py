"""Frames on the wire: header + payload + CRC-32, COBS-encoded, each followed by 0x00.

Decoded frame layout (all little-endian)::

    offset 0  u8   protocol_major
    offset 1  u8   protocol_minor
    offset 2  u8   message_type
    offset 3  u8   flags            (bit 0 OPTIONAL; other bits 0 when sent, ignored on receipt)
    offset 4  u16  seq              (per direction, +1 per frame, wraps 65535 -> 0)
    offset 6  u16  payload_length   (bytes)
    offset 8  ...  payload
    offset 8+payload_length  u32  crc32(header + payload, seed)

The seed is 0 for HELLO and VERSION and the schema hash for every other type.
:class:`FrameDecoder` turns a byte stream into frames; it never raises on bad input: it drops
the bytes up to the next 0x00, counts the damage and returns a
:class:`~firmware_protocol.events.FrameError`.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

from firmware_protocol import cobs
from firmware_protocol.constants import (
    CRC_SIZE,
    HANDSHAKE_CRC_SEED,
    HEADER_SIZE,
    MAX_FRAME_LEN,
    PROTOCOL_MAJOR,
    PROTOCOL_MINOR,
    max_encoded_len,
)
from firmware_protocol.errors import FieldValueError
from firmware_protocol.events import FrameError, FrameErrorKind
from firmware_protocol.messages import HANDSHAKE_TYPE_IDS
from firmware_protocol.schema import SCHEMA_HASH
from firmware_protocol.stats import ProtocolStats

HEADER = struct.Struct("<BBBBHH")
_OVERHEAD = HEADER_SIZE + CRC_SIZE
# Compact the receive buffer once this many consumed bytes sit in front of it.
_COMPACT_AT = 1 << 16


@dataclass(frozen=True, slots=True)
class Frame:
    """One intact frame: header fields and payload bytes (CRC already checked)."""

    protocol_major: int
    protocol_minor: int
    type_id: int
    flags: int
    seq: int
    payload: bytes


def crc_seed(type_id: int, schema_hash: int = SCHEMA_HASH) -> int:
    """CRC-32 seed of a frame of this message type: 0 for the handshake, else the schema hash."""
    return HANDSHAKE_CRC_SEED if type_id in HANDSHAKE_TYPE_IDS else schema_hash


def encode_frame(
    type_id: int,
    payload: bytes,
    seq: int,
    *,
    flags: int = 0,
    schema_hash: int = SCHEMA_HASH,
    version: tuple[int, int] = (PROTOCOL_MAJOR, PROTOCOL_MINOR),
    max_frame_len: int = MAX_FRAME_LEN,
) -> bytes:
    """Build the wire bytes of one frame: COBS(header + payload + CRC) + b"\\x00".

    >>> encode_frame(0x12, b"", 0).hex(" ")  # STOP, seq 0
    '02 02 02 12 01 01 01 01 05 5d 4b 6b 35 00'
    """
    limit = max_frame_len - _OVERHEAD
    if len(payload) > limit:
        raise FieldValueError(
            "payload length",
            len(payload),
            f"<= {limit} bytes (frame limit {max_frame_len})",
            "split the data into several messages",
        )
    body = HEADER.pack(version[0], version[1], type_id, flags, seq, len(payload)) + payload
    crc = zlib.crc32(body, crc_seed(type_id, schema_hash))
    return cobs.encode(body + crc.to_bytes(CRC_SIZE, "little")) + b"\x00"


class FrameDecoder:
    """Incremental frame reader: ``feed(bytes)``, then ``next_frame()`` until it returns None.

    Usable on its own (benchmarks, sniffers) or inside a
    :class:`~firmware_protocol.connection.Connection`. Empty frames (two delimiters in a row)
    are skipped silently, so a sender may emit extra 0x00 bytes to flush a receiver.

    >>> dec = FrameDecoder()
    >>> dec.feed(b"junk\\x00" + encode_frame(0x12, b"", 7))
    >>> dec.next_frame().kind.name, dec.next_frame().seq, dec.next_frame()
    ('COBS', 7, None)
    """

    def __init__(
        self,
        *,
        schema_hash: int = SCHEMA_HASH,
        max_frame_len: int = MAX_FRAME_LEN,
        stats: ProtocolStats | None = None,
    ) -> None:
        self.stats = stats if stats is not None else ProtocolStats()
        self._schema_hash = schema_hash
        self._max_frame_len = max_frame_len
        self._max_encoded = max_encoded_len(max_frame_len)
        self._buf = bytearray()
        self._pos = 0
        self._discarding = False

    @property
    def buffered(self) -> int:
        """Bytes received but not yet consumed."""
        return len(self._buf) - self._pos

    def feed(self, data: bytes | bytearray | memoryview) -> None:
        """Append received bytes (any chunking)."""
        self.stats.bytes_received += len(data)
        self._buf += data

    def next_frame(self) -> Frame | FrameError | None:
        """The next intact frame, a FrameError for a damaged one, or None for more bytes."""
        buf = self._buf
        while True:
            start = self._pos
            end = buf.find(0, start)
            if end < 0:
                return self._wait(start)
            self._pos = end + 1
            size = end - start
            if self._discarding:
                # The tail of an oversize frame already reported: drop it quietly.
                self._discarding = False
                self.stats.bytes_discarded += size
                continue
            if size == 0:
                continue
            if size > self._max_encoded:
                return self._error(
                    FrameErrorKind.OVERSIZE,
                    size,
                    f"{size} encoded bytes exceed {self._max_encoded}",
                )
            try:
                raw = cobs.decode(buf[start:end])
            except cobs.CobsDecodeError as error:
                return self._error(FrameErrorKind.COBS, size, str(error))
            return self._check(raw, size)

    def _wait(self, start: int) -> FrameError | None:
        pending = len(self._buf) - start
        if self._discarding:
            self.stats.bytes_discarded += pending
            self._buf.clear()
            self._pos = 0
            return None
        if pending > self._max_encoded:
            # No delimiter within the longest legal frame: report now, drop until the next 0x00.
            self._discarding = True
            self._buf.clear()
            self._pos = 0
            return self._error(
                FrameErrorKind.OVERSIZE, pending, f"no 0x00 within {self._max_encoded} bytes"
            )
        if start == len(self._buf):
            self._buf.clear()
            self._pos = 0
        elif start > _COMPACT_AT:
            del self._buf[:start]
            self._pos = 0
        return None

    def _check(self, raw: bytes, size: int) -> Frame | FrameError:
        n = len(raw)
        if n > self._max_frame_len:
            return self._error(
                FrameErrorKind.OVERSIZE, size, f"{n}-byte frame exceeds {self._max_frame_len}"
            )
        if n < _OVERHEAD:
            return self._error(
                FrameErrorKind.BAD_HEADER, size, f"{n}-byte frame is shorter than header + CRC"
            )
        body_end = n - CRC_SIZE
        expected = zlib.crc32(memoryview(raw)[:body_end], crc_seed(raw[2], self._schema_hash))
        got = int.from_bytes(raw[body_end:], "little")
        if got != expected:
            return self._error(
                FrameErrorKind.CRC,
                size,
                f"CRC 0x{got:08x} != 0x{expected:08x} (type 0x{raw[2]:02x})",
            )
        major, minor, type_id, flags, seq, length = HEADER.unpack_from(raw)
        if length != body_end - HEADER_SIZE:
            return self._error(
                FrameErrorKind.BAD_HEADER,
                size,
                f"payload_length {length} != {body_end - HEADER_SIZE} bytes in the frame",
            )
        self.stats.frames_ok += 1
        return Frame(major, minor, type_id, flags, seq, raw[HEADER_SIZE:body_end])

    def _error(self, kind: FrameErrorKind, size: int, detail: str) -> FrameError:
        counter = {
            FrameErrorKind.COBS: "cobs_errors",
            FrameErrorKind.OVERSIZE: "oversize_frames",
            FrameErrorKind.CRC: "crc_errors",
            FrameErrorKind.BAD_HEADER: "bad_headers",
        }[kind]
        setattr(self.stats, counter, getattr(self.stats, counter) + 1)
        self.stats.bytes_discarded += size
        return FrameError(kind, size, detail)
