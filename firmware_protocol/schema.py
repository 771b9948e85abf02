"""The schema hash: CRC-32 of a canonical text of every message definition (MAVLink's
CRC_EXTRA idea, applied to the whole message set).

Non-handshake frames are CRC-seeded with this hash, so a peer built from other definitions
fails every CRC, and the hash is exchanged in HELLO/VERSION so the mismatch is reported by
name. The text covers the protocol major version, the header layout and, per message, its
type id, name, sender, optional flag, fields (name and wire type, in order) and tail rule. It
does not cover the minor version: a later minor only appends optional things, which are
listed as extensions and kept out of the hash.
"""

from __future__ import annotations

import zlib

from firmware_protocol.constants import PROTOCOL_MAJOR
from firmware_protocol.messages import MESSAGE_TYPES, Message

HEADER_LAYOUT = (
    ("protocol_major", "u8"),
    ("protocol_minor", "u8"),
    ("message_type", "u8"),
    ("flags", "u8"),
    ("seq", "u16"),
    ("payload_length", "u16"),
)
"""The frame header, in order; every frame starts with it."""


def message_line(cls: type[Message]) -> str:
    """One message's canonical definition line.

    >>> from firmware_protocol.messages import Sync
    >>> message_line(Sync)
    '0x31 SYNC device: sample_index u64, board_time_ns u64'
    """
    parts = [f"{f.name} {f.wire}" for f in cls.LAYOUT]
    if cls.TAIL is not None:
        parts.append(f"{cls.TAIL.name} [{cls.TAIL.rule}]")
    flags = " optional" if cls.OPTIONAL else ""
    head = f"0x{cls.TYPE_ID:02x} {cls.NAME} {cls.SENDER.name.lower()}{flags}:"
    return " ".join([head, ", ".join(parts)]) if parts else head


def canonical_text() -> str:
    """The text whose CRC-32 is the schema hash (ASCII, one ``\\n``-terminated line each)."""
    lines = [
        f"cas-hil firmware protocol {PROTOCOL_MAJOR}",
        "header: " + ", ".join(f"{name} {wire}" for name, wire in HEADER_LAYOUT),
        "trailer: crc32 u32",
    ]
    lines += [message_line(MESSAGE_TYPES[t]) for t in sorted(MESSAGE_TYPES)]
    return "".join(line + "\n" for line in lines)


def compute_schema_hash() -> int:
    """CRC-32 (zlib, seed 0) of :func:`canonical_text` as ASCII."""
    return zlib.crc32(canonical_text().encode("ascii"))


SCHEMA_HASH: int = compute_schema_hash()
"""The schema hash of this package's definitions (u32)."""


def layout_table(cls: type[Message]) -> str:
    """Markdown table of a payload layout (offset, size, type, field, allowed, notes).

    ``SPEC.md`` contains these tables verbatim; a test keeps them in step with the code.
    """
    rows = ["| offset | size | type | field | allowed | notes |", "|---|---|---|---|---|---|"]
    offset = 0
    for f in cls.LAYOUT:
        note = f.doc or (f"derived: {_DERIVED_NOTES[f.name]}" if f.derived else "")
        rows.append(f"| {offset} | {f.size} | {f.wire} | {f.name} | {f.allowed_text()} | {note} |")
        offset += f.size
    if cls.TAIL is not None:
        rows.append(f"| {offset} | var | bytes | {cls.TAIL.name} | | {cls.TAIL.rule} |")
    if not cls.LAYOUT and cls.TAIL is None:
        rows.append("| 0 | 0 | | (empty payload) | | |")
    return "\n".join(rows)


_DERIVED_NOTES = {
    "n_rates": "number of u32 rates in the tail",
    "sample_count": "sample frames in the tail",
    "text_len": "bytes of text in the tail",
    "detail_len": "bytes of detail text in the tail",
}
