"""Compiled COBS loops (numba): one pass over the bytes, for frames of sample data.

At the tank-board rate the host decodes about a thousand ADC frames a second. Sample data
is zero-dense (a small signal has many zero high bytes, silence is all zeros), so COBS blocks
are a few bytes long and any per-block Python step, or the vectorised pointer-doubling walk
(O(n log n) with numpy's per-call overhead), cost the reader thread about 0.15 of a core. A
compiled byte loop does the same in a few microseconds per frame, without holding the GIL.

Both kernels write into a caller-allocated ``uint8`` array and return the length written;
they never raise (the caller turns a negative result into
:class:`~firmware_protocol.cobs.CobsDecodeError` with the offending offset). The encoding is
the canonical one of :func:`firmware_protocol.cobs.encode` (bit-identical; tested).
Compiled with ``cache=True``; :func:`warm_up` loads (or on a fresh checkout compiles, about
a second) the machine code, so a driver can do it before streaming starts.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

_JIT: dict[str, Any] = {"cache": True, "nogil": True}


@numba.njit(**_JIT)
def decode_into(src: Any, dst: Any) -> int:
    """Decode the block chain ``src`` (uint8, shape ``(n,)``, no 0x00 byte) into ``dst``
    (uint8, shape ``(>= n,)``); the decoded length, or ``-(i + 1)`` when the block whose
    code byte is at offset ``i`` runs past the end."""
    n = src.shape[0]
    i = 0
    o = 0
    while i < n:
        code = int(src[i])
        j = i + code
        if j > n:
            return -(i + 1)
        for k in range(i + 1, j):
            dst[o] = src[k]
            o += 1
        if code != 0xFF and j < n:
            dst[o] = 0
            o += 1
        i = j
    return o


@numba.njit(**_JIT)
def encode_into(src: Any, dst: Any) -> int:
    """COBS-encode ``src`` (uint8, shape ``(n,)``) into ``dst`` (uint8, shape
    ``(>= n + n // 254 + 1,)``); the encoded length (no delimiter).

    A block is closed at a zero byte or after 254 data bytes; after 254 data bytes a new
    block is opened only if more data follows (canonical form: a trailing 254-byte run ends
    with its ``FF`` block, no extra ``01``).
    """
    n = src.shape[0]
    code_at = 0
    code = 1
    o = 1
    for i in range(n):
        b = src[i]
        if b == 0:
            dst[code_at] = code
            code_at = o
            o += 1
            code = 1
        else:
            dst[o] = b
            o += 1
            code += 1
            if code == 0xFF and i + 1 < n:
                dst[code_at] = code
                code_at = o
                o += 1
                code = 1
    dst[code_at] = code
    return o


def warm_up() -> None:
    """Load (or compile) both kernels now rather than inside the first large frame.

    Each for a writable and a read-only source (what ``np.frombuffer`` gives over ``bytes``):
    numba compiles one machine-code version per argument type, and read-only is another type.
    A version first needed mid-stream costs about 0.1 s to compile on a fresh checkout, with
    the GIL held (the driver's reader and writer threads wait), and milliseconds to load from
    the cache after.
    """
    out = np.empty(4, dtype=np.uint8)
    for one in (np.ones(1, dtype=np.uint8), np.frombuffer(b"\x01", dtype=np.uint8)):
        decode_into(one, out)
        encode_into(one, out)
