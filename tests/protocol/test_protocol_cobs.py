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


def _zero_rich_bytes() -> st.SearchStrategy[bytes]:
    """Bytes with runs of zeros and of 253–256 non-zero bytes: every block-boundary case."""
    piece = st.one_of(
        st.binary(max_size=40),
        st.integers(0, 30).map(lambda n: b"\x00" * n),
        st.integers(250, 260).map(lambda n: bytes([7]) * n),
    )
    return st.lists(piece, max_size=30).map(b"".join)


@settings(max_examples=300, deadline=None)
@given(_zero_rich_bytes())
def test_cobs_compiled_loops_give_the_pure_bytes(data: bytes) -> None:
    pure = cobs._encode_pure(data)
    assert cobs._encode_compiled(data) == pure
    assert cobs._decode_compiled(pure) == cobs._decode_pure(pure) == data


def test_cobs_compiled_path_is_taken_from_its_threshold() -> None:
    assert cobs.kernels is not None  # numba is a runtime dependency
    calls: list[int] = []
    real = cobs.kernels.decode_into

    def spy(src: np.ndarray, dst: np.ndarray) -> int:
        calls.append(src.size)
        return int(real(src, dst))

    n = cobs.COMPILED_MIN_BYTES
    small, large = cobs.encode(b"\x05" * (n - 10)), cobs.encode(b"\x00\x05" * n)
    try:
        cobs.kernels.decode_into = spy  # type: ignore[assignment]
        assert cobs.decode(small) == b"\x05" * (n - 10)
        assert cobs.decode(large) == b"\x00\x05" * n
    finally:
        cobs.kernels.decode_into = real  # type: ignore[assignment]
    assert calls == [len(large)]


_WARM_SCRIPT = """
import json
from firmware_protocol import cobs, cobs_kernels as k

def counts():
    return {f.py_func.__name__: len(f.signatures) for f in (k.decode_into, k.encode_into)}

cobs.warm_up()
before = counts()
frame = bytes(range(1, 256)) * 4 + bytes(300)  # over the compiled threshold, zeros inside
for data in (frame, bytearray(frame)):
    enc = cobs.encode(data)
    assert cobs.decode(enc) == frame
    assert cobs.decode(bytearray(enc)) == frame
print(json.dumps({"before": before, "after": counts()}))
"""


@pytest.mark.slow
def test_cobs_warm_up_loads_every_version_a_driver_calls() -> None:
    # A read-only source (np.frombuffer over bytes) is another numba type: before warm_up
    # covered it, the tank run's first read-only frame compiled mid-stream (0.12 s on a
    # fresh checkout, GIL held). A fresh interpreter shows what streaming adds.
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    done = subprocess.run(
        [sys.executable, "-c", _WARM_SCRIPT],
        capture_output=True, text=True, cwd=root, timeout=300, check=True,
    )  # fmt: skip
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["before"] == {"decode_into": 2, "encode_into": 2}
    assert result["after"] == result["before"]


@pytest.mark.parametrize("zero_fraction", [0.0, 0.01, 0.3, 0.9, 1.0])
def test_cobs_dense_and_sparse_paths_agree_with_the_oracle(zero_fraction: float) -> None:
    rng = np.random.default_rng(11)
    for n in (0, 1, 253, 254, 255, 600, 4096, 8192):
        values = rng.integers(1, 256, n)
        values[rng.random(n) < zero_fraction] = 0
        data = values.astype(np.uint8).tobytes()
        encoded = cobs.encode(data)
        assert encoded == cobs._encode_pieces(data) == cobs._encode_pure(data)
        assert cobs.decode(encoded) == data == reference_decode(encoded)
        assert cobs._decode_pure(encoded) == data


def test_cobs_numpy_tail_walk_handles_0xff_blocks_after_short_ones() -> None:
    # Many zeros first (switches to the numpy walk), then long runs (0xFF blocks).
    data = b"\x00\x05" * 400 + bytes(range(1, 256)) * 3 + b"\x00" + b"\x07" * 600
    encoded = cobs.encode(data)
    assert cobs._decode_pure(encoded) == data == reference_decode(encoded)


def test_cobs_decode_errors_name_the_problem() -> None:
    with pytest.raises(cobs.CobsDecodeError, match="empty COBS frame"):
        cobs.decode(b"")
    with pytest.raises(cobs.CobsDecodeError, match="0x00 inside a COBS frame at offset 1"):
        cobs.decode(b"\x02\x00")
    with pytest.raises(cobs.CobsDecodeError, match=r"offset 2 \(code 0x09\) runs 6 bytes past"):
        cobs.decode(b"\x02\x11\x09\x01\x01")
    # Long and zero-dense: the compiled loop and the numpy walk find the overrunning block.
    truncated = cobs.encode(b"\x00\x01" * 800) + b"\x40"
    message = r"offset 1601 \(code 0x40\) runs 63 bytes past the end of the 1602-byte frame"
    with pytest.raises(cobs.CobsDecodeError, match=message):
        cobs.decode(truncated)
    with pytest.raises(cobs.CobsDecodeError, match=message):
        cobs._decode_pure(truncated)
