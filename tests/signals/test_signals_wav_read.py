"""The WAV reader (hil.signals.wav_read) against scipy.io.wavfile on every format it reads,
and its error for each kind of bad or cut file."""

from __future__ import annotations

import io
import struct
import tempfile
from pathlib import Path
from typing import Literal

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.io import wavfile

from hil.errors import ConfigError
from hil.signals.wav_read import WavLayout, read_wav_layout, wav_blocks
from hil.signals.wav_stream import write_float_wav

_GUID_TAIL = b"\x00\x00\x10\x00\x80\x00\x00\xaa\x00\x38\x9b\x71"


def _read_all(path: Path, block: int) -> tuple[WavLayout, np.ndarray]:
    layout = read_wav_layout(path)
    parts = list(wav_blocks(path, layout, block))
    shape = (0,) if layout.n_channels == 1 else (0, layout.n_channels)
    data = np.concatenate(parts, dtype=layout.dtype) if parts else np.zeros(shape, layout.dtype)
    return layout, data


def _same_as_scipy(path: Path, block: int) -> WavLayout:
    layout, ours = _read_all(path, block)
    fs, theirs = wavfile.read(path)
    assert layout.fs_hz == fs
    assert ours.dtype == theirs.dtype and ours.shape == theirs.shape
    assert np.array_equal(ours, theirs, equal_nan=ours.dtype.kind == "f")
    return layout


def _fmt_body(
    tag: int, channels: int, fs: int, container: int, bits: int, order: str, extensible: bool
) -> bytes:
    block_align = container * channels
    head = struct.pack(order + "HHIIHH", 0xFFFE if extensible else tag, channels, fs,
                       fs * block_align, block_align, bits)  # fmt: skip
    if not extensible:
        return head
    tail = _GUID_TAIL if order == "<" else _GUID_TAIL[:2] + _GUID_TAIL[3:1:-1] + _GUID_TAIL[4:]
    mask = (1 << channels) - 1
    return head + struct.pack(order + "HHII", 22, bits, mask, tag) + tail


def _chunk(chunk_id: bytes, body: bytes, order: str = "<", size: int | None = None) -> bytes:
    pad = b"\x00" * (len(body) % 2)
    return chunk_id + struct.pack(order + "I", len(body) if size is None else size) + body + pad


def _riff(chunks: bytes, order: str = "<") -> bytes:
    riff = b"RIFF" if order == "<" else b"RIFX"
    return riff + struct.pack(order + "I", 4 + len(chunks)) + b"WAVE" + chunks


def _write(path: Path, content: bytes) -> Path:
    path.write_bytes(content)
    return path


@settings(max_examples=60, deadline=None)
@given(
    dtype=st.sampled_from(["u1", "i2", "i4", "i8", "f4", "f8"]),
    order=st.sampled_from(["<", ">"]),
    channels=st.integers(1, 4),
    frames=st.integers(0, 70),
    block=st.integers(1, 80),
    fs=st.integers(1, 400_000),
    data=st.data(),
)
def test_a_wav_scipy_writes_reads_back_as_scipy_reads_it(
    dtype: str, order: str, channels: int, frames: int, block: int, fs: int, data: st.DataObject
) -> None:
    """Round trip of every sample type scipy.io.wavfile writes (from arrays of either byte
    order), mono and multi-channel, cut into any block size."""
    dt = np.dtype(dtype if dtype == "u1" else order + dtype)
    shape = (frames,) if channels == 1 else (frames, channels)
    width: Literal[32, 64] = 32 if dt.itemsize == 4 else 64
    elements = st.floats(width=width, allow_nan=False) if dt.kind == "f" else None
    x = data.draw(hnp.arrays(dt, shape, elements=elements))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "x.wav"
        wavfile.write(path, fs, x)
        layout = _same_as_scipy(path, block)
        _, back = _read_all(path, block)
    assert np.array_equal(back, x) and layout.n_frames == frames


@settings(max_examples=60, deadline=None)
@given(
    container=st.integers(1, 8),
    bits_spare=st.integers(0, 7),
    float_size=st.sampled_from([0, 4, 8]),
    order=st.sampled_from(["<", ">"]),
    extensible=st.booleans(),
    channels=st.integers(1, 3),
    frames=st.integers(0, 40),
    block=st.integers(1, 50),
    seed=st.integers(0, 2**32 - 1),
    junk=st.binary(max_size=5),
)
def test_every_container_and_extensible_header_reads_as_scipy_reads_it(
    container: int,
    bits_spare: int,
    float_size: int,
    order: str,
    extensible: bool,
    channels: int,
    frames: int,
    block: int,
    seed: int,
    junk: bytes,
) -> None:
    """Files scipy cannot write: 24-bit and other odd containers (left-justified in the next
    wider integer), WAVE_FORMAT_EXTENSIBLE, an unknown chunk (odd-sized, padded) before the
    data; random stored bytes, so every bit pattern of a sample occurs."""
    if float_size:
        container, bits, tag = float_size, 8 * float_size, 3
    else:
        bits = 8 if container == 1 else 8 * container - bits_spare
        tag = 1
    stored = np.random.default_rng(seed).integers(0, 256, frames * channels * container)
    fmt = _fmt_body(tag, channels, 44_100, container, bits, order, extensible)
    body = _chunk(b"fmt ", fmt, order) + _chunk(b"LIST", junk, order)
    body += _chunk(b"data", stored.astype(np.uint8).tobytes(), order)
    with tempfile.TemporaryDirectory() as folder:
        path = _write(Path(folder) / "x.wav", _riff(body, order))
        layout = _same_as_scipy(path, block)
    assert (layout.container_bytes, layout.bits_per_sample) == (container, bits)
    assert layout.big_endian == (order == ">") and layout.is_float == bool(float_size)


