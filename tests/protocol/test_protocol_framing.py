"""Frame decoder: any chunking, junk around frames, each kind of damage, CRC oracle."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from firmware_protocol import (
    PROTOCOL_MAJOR,
    SCHEMA_HASH,
    Frame,
    FrameDecoder,
    FrameError,
    FrameErrorKind,
    cobs,
    encode_frame,
)


def crc32_bitwise(data: bytes, seed: int) -> int:
    """The C routine of SPEC.md section 1.2, transcribed bit by bit (test oracle)."""
    c = seed ^ 0xFFFFFFFF
    for byte in data:
        c ^= byte
        for _ in range(8):
            c = (c >> 1) ^ (0xEDB88320 & -(c & 1))
    return c ^ 0xFFFFFFFF


def _frames(n: int, seed: int = 0) -> tuple[list[tuple[int, int, bytes]], bytes]:
    rng = np.random.default_rng(seed)
    items = []
    for seq in range(n):
        payload = rng.integers(0, 256, int(rng.integers(0, 300)), dtype=np.uint8).tobytes()
        items.append((0x30 + seq % 3, seq, payload))
    return items, b"".join(encode_frame(t, p, s) for t, s, p in items)


def _drain(decoder: FrameDecoder) -> list[Frame | FrameError]:
    out: list[Frame | FrameError] = []
    while (item := decoder.next_frame()) is not None:
        out.append(item)
    return out


def test_crc_matches_the_spec_routine_and_a_known_value() -> None:
    assert crc32_bitwise(b"123456789", 0) == 0xCBF43926  # the CRC-32 check value
    frame = cobs.decode(encode_frame(0x31, bytes(range(16)), 9)[:-1])
    assert int.from_bytes(frame[-4:], "little") == crc32_bitwise(frame[:-4], SCHEMA_HASH)
    hello = cobs.decode(encode_frame(0x01, b"\x01\x00abcd", 0)[:-1])
    assert (
        int.from_bytes(hello[-4:], "little")
        == zlib.crc32(hello[:-4])
        == crc32_bitwise(hello[:-4], 0)
    )


def test_header_bytes_are_little_endian_at_the_stated_offsets() -> None:
    frame = cobs.decode(encode_frame(0x22, b"\x10\x00\x00\x00", 0x1234, flags=1)[:-1])
    assert frame[:8] == bytes([PROTOCOL_MAJOR, 0, 0x22, 1, 0x34, 0x12, 4, 0])
    assert len(frame) == 8 + 4 + 4


@pytest.mark.parametrize("chunking", ["whole", "bytes", "random"])
def test_chunks_equal_whole(chunking: str) -> None:
    items, stream = _frames(60)
    decoder = FrameDecoder()
    got: list[Frame | FrameError] = []
    if chunking == "whole":
        decoder.feed(stream)
        got = _drain(decoder)
    else:
        rng = np.random.default_rng(5)
        i = 0
        while i < len(stream):
            step = 1 if chunking == "bytes" else int(rng.integers(1, 700))
            decoder.feed(stream[i : i + step])
            got += _drain(decoder)
            i += step
    assert [(f.type_id, f.seq, f.payload) for f in got if isinstance(f, Frame)] == items
    assert decoder.stats.frames_ok == 60 and decoder.stats.frame_errors == 0
    assert decoder.buffered == 0


def test_junk_around_frames_is_counted_and_skipped() -> None:
    items, _ = _frames(20, seed=1)
    rng = np.random.default_rng(2)
    stream = b""
    junk_count = 0
    for t, s, p in items:
        junk = rng.integers(1, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes()
        stream += junk + b"\x00" + encode_frame(t, p, s) + b"\x00\x00"
        junk_count += 1
    decoder = FrameDecoder()
    decoder.feed(stream)
    got = _drain(decoder)
    frames = [g for g in got if isinstance(g, Frame)]
    errors = [g for g in got if isinstance(g, FrameError)]
    assert [(f.type_id, f.seq, f.payload) for f in frames] == items
    assert len(errors) == junk_count == decoder.stats.frame_errors
    assert decoder.stats.bytes_discarded == sum(e.size for e in errors)


def test_each_kind_of_damage_is_reported_and_the_next_frame_survives() -> None:
    good = encode_frame(0x31, b"\x01" * 16, 1)
    raw = bytearray(cobs.decode(good[:-1]))
    flipped = bytearray(good)
    flipped[5] ^= 0x01 if flipped[5] != 0x01 else 0x03
    wrong_length = bytearray(raw)
    wrong_length[6] += 1
    wrong_length[-4:] = zlib.crc32(bytes(wrong_length[:-4]), SCHEMA_HASH).to_bytes(4, "little")
    cases = [
        (bytes(flipped), FrameErrorKind.CRC, "CRC 0x"),
        (b"\x05\x11\x22\x00", FrameErrorKind.COBS, "runs 2 bytes past the end"),
        (
            cobs.encode(b"\x01\x00\x31") + b"\x00",
            FrameErrorKind.BAD_HEADER,
            "3-byte frame is shorter",
        ),
        (
            cobs.encode(bytes(wrong_length)) + b"\x00",
            FrameErrorKind.BAD_HEADER,
            "payload_length 17 != 16",
        ),
        (b"\x01" * 9000 + b"\x00", FrameErrorKind.OVERSIZE, "exceed"),
        (cobs.encode(bytes(9000)) + b"\x00", FrameErrorKind.OVERSIZE, "exceed"),
    ]
    for damaged, kind, text in cases:
        decoder = FrameDecoder()
        decoder.feed(damaged + good)
        first, second = decoder.next_frame(), decoder.next_frame()
        assert isinstance(first, FrameError) and first.kind is kind and text in first.detail
        assert isinstance(second, Frame) and second.payload == b"\x01" * 16
        assert decoder.stats.frame_errors == 1 and decoder.stats.frames_ok == 1


def test_endless_bytes_without_a_delimiter_are_dropped_as_they_come() -> None:
    decoder = FrameDecoder()
    for _ in range(10):
        decoder.feed(b"\x07" * 4000)
        items = _drain(decoder)
        assert all(isinstance(i, FrameError) and i.kind is FrameErrorKind.OVERSIZE for i in items)
    assert decoder.stats.oversize_frames == 1
    assert decoder.buffered < 8300  # memory stays bounded
    decoder.feed(b"\x00" + encode_frame(0x31, b"ok", 3))
    last = _drain(decoder)
    assert len(last) == 1 and isinstance(last[0], Frame) and last[0].payload == b"ok"
    assert decoder.stats.bytes_discarded == 40000


def test_frames_of_another_schema_fail_the_crc() -> None:
    decoder = FrameDecoder()
    decoder.feed(encode_frame(0x31, b"x", 0, schema_hash=SCHEMA_HASH ^ 1))
    decoder.feed(encode_frame(0x01, b"\x01\x00abcd", 1, schema_hash=SCHEMA_HASH ^ 1))
    first, second = decoder.next_frame(), decoder.next_frame()
    assert isinstance(first, FrameError) and first.kind is FrameErrorKind.CRC
    assert isinstance(second, Frame)  # handshake frames use seed 0 whatever the schema
