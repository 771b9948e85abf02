"""FrameStream: the frames' samples in order, whatever the read sizes."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_devices.acoustics.frame_stream import FrameStream


def _frames(lengths: list[int]) -> FrameStream:
    """Frames of the given lengths holding 0, 1, 2, … in order (then frames of 3 forever)."""
    state = {"next": 0, "k": 0}

    def render() -> np.ndarray:
        m = lengths[state["k"]] if state["k"] < len(lengths) else 3
        state["k"] += 1
        out = np.arange(state["next"], state["next"] + m, dtype=np.float64)
        state["next"] += m
        return out

    return FrameStream(render)


@settings(max_examples=60, deadline=None)
@given(
    lengths=st.lists(st.integers(1, 9), min_size=1, max_size=8),
    reads=st.lists(st.integers(0, 20), min_size=1, max_size=12),
)
def test_any_read_sizes_give_the_stream_in_order(lengths: list[int], reads: list[int]) -> None:
    stream = _frames(lengths)
    got = np.concatenate([stream.take(n) for n in reads])
    assert got.dtype == np.float64
    assert got.tolist() == list(range(sum(reads)))


def test_a_read_is_a_copy_not_a_view_of_the_frame() -> None:
    frame = np.arange(6.0)
    stream = FrameStream(lambda: frame)
    first = stream.take(2)
    first[:] = -1.0
    assert stream.take(2).tolist() == [2.0, 3.0] and frame[:2].tolist() == [0.0, 1.0]
