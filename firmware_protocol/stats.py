"""Counters of what the reader saw: good frames, each kind of damage, gaps, unknown types."""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass
class ProtocolStats:
    """Running counts for one receive direction; every field counts frames unless named bytes.

    A corrupt stretch of line between two delimiters counts once, under the first check it
    fails (COBS, then size, then CRC, then header).
    """

    bytes_received: int = 0
    frames_ok: int = 0
    """Frames that passed COBS, size, CRC and header checks."""
    cobs_errors: int = 0
    oversize_frames: int = 0
    """Longer than the maximum frame length (the bytes were dropped up to the next 0x00)."""
    crc_errors: int = 0
    bad_headers: int = 0
    """Shorter than header + CRC, or payload_length disagreeing with the frame length."""
    bytes_discarded: int = 0
    """Bytes of all frames that failed a check (encoded size, without delimiters)."""
    sequence_gaps: int = 0
    """Times the peer's sequence number jumped."""
    missed_frames: int = 0
    """Sum of the jumps: frames the peer sent that never arrived intact."""
    unknown_messages: int = 0
    remote_errors: int = 0
    """Intact frames whose content broke the protocol (RemoteProtocolError raised)."""
    stale_frames: int = 0
    """HOST: intact frames of the old session dropped between its HELLO and the VERSION."""

    @property
    def frame_errors(self) -> int:
        """All frames that failed a check: COBS + oversize + CRC + header."""
        return self.cobs_errors + self.oversize_frames + self.crc_errors + self.bad_headers

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict (for logs and JSON)."""
        return asdict(self)
