"""COBS: published examples, canonical edge cases, round trips, dense/sparse paths, errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_protocol import cobs

# The examples of the Wikipedia article "Consistent Overhead Byte Stuffing" (without the
# trailing delimiter, which this module does not add).
WIKIPEDIA = [
    ("00", "01 01"),
    ("00 00", "01 01 01"),
    ("00 11 00", "01 02 11 01"),
    ("11 22 00 33", "03 11 22 02 33"),
    ("11 22 33 44", "05 11 22 33 44"),
    ("11 00 00 00", "02 11 01 01 01"),
]


def reference_decode(encoded: bytes) -> bytes:
    """Byte-at-a-time decoder straight from the algorithm description (test oracle)."""
    out = bytearray()
    i = 0
    while i < len(encoded):
        code = encoded[i]
        assert code != 0
        for k in range(1, code):
            out.append(encoded[i + k])
        i += code
        if code != 0xFF and i < len(encoded):
            out.append(0)
    return bytes(out)


@pytest.mark.parametrize(("decoded", "encoded"), WIKIPEDIA)
def test_cobs_wikipedia_examples(decoded: str, encoded: str) -> None:
    assert cobs.encode(bytes.fromhex(decoded)) == bytes.fromhex(encoded)
    assert cobs.decode(bytes.fromhex(encoded)) == bytes.fromhex(decoded)


def test_cobs_254_and_255_byte_runs_follow_the_canonical_form() -> None:
    run254 = bytes(range(1, 255))
    assert cobs.encode(run254) == b"\xff" + run254  # no trailing 0x01
    assert cobs.encode(b"\x00" + run254) == b"\x01\xff" + run254
    run255 = bytes(range(1, 256))
    assert cobs.encode(run255) == b"\xff" + run255[:254] + b"\x02\xff"
    assert cobs.encode(run254 + b"\x00") == b"\xff" + run254 + b"\x01\x01"
    for data in (run254, run255, run254 + b"\x00", b"\x00" + run254):
        assert cobs.decode(cobs.encode(data)) == data


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=2000))
def test_cobs_round_trip_and_no_zero(data: bytes) -> None:
    encoded = cobs.encode(data)
    assert 0 not in encoded
    assert len(encoded) <= len(data) + len(data) // 254 + 1
    assert cobs.decode(encoded) == data
    assert reference_decode(encoded) == data


@pytest.mark.parametrize("zero_fraction", [0.0, 0.01, 0.3, 0.9, 1.0])
def test_cobs_dense_and_sparse_paths_agree_with_the_oracle(zero_fraction: float) -> None:
    rng = np.random.default_rng(11)
    for n in (0, 1, 253, 254, 255, 600, 4096, 8192):
        values = rng.integers(1, 256, n)
        values[rng.random(n) < zero_fraction] = 0
        data = values.astype(np.uint8).tobytes()
        encoded = cobs.encode(data)
        assert encoded == cobs._encode_pieces(data)
        assert cobs.decode(encoded) == data == reference_decode(encoded)


def test_cobs_numpy_tail_walk_handles_0xff_blocks_after_short_ones() -> None:
    # Many zeros first (switches to the numpy walk), then long runs (0xFF blocks).
    data = b"\x00\x05" * 400 + bytes(range(1, 256)) * 3 + b"\x00" + b"\x07" * 600
    encoded = cobs.encode(data)
    assert cobs.decode(encoded) == data == reference_decode(encoded)


def test_cobs_decode_errors_name_the_problem() -> None:
    with pytest.raises(cobs.CobsDecodeError, match="empty COBS frame"):
        cobs.decode(b"")
    with pytest.raises(cobs.CobsDecodeError, match="0x00 inside a COBS frame at offset 1"):
        cobs.decode(b"\x02\x00")
    with pytest.raises(cobs.CobsDecodeError, match=r"offset 2 \(code 0x09\) runs 6 bytes past"):
        cobs.decode(b"\x02\x11\x09\x01\x01")
    # Long enough and zero-dense, so the numpy walk finds the overrunning block.
    truncated = cobs.encode(b"\x00\x01" * 800) + b"\x40"
    with pytest.raises(cobs.CobsDecodeError, match=r"\(code 0x40\) runs 63 bytes past the end"):
        cobs.decode(truncated)
