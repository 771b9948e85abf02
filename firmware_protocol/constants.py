"""Wire constants of protocol 2.0: version, header and CRC sizes, frame limits, flag bits.

Every size is in bytes. ``SPEC.md`` states the same numbers for firmware authors.
"""

from __future__ import annotations

from typing import Final

PROTOCOL_MAJOR: Final = 2
"""Major version: peers must agree on it exactly. 2 = SPEC v2 (device behaviour and timing:
refusal rules, HELLO restarts a session, DAC data by index, latched alarms).
"""
PROTOCOL_MINOR: Final = 0
"""Minor version: may differ between peers (later minors only add optional things)."""

HEADER_SIZE: Final = 8
"""Frame header: major u8, minor u8, type u8, flags u8, seq u16, payload_length u16."""
CRC_SIZE: Final = 4
"""CRC-32 trailer after the payload."""
MAX_FRAME_LEN: Final = 8192
"""Largest decoded frame (header + payload + CRC), bytes, before COBS encoding."""
MAX_PAYLOAD_LEN: Final = MAX_FRAME_LEN - HEADER_SIZE - CRC_SIZE
"""Largest payload, bytes (8180)."""
SEQ_MODULO: Final = 1 << 16
"""Sequence numbers are u16 and wrap from 65535 to 0."""

FLAG_OPTIONAL: Final = 0x01
"""Flags bit 0: a receiver that does not know this message type ignores it without a NAK."""

DAC_RUNS: Final = 64
"""Runs of consecutive queued DAC indices (gaps + 1) a device with a bounded gap queue holds
at least: a host that keeps at most this many runs queued never gets NAK BUSY (SPEC 5.2
check 6(d)). The reference boards (C and Python) hold exactly this many."""

HANDSHAKE_CRC_SEED: Final = 0
"""CRC seed of HELLO and VERSION frames (plain CRC-32), so peers built from other definitions
can still tell each other their versions."""


def max_encoded_len(decoded_len: int) -> int:
    """Largest COBS encoding of ``decoded_len`` bytes, without the 0x00 delimiter (bytes).

    >>> max_encoded_len(MAX_FRAME_LEN)
    8225
    """
    return decoded_len + decoded_len // 254 + 1
