"""Pack and unpack sample blocks: numpy arrays (frames x channels) <-> interleaved bytes.

Bytes are little-endian and interleaved: frame 0 channel 0, frame 0 channel 1, ..., frame 1
channel 0, ... Channels are in ascending bit order of the channel mask. Everything is
vectorised; there is no per-sample Python code.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from firmware_protocol.enums import SampleFormat
from firmware_protocol.errors import FieldValueError

_INT_LIMITS = {
    SampleFormat.INT16: (-(1 << 15), (1 << 15) - 1),
    SampleFormat.INT24: (-(1 << 23), (1 << 23) - 1),
}


def channel_count(mask: int) -> int:
    """Number of channels selected by a channel bit mask.

    >>> channel_count(0b1011)
    3
    """
    return int(mask).bit_count()


def pack_samples(samples: npt.ArrayLike, sample_format: SampleFormat | int) -> bytes:
    """Interleave a (frames, channels) array into little-endian sample bytes.

    ``INT16`` and ``INT24`` take integer arrays within the format's range (full-scale
    counts); ``FLOAT32`` takes any real array (full scale is +-1.0) and rounds to binary32.
    Returns ``frames * channels * sample_format.size`` bytes.

    >>> pack_samples(np.array([[1, -1], [-8388608, 8388607]]), SampleFormat.INT24).hex(" ")
    '01 00 00 ff ff ff 00 00 80 ff ff 7f'
    """
    fmt = _format(sample_format)
    array = np.asarray(samples)
    if array.ndim != 2:
        raise FieldValueError(
            "samples.shape", array.shape, "2-D (frames, channels)", "reshape mono data to (n, 1)"
        )
    if fmt is SampleFormat.FLOAT32:
        if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
            raise FieldValueError("samples.dtype", str(array.dtype), "a real dtype", "")
        return np.ascontiguousarray(array, dtype="<f4").tobytes()
    if not np.issubdtype(array.dtype, np.integer):
        raise FieldValueError(
            "samples.dtype",
            str(array.dtype),
            f"an integer dtype for {fmt.name}",
            "scale to full-scale counts and round, or use FLOAT32",
        )
    low, high = _INT_LIMITS[fmt]
    if array.size and (int(array.min()) < low or int(array.max()) > high):
        bad = int(array.min()) if int(array.min()) < low else int(array.max())
        raise FieldValueError("samples", bad, f"{low} .. {high} for {fmt.name}", "clip first")
    if fmt is SampleFormat.INT16:
        return np.ascontiguousarray(array, dtype="<i2").tobytes()
    # INT24: the low three bytes of each little-endian int32.
    wide = np.ascontiguousarray(array, dtype="<i4").reshape(-1)
    return wide.view(np.uint8).reshape(-1, 4)[:, :3].tobytes()


def unpack_samples(
    data: bytes | memoryview, channels: int, sample_format: SampleFormat | int
) -> npt.NDArray[np.int16] | npt.NDArray[np.int32] | npt.NDArray[np.float32]:
    """Split interleaved sample bytes into a (frames, channels) array.

    Returns int16 for ``INT16``, int32 (sign-extended) for ``INT24`` and float32 for
    ``FLOAT32``, in native byte order. The length must be a whole number of frames.

    >>> unpack_samples(bytes.fromhex("010000ffffff000080ffff7f"), 2, SampleFormat.INT24)
    array([[       1,       -1],
           [-8388608,  8388607]], dtype=int32)
    """
    fmt = _format(sample_format)
    if channels < 1:
        raise FieldValueError("channels", channels, ">= 1", "")
    frame_bytes = channels * fmt.size
    if len(data) % frame_bytes:
        raise FieldValueError(
            "len(data)",
            len(data),
            f"a multiple of {frame_bytes} ({channels} channels x {fmt.size} bytes {fmt.name})",
            "check the channel mask and format",
        )
    if fmt is SampleFormat.INT16:
        return np.frombuffer(data, dtype="<i2").astype(np.int16).reshape(-1, channels)
    if fmt is SampleFormat.FLOAT32:
        return np.frombuffer(data, dtype="<f4").astype(np.float32).reshape(-1, channels)
    triples = np.frombuffer(data, dtype=np.uint8).reshape(-1, 3)
    wide = np.empty((triples.shape[0], 4), dtype=np.uint8)
    wide[:, 1:] = triples
    wide[:, 0] = 0
    # Placing the 3 bytes in the top of an int32 and shifting right arithmetically sign-extends.
    values = (wide.view("<i4").reshape(-1) >> 8).astype(np.int32)
    return values.reshape(-1, channels)


def _format(sample_format: SampleFormat | int) -> SampleFormat:
    try:
        return SampleFormat(sample_format)
    except ValueError:
        allowed = ", ".join(f"{f.value} ({f.name})" for f in SampleFormat)
        raise FieldValueError("sample_format", sample_format, f"one of {allowed}", "") from None