def test_24_bit_samples_are_left_justified_in_int32(tmp_path: Path) -> None:
    """0x123456 and -2 (0xfffffe) stored in 3 bytes read as 0x12345600 and -512."""
    fmt = _fmt_body(1, 1, 8000, 3, 24, "<", False)
    data = _chunk(b"data", b"\x56\x34\x12\xfe\xff\xff")
    path = _write(tmp_path / "x.wav", _riff(_chunk(b"fmt ", fmt) + data))
    (block,) = wav_blocks(path, read_wav_layout(path))
    assert block.dtype == np.dtype("<i4") and block.tolist() == [0x12345600, -512]


def test_an_rf64_file_reads_its_64_bit_data_size(tmp_path: Path) -> None:
    """An RF64 file (the 32-bit data size is 0xFFFFFFFF; the ds64 chunk holds the size)."""
    path = tmp_path / "x.wav"
    with path.open("wb") as fh:
        write_float_wav(fh, lambda s, n: np.arange(s, s + n, dtype=np.float32), 9, 1000,
                        block=4, rf64_above=0)  # fmt: skip
    assert path.read_bytes()[:4] == b"RF64"
    layout = _same_as_scipy(path, 4)
    assert layout.n_frames == 9


def _fmt16(tag: int = 1, channels: int = 1, container: int = 2, bits: int = 16) -> bytes:
    return _chunk(b"fmt ", _fmt_body(tag, channels, 8000, container, bits, "<", False))


_GOOD_DATA = _chunk(b"data", b"\x00\x00" * 4)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"RIFF\x00", "a WAV file: it holds 5 bytes, fewer than the 12 of a RIFF header"),
        (
            b"OggS" + bytes(40),
            "a WAV file (RIFF, RIFX or RF64 of form WAVE): it begins with b'OggS'",
        ),
        (b"RIFF\x00\x00\x00\x00AVI " + bytes(8), "its form is b'AVI '"),
        (
            b"RF64\xff\xff\xff\xffWAVE" + _fmt16(),
            "first chunk is a ds64 of at least 24 bytes (it is b'fmt ' of 16 bytes)",
        ),
        (_riff(b""), "a WAV file with a fmt chunk: the file ends after 12 bytes without one"),
        (_riff(_fmt16()), "a WAV file with a data chunk: the file ends after 36 bytes"),
        (_riff(_GOOD_DATA + _fmt16()), "a WAV file whose fmt chunk comes before its data chunk"),
        (_riff(b"fmt \x10\x00\x00\x00\x01\x00"), "it ends inside its fmt chunk (2 of 16 bytes)"),
        (
            _riff(_chunk(b"fmt ", bytes(14)) + _GOOD_DATA),
            "fmt chunk holds at least 16 bytes (it holds 14)",
        ),
        (
            _riff(_chunk(b"fmt ", _fmt_body(1, 1, 8000, 2, 16, "<", True)[:30]) + _GOOD_DATA),
            "a WAVE_FORMAT_EXTENSIBLE fmt chunk of at least 40 bytes (it holds 30)",
        ),
        (
            _riff(
                _chunk(b"fmt ", _fmt_body(1, 1, 8000, 2, 16, "<", True)[:-1] + b"\x00") + _GOOD_DATA
            ),
            "its WAVE_FORMAT_EXTENSIBLE sub-format GUID 01000000000010008000",
        ),
        (
            _riff(_fmt16(tag=7, container=1, bits=8) + _GOOD_DATA),
            "PCM (format 1) or IEEE float (format 3) samples; its format is 0x0007 (mu-law); "
            "convert it to PCM or float WAV",
        ),
        (_riff(_fmt16(tag=0x1234) + _GOOD_DATA), "its format is 0x1234 (unknown)"),
        (_riff(_fmt16(channels=0) + _GOOD_DATA), "with at least one channel, a sample rate"),
        (
            _riff(_fmt16(tag=3) + _GOOD_DATA),
            "32- or 64-bit float samples in 4- or 8-byte containers (1 channel(s), block align 2 "
            "bytes, 16 bits per sample)",
        ),
        (_riff(_fmt16(bits=4) + _GOOD_DATA), "integer samples of 1 to 64 bits in containers"),
        (_riff(_fmt16(bits=17) + _GOOD_DATA), "(1 channel(s), block align 2 bytes, 17 bits"),
        (
            _riff(_fmt16() + _chunk(b"data", bytes(100), size=400)),
            "a complete WAV file: its data chunk declares 400 bytes but the file holds 100 after "
            "the header; the recording was cut short",
        ),
    ],
    ids=lambda value: value[:30] if isinstance(value, str) else "file",
)
def test_a_bad_or_cut_file_is_refused_saying_what_is_wrong(
    tmp_path: Path, content: bytes, message: str
) -> None:
    path = _write(tmp_path / "bad.wav", content)
    with pytest.raises(ConfigError) as caught:
        read_wav_layout(path, "--input")
    assert str(caught.value).startswith(f"--input = '{path}' is not allowed: must be ")
    assert message in str(caught.value)


def test_a_missing_file_or_a_folder_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"'.*nope\.wav' is not allowed: must be an existing"):
        read_wav_layout(tmp_path / "nope.wav")
    with pytest.raises(ConfigError, match="must be a WAV file, not a folder"):
        read_wav_layout(tmp_path)


def test_a_block_below_one_frame_is_refused(tmp_path: Path) -> None:
    buf = io.BytesIO()
    wavfile.write(buf, 8000, np.zeros(3, dtype=np.int16))
    path = _write(tmp_path / "x.wav", buf.getvalue())
    with pytest.raises(ConfigError, match="block = 0 is not allowed: must be at least 1 frame"):
        next(wav_blocks(path, read_wav_layout(path), 0))
