"""Fuzz: mutated frame streams never raise, lose no intact frame and count every bad one.

150 000 frames, 100 000 of them mutated (bit flips, zero bytes, deletions, insertions,
truncations), fed in random chunks. Seeded, so any failure reproduces.
"""

from __future__ import annotations

import numpy as np
import pytest

from firmware_protocol import (
    NEED_DATA,
    AdcData,
    Configure,
    Connection,
    Frame,
    FrameDecoder,
    FrameError,
    Role,
    SampleFormat,
    SequenceGap,
    State,
    encode_frame,
)

N_FRAMES = 150_000
N_MUTATED = 100_000


def _mutate(frame: bytes, rng: np.random.Generator) -> bytes:
    """Damage the content (never the trailing delimiter) so the frame cannot stay valid."""
    body = bytearray(frame[:-1])
    n = len(body)
    kind = int(rng.integers(0, 5))
    pos = int(rng.integers(0, n))
    if kind == 0:  # flip bits in up to three distinct bytes
        for p in rng.choice(n, min(n, int(rng.integers(1, 4))), replace=False):
            body[p] ^= int(rng.integers(1, 256))
    elif kind == 1:  # a stray delimiter inside the frame
        body[pos] = 0
    elif kind == 2:
        del body[pos]
    elif kind == 3:  # insertion strictly inside, so no intact frame hides behind it
        body.insert(int(rng.integers(1, n)), int(rng.integers(0, 256)))
    else:
        del body[int(rng.integers(1, n)) :]
    return bytes(body) + b"\x00"


def _build_stream(rng: np.random.Generator) -> tuple[bytes, np.ndarray]:
    lengths = rng.integers(0, 48, N_FRAMES)
    noise = rng.integers(0, 256, int(lengths.sum()), dtype=np.uint8).tobytes()
    mutated = np.zeros(N_FRAMES, dtype=bool)
    mutated[rng.choice(N_FRAMES, N_MUTATED, replace=False)] = True
    parts = []
    offset = 0
    for i in range(N_FRAMES):
        # The payload starts with the frame number so delivered frames can be identified.
        payload = i.to_bytes(4, "little") + noise[offset : offset + int(lengths[i])]
        offset += int(lengths[i])
        wire = encode_frame(0x31, payload, i & 0xFFFF)
        parts.append(_mutate(wire, rng) if mutated[i] else wire)
    return b"".join(parts), mutated


@pytest.mark.slow
def test_fuzz_mutated_streams() -> None:
    rng = np.random.default_rng(20240601)
    stream, mutated = _build_stream(rng)
    cuts = np.sort(rng.integers(0, len(stream), 20_000))
    decoder = FrameDecoder()
    # For every delivered frame: its number and the errors reported since the previous one.
    delivered: list[int] = []
    errors_before: list[int] = []
    errors = 0
    for chunk in np.split(np.frombuffer(stream, dtype=np.uint8), cuts):
        decoder.feed(chunk.tobytes())
        while (item := decoder.next_frame()) is not None:
            if isinstance(item, FrameError):
                errors += 1
            else:
                assert isinstance(item, Frame)
                delivered.append(int.from_bytes(item.payload[:4], "little"))
                errors_before.append(errors)
                errors = 0
    intact = np.flatnonzero(~mutated)
    # Every intact frame is delivered, in order, and nothing else is.
    np.testing.assert_array_equal(delivered, intact)
    # Every corrupt frame is counted, right where it was (resync within one frame).
    mutated_between = np.diff(np.concatenate(([-1], intact))) - 1
    assert np.all(np.asarray(errors_before) >= mutated_between)
    stats = decoder.stats
    assert stats.frames_ok == len(intact) == N_FRAMES - N_MUTATED
    assert stats.frame_errors == sum(errors_before) + errors >= N_MUTATED
    assert stats.bytes_received == len(stream)


def test_fuzz_a_lost_delimiter_costs_at_most_the_next_frame() -> None:
    frames = [encode_frame(0x31, bytes([i]) * 10, i) for i in range(5)]
    stream = frames[0] + frames[1][:-1] + frames[2] + frames[3] + frames[4]
    decoder = FrameDecoder()
    decoder.feed(stream)
    got = []
    while (item := decoder.next_frame()) is not None:
        got.append(item.seq if isinstance(item, Frame) else "error")
    assert got == [0, "error", 3, 4]


@pytest.mark.slow
def test_fuzz_connection_reports_missed_adc_frames_and_never_raises() -> None:
    rng = np.random.default_rng(7)
    host = Connection(Role.HOST)
    host.state = State.STREAMING  # start mid-stream: only reading matters here
    host.configuration = Configure(1_000_000, 1, 0b11, SampleFormat.INT16, SampleFormat.INT16)
    n, bad = 20_000, 0
    block = rng.integers(-3000, 3000, (64, 2)).astype(np.int16)
    wires = []
    for i in range(n):
        wire = encode_frame(
            AdcData.TYPE_ID,
            AdcData.from_array(64 * i, 0b11, SampleFormat.INT16, block).encode_payload(),
            i & 0xFFFF,
        )
        if rng.random() < 0.3 and i not in (0, n - 1):
            wire = _mutate(wire, rng)
            bad += 1
        wires.append(wire)
    host.receive_data(b"".join(wires))
    data = gaps = 0
    while (event := host.next_event()) is not NEED_DATA:
        if isinstance(event, AdcData):
            data += 1
        elif isinstance(event, SequenceGap):
            gaps += event.missed
    assert data == n - bad
    assert gaps == bad == host.stats.missed_frames
    assert host.stats.frame_errors >= bad
