"""Consistent Overhead Byte Stuffing (Cheshire & Baker 1999), as in the ``cobs`` package.

The encoding holds no 0x00 byte, so 0x00 delimits frames on the wire. Each block starts with
a code byte ``c`` (1..255) followed by ``c - 1`` data bytes; a decoded 0x00 follows every block
except a block with code 0xFF and the last block. The encoder follows the canonical rule of
Wikipedia's examples (254 non-zero bytes at the end encode as ``FF`` + data, without a
trailing ``01``).

Both directions avoid per-byte Python loops. Frames of at least :data:`COMPILED_MIN_BYTES`
(sample data) go through the compiled one-pass loops of
:mod:`firmware_protocol.cobs_kernels` (numba) when numba is installed. Otherwise the encoder
splits at zero bytes with ``bytes.split`` (or places code bytes with numpy when zeros are
dense), and the decoder walks the block chain one block at a time (a slice per block),
switching to a vectorised pointer-doubling walk with numpy when blocks are short (zero-dense
data such as silence). All paths give the same bytes (tested against each other).
"""

from __future__ import annotations

from types import ModuleType

import numpy as np

from firmware_protocol.errors import RemoteProtocolError

try:  # numba is a runtime dependency of the testbench, not of the protocol itself
    from firmware_protocol import cobs_kernels as _kernels

    kernels: ModuleType | None = _kernels
except ImportError:  # pragma: no cover - exercised only where numba is missing
    kernels = None

# From this many bytes on, the compiled loop beats the pure-Python paths (its call costs a
# few microseconds of argument conversion).
COMPILED_MIN_BYTES = 256

# Below this many zero bytes the per-block loop beats numpy's fixed call overhead.
_DENSE_ZEROS = 48
# Blocks walked in Python before deciding whether the rest of the frame is zero-dense.
_PROBE_BLOCKS = 24
# Mean block length (bytes) under which the numpy walk is faster than the Python loop.
_SHORT_BLOCK = 40
# Fewest remaining bytes worth the numpy walk's fixed cost.
_NUMPY_TAIL = 512


def warm_up() -> None:
    """Load the compiled loops now (a no-op without numba): their first call in a process
    loads machine code from numba's cache (or compiles it on a fresh checkout, about a
    second), which a driver does before streaming rather than inside its first frame."""
    if kernels is not None:
        kernels.warm_up()


class CobsDecodeError(RemoteProtocolError):
    """The bytes between two delimiters are not a valid COBS encoding."""


def encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (no delimiter is added).

    >>> encode(b"\\x11\\x22\\x00\\x33").hex(" ")
    '03 11 22 02 33'
    >>> encode(b"\\x00").hex(" ")
    '01 01'
    >>> encode(b"").hex(" ")
    '01'
    """
    if kernels is not None and len(data) >= COMPILED_MIN_BYTES:
        return _encode_compiled(data)
    return _encode_pure(data)


def _encode_pure(data: bytes) -> bytes:
    """:func:`encode` without the compiled loop (where numba is missing; tests)."""
    if data.count(0) >= _DENSE_ZEROS:
        dense = _encode_dense(data)
        if dense is not None:
            return dense
    return _encode_pieces(data)


def _encode_compiled(data: bytes | bytearray) -> bytes:
    assert kernels is not None
    src = np.frombuffer(data, dtype=np.uint8)
    dst = np.empty(src.size + src.size // 254 + 1, dtype=np.uint8)
    return dst[: kernels.encode_into(src, dst)].tobytes()


def _encode_pieces(data: bytes) -> bytes:
    out = bytearray()
    pieces = data.split(b"\x00")
    last = len(pieces) - 1
    for k, piece in enumerate(pieces):
        n = len(piece)
        i = 0
        while n - i >= 254:
            out.append(0xFF)
            out += piece[i : i + 254]
            i += 254
        rest = n - i
        # A piece that ends exactly on a 254-byte block needs no extra code at the very end.
        if k < last or rest > 0 or n == 0:
            out.append(rest + 1)
            out += piece[i:]
    return bytes(out)


def _encode_dense(data: bytes) -> bytes | None:
    """Vectorised encoding when every zero-free run is short; None if a run needs splitting."""
    raw = np.frombuffer(data, dtype=np.uint8)
    n = raw.size
    zeros = np.flatnonzero(raw == 0)
    bounds = np.empty(zeros.size + 2, dtype=np.int64)
    bounds[0] = -1
    bounds[1:-1] = zeros
    bounds[-1] = n
    codes = np.diff(bounds)
    # A run of 254 followed by a zero needs an extra 0x01 block: leave that to the loop.
    if codes[:-1].max(initial=0) > 254 or codes[-1] > 255:
        return None
    out = np.empty(n + 1, dtype=np.uint8)
    out[1:] = raw
    out[bounds[:-1] + 1] = codes
    return out.tobytes()


def decode(encoded: bytes | bytearray) -> bytes:
    """Decode one COBS block chain (the bytes between two delimiters, without them).

    Raises :class:`CobsDecodeError` on an empty input, a 0x00 byte, or a block that runs
    past the end.

    >>> decode(bytes.fromhex("03 11 22 02 33"))
    b'\\x11"\\x003'
    >>> decode(bytes.fromhex("05 11 22"))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    firmware_protocol.cobs.CobsDecodeError: COBS block at offset 0 (code 0x05) runs 2 bytes past...
    """
    n = len(encoded)
    if n == 0:
        raise CobsDecodeError("empty COBS frame")
    if encoded.find(0) >= 0:
        raise CobsDecodeError(f"0x00 inside a COBS frame at offset {encoded.find(0)}")
    if kernels is not None and n >= COMPILED_MIN_BYTES:
        return _decode_compiled(encoded)
    return _decode_pure(encoded)


def _decode_compiled(encoded: bytes | bytearray) -> bytes:
    assert kernels is not None
    src = np.frombuffer(encoded, dtype=np.uint8)
    dst = np.empty(src.size, dtype=np.uint8)
    m = kernels.decode_into(src, dst)
    if m < 0:
        i = -m - 1
        code = int(src[i])
        raise CobsDecodeError(
            f"COBS block at offset {i} (code 0x{code:02x}) runs {i + code - src.size} bytes"
            f" past the end of the {src.size}-byte frame"
        )
    return dst[:m].tobytes()


def _decode_pure(encoded: bytes | bytearray) -> bytes:
    """:func:`decode` without the compiled loop (where numba is missing; tests)."""
    n = len(encoded)
    out = bytearray()
    i = 0
    blocks = 0
    while i < n:
        if blocks == _PROBE_BLOCKS and i < _SHORT_BLOCK * _PROBE_BLOCKS and n - i > _NUMPY_TAIL:
            # Short blocks so far and a long way to go: walk the rest with numpy.
            return bytes(out) + _decode_tail_numpy(encoded, i)
        code = encoded[i]
        j = i + code
        if j > n:
            raise CobsDecodeError(
                f"COBS block at offset {i} (code 0x{code:02x}) runs {j - n} bytes past"
                f" the end of the {n}-byte frame"
            )
        out += encoded[i + 1 : j]
        if code != 0xFF and j < n:
            out.append(0)
        i = j
        blocks += 1
    return bytes(out)


def _decode_tail_numpy(encoded: bytes | bytearray, start: int) -> bytes:
    """Decode ``encoded[start:]`` (``start`` is a code position) by pointer doubling.

    The code positions are the chain start, next(start), next(next(start)), ... where
    next(p) = p + code[p]. Doubling the jump table log2(chain length) times finds all of them
    with O(n log n) vectorised work instead of one Python step per block.
    """
    raw = np.frombuffer(encoded, dtype=np.uint8)
    n = raw.size
    jump = np.arange(n + 1, dtype=np.int64)
    jump[:n] += raw
    np.minimum(jump, n, out=jump)
    on_chain = np.zeros(n + 1, dtype=bool)
    front = np.array([start], dtype=np.int64)
    on_chain[start] = True
    while True:
        reached = jump[front]
        on_chain[reached] = True
        front = np.concatenate((front, reached))
        if jump[start] >= n:
            break
        jump = jump[jump]
    pos = np.flatnonzero(on_chain[:n])
    codes = raw[pos]
    end = int(pos[-1]) + int(codes[-1])
    if end > n:
        raise CobsDecodeError(
            f"COBS block at offset {int(pos[-1])} (code 0x{int(codes[-1]):02x}) runs"
            f" {end - n} bytes past the end of the {n}-byte frame"
        )
    # A zero before a block replaces its code byte unless the block before it was 0xFF.
    keep = np.ones(n, dtype=bool)
    keep[:start] = False
    keep[pos[0]] = False
    keep[pos[1:][codes[:-1] == 0xFF]] = False
    decoded = raw.copy()
    decoded[pos] = 0
    # The chunk from the Python walk ended at a block boundary with a pending zero (if any)
    # already appended, so the first code position here is dropped.
    return decoded[keep].tobytes()
