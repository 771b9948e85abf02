"""ADC clipping is never silent: the simulated board counts the values it clips, latches
ADC_CLIPPING in STATUS (SPEC 5.8), and the host driver raises it as an alarm annotation."""

from __future__ import annotations

import numpy as np

from hil.acquisition import AnnotationKind
from hil.acquisition.annotations import ADC_CLIPPING_TEXT
from hil.devices.board import Board
from hil.devices.board_settings import BoardSettings
from hil.devices.clock import VirtualClock
from sim_devices.board import BoardPort, LoopbackWorld, MemoryBoardLink, SimulatedBoard
from sim_devices.board.scaling import from_full_scale, from_full_scale_clipped
from sim_devices.board.spec import SampleFormat

RATE_HZ = 48_000


def _tone(k: int, n: int) -> np.ndarray:
    """0.5 full scale, 1 kHz."""
    return 0.5 * np.sin(2 * np.pi * 1000.0 * (k + np.arange(n)) / RATE_HZ)


def _stream(gain: float, seconds: float = 0.2) -> tuple[Board, SimulatedBoard, np.ndarray]:
    clock = VirtualClock(tick_s=0.001)
    sim = SimulatedBoard(clock=clock, world=LoopbackWorld(0, gain=gain))
    link = MemoryBoardLink(BoardPort(sim), timeout=0.0)
    settings = BoardSettings(sample_rate_hz=RATE_HZ, dac_channels=1, adc_channels=1)
    board = Board(link, settings=settings, virtual_time=clock, ring_seconds=2.0).open()
    board.configure()
    first = board.start(_tone)
    end = first + round(seconds * RATE_HZ)
    assert board.wait_for_samples(end, timeout_s=seconds + 1.0)
    return board, sim, board.read(first, end - first)


def test_the_conversion_counts_every_clipped_value() -> None:
    values = np.array([[0.5], [1.0], [-1.0], [-1.5], [2.0], [np.nan]])
    counts, clipped = from_full_scale_clipped(values, SampleFormat.INT16)
    assert counts[:, 0].tolist() == [16384, 32767, -32768, -32768, 32767, 0]
    assert clipped == 3  # +1.0 is beyond the top code; -1.0 is the bottom code, not clipped
    assert from_full_scale_clipped(values, SampleFormat.FLOAT32)[1] == 0


def test_a_block_with_nothing_to_clip_converts_as_the_full_rule() -> None:
    rng = np.random.default_rng(7)
    # In range up to both rails: -1.0 is the bottom code, 32766.5 / 32768 rounds (to even)
    # down to the top code 32766, 32767.4 / 32768 to the top code 32767.
    values = np.concatenate(
        [
            rng.uniform(-1.0, 1.0 - 1.0 / 32768, (500, 2)),
            [[-1.0, 32766.5 / 32768]],
            [[32767.4 / 32768, 0.0]],
        ]
    )
    counts, clipped = from_full_scale_clipped(values, SampleFormat.INT16)
    assert clipped == 0 and counts.dtype == np.int16
    assert counts[-2:].tolist() == [[-32768, 32766], [32767, 0]]
    np.testing.assert_array_equal(counts, np.rint(values * 32768.0).astype(np.int16))
    np.testing.assert_array_equal(counts, from_full_scale(values, SampleFormat.INT16))
    counts24, clipped24 = from_full_scale_clipped(values, SampleFormat.INT24)
    assert clipped24 == 0 and counts24.dtype == np.int32
    np.testing.assert_array_equal(counts24, from_full_scale(values, SampleFormat.INT24))
    # One value past the top rail in a block: the block takes the clipping rule.
    values[3, 1] = 1.0
    counts, clipped = from_full_scale_clipped(values, SampleFormat.INT16)
    assert clipped == 1 and counts[3, 1] == 32767
    empty, none = from_full_scale_clipped(np.zeros((0, 2)), SampleFormat.INT16)
    assert empty.shape == (0, 2) and empty.dtype == np.int16 and none == 0


def test_a_loud_input_is_counted_on_the_board_and_raised_as_an_alarm_by_the_host() -> None:
    board, sim, data = _stream(gain=3.0)  # 1.5 × full scale at the peaks
    expected = sim.adc_clipped_samples
    assert expected > 0
    rails = int(np.count_nonzero((data[:, 0] == 32767) | (data[:, 0] == -32768)))
    assert rails <= expected  # every value at a rail in what the host holds was clipped
    alarms = [
        a
        for a in board.annotations.of_kind(AnnotationKind.ALARM)
        if a.detail.startswith(ADC_CLIPPING_TEXT)
    ]
    assert alarms and board.adc_clipping_reports == len(alarms)
    assert "lower the drive amplitude or the receive gain" in alarms[0].detail
    board.close()


def test_an_input_within_full_scale_raises_nothing() -> None:
    board, sim, _ = _stream(gain=1.0)
    assert sim.adc_clipped_samples == 0 and board.adc_clipping_reports == 0
    assert not [
        a
        for a in board.annotations.of_kind(AnnotationKind.ALARM)
        if a.detail.startswith(ADC_CLIPPING_TEXT)
    ]
    board.close()
