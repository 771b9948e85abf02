"""Buffers a live loop fills are mapped when made: writing them through afterwards adds no
resident memory (no page faults mid-stream). Measured with the process's resident set
(Linux /proc/self/statm)."""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np
import pytest

from hil.acquisition import SampleRing
from hil.estimation.row_buffer import RowBuffer
from hil.resident_arrays import resident_zeros

pytestmark = pytest.mark.skipif(
    not os.path.exists("/proc/self/statm"), reason="resident memory is read from /proc/self/statm"
)

MIB = 1 << 20
SIZE = 64 * MIB  # above glibc's largest mmap threshold: always fresh, lazily mapped pages


def _rss() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _growth_when_written(make: Callable[[], np.ndarray]) -> tuple[int, int]:
    """(RSS growth while making, RSS growth while then writing every byte), bytes."""
    before = _rss()
    arr = make()
    made = _rss()
    arr.reshape(-1).view(np.uint8)[:] = 1
    return made - before, _rss() - made


def _lazy_platform() -> None:
    _, lazy = _growth_when_written(lambda: np.zeros(SIZE, np.uint8))
    if lazy < SIZE // 2:
        pytest.skip("np.zeros is mapped eagerly here: there is no first-touch fault to avoid")


def test_resident_zeros_are_mapped_when_made() -> None:
    _lazy_platform()
    made, written = _growth_when_written(lambda: resident_zeros(SIZE, np.uint8))
    assert made >= SIZE * 0.9
    assert written < 4 * MIB


def test_sample_ring_is_mapped_when_made() -> None:
    _lazy_platform()
    frames = SIZE // 4  # 2 channels int16
    block = np.ones((frames // 8, 2), np.int16)
    before = _rss()
    ring = SampleRing(frames, 2, np.int16)
    made = _rss()
    for k in range(8):
        assert ring.write(k * block.shape[0], block)
    assert made - before >= SIZE * 0.9
    assert _rss() - made < 4 * MIB
    assert ring.read(0, 3).tolist() == [[1, 1]] * 3


def test_row_buffer_is_mapped_when_made() -> None:
    _lazy_platform()
    rows = SIZE // (64 * 8) // 4  # the buffer holds 4 x keep rows of 64 float64
    new_rows = np.ones((3 * rows, 64))
    before = _rss()
    buf = RowBuffer(rows, (64,), np.float64)
    made = _rss()
    buf.append(new_rows, 0)
    assert made - before >= SIZE * 0.9
    assert _rss() - made < 4 * MIB
    assert buf.array[buf.position(3 * rows - 1)].tolist() == [1.0] * 64
