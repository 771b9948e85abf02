"""The callback contract pieces: status flags, block times, xrun log, ring buffers, runner."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.devices.audio import BlockTime, CallbackStop, StatusFlags, XrunLog
from hil.devices.audio.contract import BlockOutcome, CallbackRunner, FloatArray
from hil.devices.audio.ring import ring_read, ring_write


def test_status_flags_have_portaudio_bit_values() -> None:
    # paInputUnderflow .. paPrimingOutput in portaudio.h
    assert [int(f) for f in StatusFlags] == [1, 2, 4, 8, 16]
    assert not StatusFlags(0)


def test_block_time_copy_is_independent() -> None:
    t = BlockTime()
    t.sample_index, t.current_time_s = 512, 1.5
    snap = t.copy()
    t.sample_index = 768
    assert (snap.sample_index, snap.current_time_s) == (512, 1.5)
    assert repr(snap).startswith("BlockTime(sample_index=512,")


def test_xrun_log_keeps_capacity_and_counts_the_rest() -> None:
    log = XrunLog(capacity=3)
    for k in range(5):
        log.record(256 * k, 2)
    assert len(log) == 3 and log.dropped == 2
    assert log.events() == [(0, StatusFlags(2)), (256, StatusFlags(2)), (512, StatusFlags(2))]
    log.clear()
    assert log.events() == [] and log.dropped == 0


def _runner_block(
    runner: CallbackRunner, frames: int, flags: int = 0
) -> tuple[BlockOutcome, FloatArray]:
    out = np.full((frames, 1), 9.0, dtype=np.float32)
    outcome = runner.run_block(np.zeros((frames, 1), np.float32), out, frames, 0.0, 0.0, 0.0, flags)
    return outcome, out


def test_runner_counts_samples_logs_xruns_and_keeps_errors() -> None:
    def callback(
        indata: FloatArray, outdata: FloatArray, frames: int, time: BlockTime, status: StatusFlags
    ) -> None:
        outdata.fill(0.5)
        if time.sample_index == 64:
            raise CallbackStop
        if time.sample_index == 96:
            raise ZeroDivisionError("bad block")

    runner = CallbackRunner(callback)
    assert _runner_block(runner, 32)[0] is BlockOutcome.CONTINUE
    outcome, out = _runner_block(runner, 32, flags=4)
    assert outcome is BlockOutcome.CONTINUE and np.all(out == 0.5)
    assert _runner_block(runner, 32)[0] is BlockOutcome.COMPLETE
    outcome, out = _runner_block(runner, 32)
    assert outcome is BlockOutcome.ABORT
    assert not out.any()  # the failed block's output is silenced
    assert runner.sample_index == 128
    assert runner.xruns.events() == [(32, StatusFlags.OUTPUT_UNDERFLOW)]
    with pytest.raises(ZeroDivisionError, match="bad block"):
        runner.raise_pending()
    runner.raise_pending()  # only once


@settings(max_examples=50, deadline=None)
@given(
    size=st.integers(1, 64),
    start=st.integers(-200, 10_000),
    frames=st.integers(1, 64),
    seed=st.integers(0, 2**32 - 1),
)
def test_ring_write_then_read_round_trips(size: int, start: int, frames: int, seed: int) -> None:
    frames = min(frames, size)
    ring = np.zeros((size, 2), dtype=np.float32)
    block = np.random.default_rng(seed).standard_normal((frames, 2)).astype(np.float32)
    ring_write(ring, start, block)
    back = np.empty_like(block)
    ring_read(ring, start, back)
    assert np.array_equal(back, block)
    rows = (start + np.arange(frames)) % size
    assert np.array_equal(ring[rows], block)
