"""Read a WAV file's samples block by block: RIFF, RIFX (big-endian) and RF64 (EBU Tech 3306)
files of PCM integer (1 to 64 bits) or IEEE float (32 or 64 bits) samples, plain or inside
``WAVE_FORMAT_EXTENSIBLE``, one or more channels.

Samples come back in the types :func:`scipy.io.wavfile.read` gives, so the two agree value
for value (tested on every format): 8 bits or fewer as ``uint8`` (offset binary, 128 is
zero); 16 bits as ``int16``; 24 and 32 bits as ``int32``; up to 64 bits as ``int64``;
floats as ``float32`` or ``float64``. An integer sample of a 3-, 5-, 6- or 7-byte container
is left-justified in the next wider type (24-bit ``0x123456`` is the ``int32``
``0x12345600``), so the full scale of ``b``-byte storage is ``2**(8 b - 1)`` whatever
the container. Blocks have shape ``(n,)`` for one channel and ``(n, channels)`` otherwise.

Written here so that reading the input of ``hil estimate`` imports no ``scipy.io`` (0.3 s of
CPU in a fresh interpreter, 0.035 s once numba has imported ``scipy.linalg``); only the
header is parsed in Python, the samples are converted with NumPy a block at a time.

Examples
--------
>>> import tempfile, pathlib, numpy as np
>>> from scipy.io import wavfile
>>> folder = tempfile.TemporaryDirectory()
>>> path = pathlib.Path(folder.name) / "two.wav"
>>> wavfile.write(path, 48_000, np.array([[1, -2], [3, -4], [5, -6]], dtype=np.int16))
>>> layout = read_wav_layout(path)
>>> layout.fs_hz, layout.n_channels, layout.n_frames, layout.dtype.str
(48000, 2, 3, '<i2')
>>> [b.tolist() for b in wav_blocks(path, layout, block=2)]
[[[1, -2], [3, -4]], [[5, -6]]]
>>> folder.cleanup()
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError

PCM = 0x0001
IEEE_FLOAT = 0x0003
EXTENSIBLE = 0xFFFE

#: Format tags a user may meet, named in the error that refuses them.
_FORMAT_NAMES = {
    0x0002: "Microsoft ADPCM",
    0x0006: "A-law",
    0x0007: "mu-law",
    0x0011: "IMA ADPCM",
    0x0031: "GSM 6.10",
    0x0050: "MPEG",
    0x0055: "MPEG layer 3",
}

#: The last 12 bytes of a KSDATAFORMAT_SUBTYPE GUID whose first 4 bytes are a format tag
#: (RFC 2361 template {XXXXXXXX-0000-0010-8000-00AA00389B71}), as stored little-endian.
_GUID_TAIL = b"\x00\x00\x10\x00\x80\x00\x00\xaa\x00\x38\x9b\x71"

_CONVERT_HINT = "convert it to PCM or float WAV, e.g. sox in.wav -e signed-integer out.wav"


@dataclass(frozen=True)
class WavLayout:
    """Where a WAV file's samples are and how they are stored.

    ``fs_hz`` sample rate (Hz); ``n_channels``; ``n_frames`` samples per channel;
    ``container_bytes`` bytes per stored sample (``block_align / n_channels``);
    ``bits_per_sample`` significant bits; ``is_float`` IEEE float (else PCM integer);
    ``big_endian`` RIFX; ``data_offset`` byte offset of the first sample in the file.
    """

    fs_hz: int
    n_channels: int
    n_frames: int
    container_bytes: int
    bits_per_sample: int
    is_float: bool
    big_endian: bool
    data_offset: int

    @property
    def block_align(self) -> int:
        """Bytes per frame (one sample of every channel)."""
        return self.container_bytes * self.n_channels

    @property
    def dtype(self) -> np.dtype[np.generic]:
        """NumPy type of the samples :func:`wav_blocks` yields (the file's byte order)."""
        order = ">" if self.big_endian else "<"
        if self.is_float:
            return np.dtype(f"{order}f{self.container_bytes}")
        if self.bits_per_sample <= 8:
            return np.dtype("u1")
        return np.dtype(f"{order}i{_wider(self.container_bytes)}")


def _wider(container_bytes: int) -> int:
    """Bytes of the NumPy integer holding a container of ``container_bytes`` (1 to 8)."""
    return next(size for size in (1, 2, 4, 8) if size >= container_bytes)


def read_wav_layout(path: Path | str, field: str = "path") -> WavLayout:
    """Parse the header of the WAV file ``path``: where its samples are and their format.

    ``field`` names the setting that gave ``path`` in the errors (``"--input"``). Raises
    :class:`~hil.errors.ConfigError` naming the file, what was found and what to do for a
    missing file, a file that is not a WAV, an unsupported sample format, an inconsistent
    header, or a data chunk the file is too short to hold (a cut recording).
    """
    name = str(path)
    try:
        with open(path, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            return _parse(fh, size, name, field)
    except FileNotFoundError:
        raise ConfigError(field, name, "an existing WAV file") from None
    except IsADirectoryError:
        raise ConfigError(field, name, "a WAV file, not a folder") from None
    except OSError as exc:  # no permission, an I/O error
        raise ConfigError(field, name, f"a readable WAV file ({exc.strerror})") from None


def _bad(field: str, name: str, allowed: str, hint: str = "") -> ConfigError:
    return ConfigError(field, name, allowed, hint)


def _read_exact(fh: BinaryIO, n: int, what: str, field: str, name: str) -> bytes:
    """``n`` bytes of ``what``; a truncated-file error when the file ends first."""
    raw = fh.read(n)
    if len(raw) < n:
        raise _bad(
            field,
            name,
            f"a complete WAV file: it ends inside its {what} ({len(raw)} of {n} bytes)",
            "the file was cut short; record or copy it again",
        )
    return raw


def _parse(fh: BinaryIO, file_size: int, name: str, field: str) -> WavLayout:
    head = fh.read(12)
    if len(head) < 12:
        raise _bad(
            field,
            name,
            f"a WAV file: it holds {len(head)} bytes, fewer than the 12 of a RIFF header",
            "record or copy it again",
        )
    riff, form = head[:4], head[8:12]
    if riff not in (b"RIFF", b"RIFX", b"RF64") or form != b"WAVE":
        raise _bad(
            field,
            name,
            f"a WAV file (RIFF, RIFX or RF64 of form WAVE): it begins with {head[:4]!r} and "
            f"its form is {form!r}",
            "convert it to WAV, e.g. sox in.flac out.wav",
        )
    order = ">" if riff == b"RIFX" else "<"
    rf64_data_size: int | None = None
    if riff == b"RF64":
        chunk = _read_exact(fh, 8, "ds64 chunk header", field, name)
        ds64_size = struct.unpack("<I", chunk[4:])[0]
        if chunk[:4] != b"ds64" or ds64_size < 24:
            raise _bad(
                field,
                name,
                f"an RF64 file whose first chunk is a ds64 of at least 24 bytes (it is "
                f"{chunk[:4]!r} of {ds64_size} bytes)",
                "the header is damaged; rewrite it, e.g. sox in.wav out.wav",
            )
        body = _read_exact(fh, ds64_size + ds64_size % 2, "ds64 chunk", field, name)
        rf64_data_size = struct.unpack("<Q", body[8:16])[0]
    fmt: tuple[int, int, int, int, int] | None = None
    while True:
        chunk = fh.read(8)
        if len(chunk) < 8:
            missing = "fmt" if fmt is None else "data"
            raise _bad(
                field,
                name,
                f"a WAV file with a {missing} chunk: the file ends after {fh.tell()} bytes "
                "without one",
                "the file is damaged or cut short; record or copy it again",
            )
        chunk_id = chunk[:4]
        chunk_size = struct.unpack(order + "I", chunk[4:])[0]
        if chunk_id == b"fmt ":
            body = _read_exact(fh, chunk_size + chunk_size % 2, "fmt chunk", field, name)
            fmt = _format(body[:chunk_size], order, field, name)
        elif chunk_id == b"data":
            if fmt is None:
                raise _bad(
                    field,
                    name,
                    "a WAV file whose fmt chunk comes before its data chunk",
                    "rewrite the file, e.g. sox in.wav out.wav",
                )
            if rf64_data_size is not None and chunk_size == 0xFFFFFFFF:
                chunk_size = rf64_data_size
            return _layout(fmt, chunk_size, fh.tell(), file_size, order, field, name)
        else:
            fh.seek(chunk_size + chunk_size % 2, os.SEEK_CUR)


def _format(body: bytes, order: str, field: str, name: str) -> tuple[int, int, int, int, int]:
    """(format tag, channels, fs Hz, block align, bits per sample) of a fmt chunk's body."""
    if len(body) < 16:
        raise _bad(
            field,
            name,
            f"a WAV file whose fmt chunk holds at least 16 bytes (it holds {len(body)})",
            "the header is damaged; rewrite it, e.g. sox in.wav out.wav",
        )
    tag, channels, fs, _, block_align, bits = struct.unpack(order + "HHIIHH", body[:16])
    if tag == EXTENSIBLE:
        if len(body) < 40:
            raise _bad(
                field,
                name,
                f"a WAVE_FORMAT_EXTENSIBLE fmt chunk of at least 40 bytes (it holds {len(body)})",
                "the header is damaged; rewrite it, e.g. sox in.wav out.wav",
            )
        guid = body[24:40]
        tail = _GUID_TAIL if order == "<" else _GUID_TAIL[:2] + _GUID_TAIL[3:1:-1] + _GUID_TAIL[4:]
        if guid[4:] != tail:
            raise _bad(
                field,
                name,
                f"PCM or IEEE float samples; its WAVE_FORMAT_EXTENSIBLE sub-format GUID "
                f"{guid.hex()} is neither",
                _CONVERT_HINT,
            )
        tag = struct.unpack(order + "I", guid[:4])[0]
    if tag not in (PCM, IEEE_FLOAT):
        known = _FORMAT_NAMES.get(tag, "unknown")
        raise _bad(
            field,
            name,
            f"PCM (format 1) or IEEE float (format 3) samples; its format is {tag:#06x} ({known})",
            _CONVERT_HINT,
        )
    return tag, channels, fs, block_align, bits


def _layout(
    fmt: tuple[int, int, int, int, int],
    data_size: int,
    data_offset: int,
    file_size: int,
    order: str,
    field: str,
    name: str,
) -> WavLayout:
    tag, channels, fs, block_align, bits = fmt
    what = f"{channels} channel(s), block align {block_align} bytes, {bits} bits per sample"
    if channels < 1 or fs < 1 or block_align < channels or block_align % channels:
        raise _bad(
            field,
            name,
            "a WAV header with at least one channel, a sample rate > 0 Hz and a block align "
            f"that is a whole number of bytes per channel ({what}, {fs} Hz)",
            "the header is damaged; rewrite it, e.g. sox in.wav out.wav",
        )
    container = block_align // channels
    is_float = tag == IEEE_FLOAT
    if is_float:
        ok = (bits, container) in ((32, 4), (64, 8))
        allowed = "32- or 64-bit float samples in 4- or 8-byte containers"
    else:
        ok = 1 <= bits <= 8 * container and container <= 8 and (bits > 8 or container == 1)
        allowed = (
            "integer samples of 1 to 64 bits in containers of 1 to 8 bytes (8 bits or fewer "
            "in 1 byte)"
        )
    if not ok:
        raise _bad(field, name, f"{allowed} ({what})", _CONVERT_HINT)
    available = file_size - data_offset
    if data_size > available:
        raise _bad(
            field,
            name,
            f"a complete WAV file: its data chunk declares {data_size} bytes but the file "
            f"holds {available} after the header",
            "the recording was cut short; record it again, or rewrite the header to what "
            "is there, e.g. sox --ignore-length in.wav out.wav",
        )
    return WavLayout(
        fs_hz=fs,
        n_channels=channels,
        n_frames=data_size // block_align,
        container_bytes=container,
        bits_per_sample=bits,
        is_float=is_float,
        big_endian=order == ">",
        data_offset=data_offset,
    )


def frames_from_bytes(raw: bytes, layout: WavLayout) -> NDArray[np.generic]:
    """Whole frames of ``raw`` (bytes as stored) as samples of ``layout.dtype``: shape
    ``(n,)`` for one channel, ``(n, channels)`` otherwise."""
    n = len(raw) // layout.block_align
    raw = raw[: n * layout.block_align]
    dtype = layout.dtype
    if layout.container_bytes == dtype.itemsize:
        samples = np.frombuffer(raw, dtype=dtype)
    else:  # 3-, 5-, 6- or 7-byte integers: left-justify the stored bytes in a wider integer
        stored = np.frombuffer(raw, dtype=np.uint8).reshape(-1, layout.container_bytes)
        wide = np.zeros((stored.shape[0], dtype.itemsize), dtype=np.uint8)
        if layout.big_endian:
            wide[:, : layout.container_bytes] = stored
        else:
            wide[:, -layout.container_bytes :] = stored
        samples = wide.view(dtype).reshape(-1)
    return samples if layout.n_channels == 1 else samples.reshape(n, layout.n_channels)


def wav_blocks(
    path: Path | str, layout: WavLayout, block: int = 1 << 16
) -> Iterator[NDArray[np.generic]]:
    """The samples of ``path`` (whose header is ``layout``), ``block`` frames at a time
    (the last block shorter); the file is open only while the iterator runs."""
    if block < 1:
        raise ConfigError("block", block, "at least 1 frame")
    with open(path, "rb") as fh:
        fh.seek(layout.data_offset)
        for start in range(0, layout.n_frames, block):
            count = min(block, layout.n_frames - start)
            yield frames_from_bytes(fh.read(count * layout.block_align), layout)
