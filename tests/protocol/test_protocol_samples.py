"""Sample payload helpers: int16 / int24 / float32 interleaving, sign extension, errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from firmware_protocol import FieldValueError, SampleFormat, pack_samples, unpack_samples


def test_int24_golden_bytes_and_sign_extension() -> None:
    values = np.array([[1, -1], [8388607, -8388608], [256, -256]])
    data = pack_samples(values, SampleFormat.INT24)
    assert data.hex() == "010000ffffffffff7f000080000100" + "00ffff"
    back = unpack_samples(data, 2, SampleFormat.INT24)
    assert back.dtype == np.int32
    np.testing.assert_array_equal(back, values)


def test_int16_and_float32_are_interleaved_little_endian() -> None:
    assert pack_samples(np.array([[1, 2], [3, -2]], dtype=np.int16), 1).hex() == (
        "010002000300feff"
    )
    assert pack_samples(np.array([[0.5, -1.0]]), SampleFormat.FLOAT32).hex() == "0000003f000080bf"


@settings(max_examples=150, deadline=None)
@given(
    st.sampled_from(list(SampleFormat)),
    hnp.array_shapes(min_dims=2, max_dims=2, max_side=40),
    st.integers(0, 2**32 - 1),
)
def test_pack_unpack_round_trip(fmt: SampleFormat, shape: tuple[int, int], seed: int) -> None:
    rng = np.random.default_rng(seed)
    values: np.ndarray
    if fmt is SampleFormat.FLOAT32:
        values = rng.uniform(-1, 1, shape).astype(np.float32)
    else:
        bits = 16 if fmt is SampleFormat.INT16 else 24
        values = rng.integers(-(1 << (bits - 1)), 1 << (bits - 1), shape)
    data = pack_samples(values, fmt)
    assert len(data) == values.size * fmt.size
    np.testing.assert_array_equal(unpack_samples(data, shape[1], fmt), values)


def test_pack_rejects_out_of_range_and_wrong_dtype() -> None:
    with pytest.raises(
        FieldValueError,
        match=r"samples = 8388608 is not allowed: must be -8388608 \.\. 8388607 for INT24",
    ):
        pack_samples(np.array([[8388608]]), SampleFormat.INT24)
    with pytest.raises(FieldValueError, match=r"samples = -32769 .* -32768 \.\. 32767 for INT16"):
        pack_samples(np.array([[-32769, 0]]), SampleFormat.INT16)
    with pytest.raises(
        FieldValueError, match=r"samples\.dtype = 'float64' .* integer dtype for INT16"
    ):
        pack_samples(np.zeros((2, 1)), SampleFormat.INT16)
    with pytest.raises(
        FieldValueError, match=r"samples.shape = \(4,\) .* 2-D \(frames, channels\)"
    ):
        pack_samples(np.zeros(4, dtype=np.int16), SampleFormat.INT16)
    with pytest.raises(FieldValueError, match=r"sample_format = 7 .* one of 1 \(INT16\)"):
        pack_samples(np.zeros((1, 1), dtype=np.int16), 7)


def test_unpack_rejects_partial_frames() -> None:
    with pytest.raises(
        FieldValueError, match=r"len\(data\) = 5 .* multiple of 6 \(2 channels x 3 bytes INT24\)"
    ):
        unpack_samples(b"\x00" * 5, 2, SampleFormat.INT24)
