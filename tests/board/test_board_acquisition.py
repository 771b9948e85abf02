"""Acquisition pieces: the sample-indexed ring, gap detection, the SYNC clock fit, and the
settings descriptors and DAC scaling of the driver."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_protocol import SampleFormat
from hil.acquisition import AnnotationKind, SampleClockFit, SampleGapDetector, SampleRing
from hil.devices.board_dac_feeder import DacFeeder
from hil.devices.board_settings import BoardSettings, Setting, to_wire_samples
from hil.errors import ConfigError


@settings(max_examples=40, deadline=None)
@given(cuts=st.lists(st.integers(1, 300), min_size=1, max_size=12), capacity=st.integers(50, 900))
def test_ring_chunks_equal_whole(cuts: list[int], capacity: int) -> None:
    rng = np.random.default_rng(4)
    total = sum(cuts)
    data = rng.integers(-1000, 1000, (total, 2)).astype(np.int16)
    ring = SampleRing(capacity, 2, np.int16)
    pos = 500
    for n in cuts:
        assert ring.write(pos, data[pos - 500 : pos - 500 + n])
        pos += n
    held = min(total, capacity)
    assert ring.end_index == 500 + total and ring.start_index == 500 + total - held
    np.testing.assert_array_equal(ring.read(500 + total - held, held), data[total - held :])
    assert ring.written == total and ring.missing == 0


def test_ring_refuses_repeats_and_reads_outside_what_it_holds() -> None:
    ring = SampleRing(10, 1, np.int16)
    ring.write(0, np.ones((8, 1), np.int16))
    assert ring.write(5, np.ones((2, 1), np.int16)) is False and ring.written == 8
    ring.write(8, np.ones((8, 1), np.int16))
    with pytest.raises(ConfigError, match=r"first \.\. first\+n = '2 \.\. 6' is not allowed: must"):
        ring.read(2, 4)
    with pytest.raises(ConfigError, match="capacity = 0 is not allowed"):
        SampleRing(0, 1)


def test_ring_expecting_a_start_zero_fills_samples_lost_before_the_first_block() -> None:
    ring = SampleRing(16, 2, np.int16)
    ring.expect(100)
    assert (ring.start_index, ring.end_index) == (100, 100)
    block = np.full((3, 2), 7, np.int16)
    assert ring.write(104, block)
    assert (ring.start_index, ring.end_index, ring.missing, ring.written) == (100, 107, 4, 3)
    np.testing.assert_array_equal(ring.read(100, 7)[:, 0], [0, 0, 0, 0, 7, 7, 7])
    # Once samples are held the expectation is spent: a later expect() changes nothing.
    ring.expect(200)
    assert (ring.start_index, ring.end_index) == (100, 107)
    with pytest.raises(ConfigError, match=r"within 100 \.\. 107"):
        ring.read(99, 2)


def test_ring_expecting_a_later_start_begins_where_the_stream_does() -> None:
    ring = SampleRing(16, 1, np.int16)
    ring.expect(100)
    ring.expect(120)  # a START refused and sent again: nothing held yet, so it moves
    assert ring.write(118, np.arange(4, dtype=np.int16).reshape(4, 1))
    assert (ring.start_index, ring.end_index, ring.missing) == (118, 122, 0)
    assert not ring.write(120, np.zeros((1, 1), np.int16))  # a repeat is still refused


def test_ring_wait_for_wakes_on_write() -> None:
    ring = SampleRing(100, 1, np.int16)
    writer = threading.Timer(0.01, lambda: ring.write(0, np.zeros((50, 1), np.int16)))
    writer.start()
    assert ring.wait_for(50, 5.0) and not ring.wait_for(51, 0.01)
    writer.join()


class CountingCondition(threading.Condition):
    """A condition that counts its notify_all calls."""

    notified = 0

    def notify_all(self) -> None:
        self.notified += 1
        super().notify_all()


def test_ring_wakes_a_waiter_only_once_its_index_is_held() -> None:
    ring = SampleRing(1000, 1, np.int16)
    cond = CountingCondition(ring._lock)
    ring._cond = cond
    block = np.zeros((10, 1), np.int16)
    ring.write(0, block)  # nobody waits: no notification at all
    assert cond.notified == 0
    results: dict[str, bool] = {}
    waiters = [
        threading.Thread(target=lambda k=k, i=i: results.__setitem__(k, ring.wait_for(i, 10.0)))
        for k, i in (("near", 40), ("far", 100))
    ]
    for w in waiters:
        w.start()
    while len(ring._targets) < 2:  # both registered
        threading.Event().wait(0.001)
    for first in (10, 20):
        ring.write(first, block)  # end 30: below both indices
    assert cond.notified == 0 and results == {}
    ring.write(30, block)  # end 40: the near waiter's index
    waiters[0].join(10.0)
    assert results == {"near": True} and cond.notified == 1
    ring.write(40, np.zeros((60, 1), np.int16))  # end 100
    waiters[1].join(10.0)
    assert results == {"near": True, "far": True} and cond.notified == 2
    assert not ring.wait_for(500, 0.01) and ring._targets == []  # a timed-out wait is forgotten
    ring.write(100, block)
    assert cond.notified == 2


def test_gap_detector_reports_gaps_and_overlaps_once() -> None:
    det = SampleGapDetector()
    notes = [det.check(f, n) for f, n in ((0, 10), (10, 10), (25, 5), (28, 4), (32, 1))]
    kinds = [None if n is None else (n.kind, n.sample_index, n.length) for n in notes]
    assert kinds == [
        None,
        None,
        (AnnotationKind.GAP, 20, 5),
        (AnnotationKind.OVERLAP, 28, 2),
        None,
    ]
    assert (det.gap_samples, det.overlap_samples, det.expected) == (5, 2, 33)


def test_clock_fit_recovers_rate_and_offset_through_jitter() -> None:
    rng = np.random.default_rng(8)
    fit = SampleClockFit(1e6)
    true_rate, t0 = 1e6 * (1 - 35e-6), 123.0
    for k in range(200):
        index = k * 100_000
        fit.add(index, t0 + index / true_rate + 0.002 + rng.uniform(0, 0.001))
    assert fit.rate_hz == pytest.approx(true_rate, abs=5.0)  # 5 ppm; the offset is 35 ppm
    assert fit.host_time(5_000_000) == pytest.approx(t0 + 5_000_000 / true_rate + 0.0025, abs=2e-4)
    assert abs(fit.sample_index(fit.host_time(7_654_321)) - 7_654_321) <= 1
    assert np.abs(fit.residuals_s()).max() < 0.001


def test_clock_fit_needs_a_pair_first() -> None:
    with pytest.raises(ConfigError, match="sync pairs = 0 is not allowed: must be >= 1; wait"):
        SampleClockFit(1e6).host_time(0)


def test_setting_descriptor_validates_and_converts() -> None:
    s = BoardSettings(adc_format="int24", dac_gain_db=-6)
    assert s.adc_format is SampleFormat.INT24 and s.dac_gain_db == -6.0
    config = s.to_configure()
    assert (config.adc_format, config.dac_gain_cdb, config.adc_channel_mask) == (
        SampleFormat.INT24,
        -600,
        0b11,
    )
    assert isinstance(BoardSettings.sample_rate_hz, Setting)
    with pytest.raises(ConfigError, match=r"sample_rate_hz = 1\.5 is not allowed"):
        BoardSettings(sample_rate_hz=1.5)
    with pytest.raises(ConfigError, match=r"dac_gain_db = nan is not allowed: must be -120\.0"):
        BoardSettings(dac_gain_db=float("nan"))
    with pytest.raises(ConfigError, match="adc_channels = True is not allowed"):
        BoardSettings(adc_channels=True)


def test_dac_feeder_chunks_equal_whole_for_generators_and_callables() -> None:
    rng = np.random.default_rng(6)
    signal = rng.uniform(-1, 1, 1000)
    whole = to_wire_samples(signal, SampleFormat.INT16, 2)
    blocks = (signal[i : i + 64] for i in range(0, 1000, 64))
    feeder = DacFeeder(blocks, SampleFormat.INT16, 2, first=0)
    out = []
    for n in (10, 100, 7, 300, 1000):
        while (block := feeder.take(n)) is not None and block.shape[0]:
            out.append(block)
            if sum(b.shape[0] for b in out) >= 1000:
                break
    np.testing.assert_array_equal(np.concatenate(out), whole)
    callable_feeder = DacFeeder(
        lambda first, n: signal[first : first + n], SampleFormat.INT16, 2, 0
    )
    block = callable_feeder.take(100)
    assert block is not None
    np.testing.assert_array_equal(block, whole[:100])


def test_dac_block_of_wrong_shape_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"DAC block shape = \(4, 3\) is not allowed"):
        to_wire_samples(np.zeros((4, 3)), SampleFormat.INT16, 2)


def test_heap_freeze_keeps_setup_objects_out_of_full_collections_until_stopped() -> None:
    import gc

    from hil.acquisition import HeapFreeze

    before = gc.get_freeze_count()
    setup = [[i] for i in range(1000)]  # objects alive when the run starts
    heap = HeapFreeze()
    heap.start()
    frozen = gc.get_freeze_count()
    later = [[i] for i in range(1000)]  # allocated after the start: a second one keeps them out
    heap.start()  # a second start changes nothing
    # The count is the permanent generation's size: a frozen object freed meanwhile (by any
    # thread, e.g. an event loop another test left running) leaves it, so it can only fall.
    assert frozen >= before + len(setup) and gc.get_freeze_count() <= frozen
    assert len(later) == 1000
    heap.stop()
    heap.stop()
    assert gc.get_freeze_count() == 0
    with HeapFreeze() as h:
        assert gc.get_freeze_count() >= len(setup) and isinstance(h, HeapFreeze)
    assert gc.get_freeze_count() == 0


def test_heap_freeze_without_its_collection_keeps_the_setups_garbage_until_stopped() -> None:
    """``collect=False`` (a run on virtual time) freezes the setup's garbage with it: a
    reference cycle dropped before the start outlives a full collection while frozen and is
    freed at the first one after the stop; with the collection it is freed at the start."""
    import gc
    import weakref

    from hil.acquisition import HeapFreeze

    class Node:
        def __init__(self) -> None:
            self.me = self  # a cycle: only the collector frees it

    automatic = gc.isenabled()
    gc.disable()  # no automatic pass between the drop and the start
    try:
        for collect in (True, False):
            node = Node()
            alive = weakref.ref(node)
            del node
            with HeapFreeze(collect=collect):
                gc.collect()
                assert (alive() is None) is collect
            gc.collect()
            assert alive() is None and gc.get_freeze_count() == 0
    finally:
        if automatic:
            gc.enable()
