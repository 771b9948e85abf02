"""Streamed float32 mono WAV files of any length: RIFF up to 4 GiB, RF64 (EBU Tech 3306) above.

A RIFF chunk size is a 32-bit field, so a plain WAV cannot describe more than 4 GiB of data;
above that the header is RF64 (``RF64`` + a ``ds64`` chunk holding the 64-bit sizes, the
32-bit fields set to 0xFFFFFFFF), which SciPy, libsndfile and sox read.

>>> import io, numpy as np
>>> from scipy.io import wavfile
>>> buf = io.BytesIO()
>>> write_float_wav(buf, lambda start, n: np.arange(start, start + n, dtype=np.float32),
...                 10, 1000, block=4, rf64_above=0)
>>> _ = buf.seek(0)
>>> fs, x = wavfile.read(buf)
>>> int(fs), x.tolist() == list(range(10)), buf.getvalue()[:4]
(1000, True, b'RF64')
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

U32_MAX = 0xFFFFFFFF
BYTES_PER_SAMPLE = 4
_HEADER_BYTES = 12 + 8 + 18 + 8 + 4 + 8  # RIFF/WAVE, fmt (18), fact (4), data header
RF64_ABOVE = U32_MAX - _HEADER_BYTES
"""Data sizes (bytes) above this are written as RF64."""

Render = Callable[[int, int], NDArray[np.float32]]
"""``render(start, count)``: samples ``start .. start + count - 1`` as float32."""


def wav_bytes(n_samples: int) -> int:
    """Size (bytes) of the file :func:`write_float_wav` writes for ``n_samples``."""
    data = BYTES_PER_SAMPLE * n_samples
    return data + _HEADER_BYTES + (36 if data > RF64_ABOVE else 0)


def _header(n_samples: int, fs: int, rf64: bool) -> bytes:
    data = BYTES_PER_SAMPLE * n_samples
    fmt = b"fmt " + struct.pack("<IHHIIHHH", 18, 3, 1, fs, fs * 4, 4, 32, 0)
    fact_samples = U32_MAX if rf64 else n_samples
    fact = b"fact" + struct.pack("<II", 4, min(fact_samples, U32_MAX))
    if not rf64:
        riff = b"RIFF" + struct.pack("<I", 4 + len(fmt) + len(fact) + 8 + data) + b"WAVE"
        return riff + fmt + fact + b"data" + struct.pack("<I", data)
    ds64 = b"ds64" + struct.pack("<IQQQI", 28, 4 + 36 + len(fmt) + len(fact) + 8 + data,
                                 data, n_samples, 0)  # fmt: skip
    riff = b"RF64" + struct.pack("<I", U32_MAX) + b"WAVE"
    return riff + ds64 + fmt + fact + b"data" + struct.pack("<I", U32_MAX)


def write_float_wav(
    fh: BinaryIO,
    render: Render,
    n_samples: int,
    fs: int,
    *,
    block: int = 1 << 20,
    rf64_above: int = RF64_ABOVE,
) -> None:
    """Write ``n_samples`` from ``render`` to the open binary file ``fh``, ``block`` at a time.

    ``rf64_above``: data sizes (bytes) above it get an RF64 header (tests lower it).
    """
    rf64 = BYTES_PER_SAMPLE * n_samples > rf64_above
    fh.write(_header(n_samples, fs, rf64))
    done = 0
    while done < n_samples:
        count = min(block, n_samples - done)
        fh.write(np.asarray(render(done, count), dtype="<f4").tobytes())
        done += count
