"""The simulated board firmware through a raw HOST Connection (no driver): handshake,
configuration checks, credit, streaming by sample index, watchdog, faults, worlds."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_protocol import (
    NEED_DATA,
    AdcData,
    Alarm,
    Configure,
    Connection,
    Credit,
    DacData,
    Keepalive,
    Nak,
    NakCode,
    Role,
    SampleFormat,
    Start,
    State,
    Status,
    Stop,
    Sync,
)
from hil.errors import ConfigError
from sim_devices.board import BoardSpec, FaultPlan, LoopbackWorld, SimulatedBoard
from sim_devices.board.dac_fifo import DacFifo
from sim_devices.board.scaling import from_full_scale, to_full_scale
from sim_devices.stage.clock import ManualClock

RATE = 1_000_000
INT16 = SampleFormat.INT16


def exchange(host: Connection, board: SimulatedBoard, *messages: object) -> list[Any]:
    for message in messages:
        board.receive_data(host.send(message))  # type: ignore[arg-type]
    board.tick()
    out = board.data_to_send()
    if out:  # b"" would mean end of stream to a Connection
        host.receive_data(out)
    events: list[Any] = []
    while (event := host.next_event()) is not NEED_DATA:
        events.append(event)
    return events


def ready(board: SimulatedBoard) -> Connection:
    host = Connection(Role.HOST)
    events = exchange(host, board, host.make_hello())
    assert host.state is State.READY, events
    return host


def configured(board: SimulatedBoard, config: Configure | None = None) -> Connection:
    host = ready(board)
    exchange(host, board, config or Configure(RATE, 0b11, 0b11, INT16, INT16))
    assert host.state is State.CONFIGURED
    return host


def test_handshake_reports_identity_and_capabilities() -> None:
    board = SimulatedBoard(BoardSpec(board_serial=77), clock=ManualClock())
    host = Connection(Role.HOST)
    events = exchange(host, board, host.make_hello())
    names = [type(e).__name__ for e in events]
    assert names[:2] == ["Version", "Capabilities"]
    assert events[0].board_serial == 77
    caps = host.capabilities
    assert caps is not None and caps.sample_rates_hz[0] == 1_000_000
    assert caps.dac_channels == caps.adc_channels == 2 and caps.formats == 0b111


def test_incompatible_host_gets_version_and_nothing_more() -> None:
    board = SimulatedBoard(BoardSpec(protocol_version=(3, 0)), clock=ManualClock())
    host = Connection(Role.HOST)
    board.receive_data(host.send(host.make_hello()))
    board.tick()
    out = board.data_to_send()
    # SPEC 5.1: VERSION only, then back to IDLE, waiting for a compatible HELLO.
    assert board.conn.state is State.IDLE and board.conn.refusal is not None
    assert out.count(b"\x00") == 1  # one frame: VERSION


@pytest.mark.parametrize(
    ("config", "code"),
    [
        (Configure(12345, 1, 1, INT16, INT16), NakCode.UNSUPPORTED_RATE),
        (Configure(RATE, 0b100, 1, INT16, INT16), NakCode.UNSUPPORTED_CHANNELS),
        (Configure(RATE, 1, 1, INT16, INT16, dac_gain_cdb=5000), NakCode.GAIN_OUT_OF_RANGE),
    ],
)
def test_configure_outside_capabilities_is_naked(config: Configure, code: NakCode) -> None:
    board = SimulatedBoard(clock=ManualClock())
    host = ready(board)
    events = exchange(host, board, config)
    naks = [e for e in events if isinstance(e, Nak)]
    assert [n.code for n in naks] == [code] and host.state is State.READY


def test_unsupported_format_is_naked() -> None:
    board = SimulatedBoard(BoardSpec(formats=(INT16,)), clock=ManualClock())
    host = ready(board)
    events = exchange(host, board, Configure(RATE, 1, 1, INT16, SampleFormat.FLOAT32))
    assert [e.code for e in events if isinstance(e, Nak)] == [NakCode.UNSUPPORTED_FORMAT]


def test_configure_grants_the_whole_dac_buffer_and_syncs() -> None:
    clock = ManualClock(3.0)
    board = SimulatedBoard(BoardSpec(dac_buffer_samples=40_000), clock=clock)
    host = ready(board)
    clock.advance(0.5)
    events = exchange(host, board, Configure(RATE, 0b11, 0b11, INT16, INT16))
    credits = [e.credit_samples for e in events if isinstance(e, Credit)]
    syncs = [e for e in events if isinstance(e, Sync)]
    assert credits == [40_000] and host.dac_credit == 40_000
    # The clock ran at the default rate (1 MS/s) since power-up at t = 3 s; board time
    # counts from power-up too (SPEC 5.3), not from the injected clock's zero.
    assert syncs[0].sample_index == 500_000 and syncs[0].board_time_ns == 500_000_000


def test_start_index_in_the_past_is_naked() -> None:
    clock = ManualClock()
    board = SimulatedBoard(clock=clock)
    host = configured(board)
    clock.advance(0.01)
    events = exchange(host, board, Start(5000))
    assert [e.code for e in events if isinstance(e, Nak)] == [NakCode.START_INDEX_PASSED]


def test_streaming_sends_every_index_once_with_loopback_content() -> None:
    clock = ManualClock()
    board = SimulatedBoard(clock=clock, world=LoopbackWorld(delay_samples=3))
    host = configured(board)
    rng = np.random.default_rng(5)
    dac = rng.integers(-30000, 30000, (6000, 2)).astype(np.int16)
    start = 1000
    for k in range(0, 6000, 2000):
        exchange(host, board, DacData.from_array(start + k, 0b11, INT16, dac[k : k + 2000]))
    exchange(host, board, Start(start))
    adc = []
    for _ in range(8):  # 8 ms of board time, 1 ms per tick
        clock.advance(0.001)
        adc += [e for e in exchange(host, board) if isinstance(e, AdcData)]
    firsts = [a.first_sample_index for a in adc]
    counts = [a.sample_count for a in adc]
    assert firsts[0] == start
    assert all(f + c == g for f, c, g in zip(firsts, counts, firsts[1:], strict=False))
    got = np.concatenate([a.samples() for a in adc])
    assert got.shape[0] == 8000 - start
    np.testing.assert_array_equal(got[3:6003], dac)
    assert not got[:3].any() and board.dac_underruns == 1  # DAC ran dry after 6000 samples


def test_stop_flushes_captured_samples_then_acks() -> None:
    clock = ManualClock()
    board = SimulatedBoard(clock=clock)
    host = configured(board)
    exchange(host, board, Start(0))
    clock.advance(0.0025)
    events = exchange(host, board, Stop())
    adc = [e for e in events if isinstance(e, AdcData)]
    assert sum(a.sample_count for a in adc) == 2500 and host.state is State.STOPPED
    clock.advance(0.01)
    assert not [e for e in exchange(host, board) if isinstance(e, AdcData)]


def test_watchdog_expiry_stops_transmission() -> None:
    clock = ManualClock()
    board = SimulatedBoard(clock=clock)
    host = configured(board)
    exchange(host, board, Keepalive(100), Start(0))
    clock.advance(0.05)
    assert [e for e in exchange(host, board) if isinstance(e, AdcData)]
    clock.advance(0.2)  # no host frame for 250 ms > 100 ms
    events = exchange(host, board)
    status = [e for e in events if isinstance(e, Status) and e.alarms & Alarm.WATCHDOG_EXPIRED]
    adc = [e for e in events if isinstance(e, AdcData)]
    # Samples up to the expiry instant (100 ms after the last host frame, at t = 0) went
    # out, then nothing: 50 ms of them in this exchange.
    assert sum(a.sample_count for a in adc) == 50_000 and len(status) == 1
    assert host.state is State.STOPPED and board.snapshot().state is State.STOPPED
    clock.advance(0.5)
    assert not [e for e in exchange(host, board) if isinstance(e, AdcData)]


def test_host_frames_feed_the_watchdog() -> None:
    clock = ManualClock()
    board = SimulatedBoard(clock=clock)
    host = configured(board)
    exchange(host, board, Keepalive(100), Start(0))
    for _ in range(10):
        clock.advance(0.06)
        exchange(host, board, Keepalive(100))
    assert host.state is State.STREAMING and board.faults.counters.watchdog_expiries == 0


def test_credit_beyond_grant_is_naked_credit_exceeded() -> None:
    board = SimulatedBoard(BoardSpec(dac_buffer_samples=1000), clock=ManualClock())
    host = configured(board)
    host.dac_credit = 5000  # a host that miscounts
    events = exchange(host, board, DacData.from_array(0, 0b11, INT16, np.zeros((2000, 2), int)))
    naks = [e for e in events if isinstance(e, Nak)]
    assert [(n.code, n.ref_type) for n in naks] == [(NakCode.CREDIT_EXCEEDED, DacData.TYPE_ID)]


def test_adc_overrun_fault_loses_exactly_the_requested_samples() -> None:
    clock = ManualClock()
    faults = FaultPlan()
    board = SimulatedBoard(clock=clock, faults=faults)
    host = configured(board)
    exchange(host, board, Start(0))
    faults.adc_overrun(3000)
    clock.advance(0.01)
    adc = [e for e in exchange(host, board) if isinstance(e, AdcData)]
    assert adc[0].first_sample_index == 3000
    assert sum(a.sample_count for a in adc) == 7000 and board.adc_overruns == 1


def test_byte_faults_damage_one_frame_each() -> None:
    clock = ManualClock()
    faults = FaultPlan(seed=3)
    board = SimulatedBoard(clock=clock, faults=faults)
    host = configured(board)
    exchange(host, board, Start(0))
    for inject in (faults.drop_bytes, faults.flip_bit, faults.garbage):
        before = host.stats.frame_errors
        inject()
        clock.advance(0.002)
        exchange(host, board)
        assert host.stats.frame_errors > before
    counters = faults.counters
    assert (counters.dropped_bytes, counters.flipped_bits, counters.garbage_bursts) == (1, 1, 1)


def test_fault_arguments_are_checked() -> None:
    with pytest.raises(ConfigError, match=r"drop_bytes\.n = 0 is not allowed: must be an integer"):
        FaultPlan().drop_bytes(0)


@settings(max_examples=30, deadline=None)
@given(
    cuts=st.lists(st.integers(1, 50), min_size=1, max_size=8),
    delay=st.integers(0, 40),
)
def test_loopback_world_chunks_equal_whole(cuts: list[int], delay: int) -> None:
    rng = np.random.default_rng(11)
    x = rng.normal(size=(sum(cuts), 2))
    whole = LoopbackWorld(delay, 0.5)(x, 0)
    world = LoopbackWorld(delay, 0.5)
    parts, pos = [], 0
    for n in cuts:
        parts.append(world(x[pos : pos + n], pos))
        pos += n
    np.testing.assert_array_equal(np.concatenate(parts), whole)
    n = x.shape[0]
    np.testing.assert_array_equal(whole[min(delay, n) :], 0.5 * x[: max(0, n - delay)])


def test_loopback_world_rejects_negative_delay() -> None:
    with pytest.raises(ConfigError, match=r"delay_samples = -1 is not allowed.*a cable is causal"):
        LoopbackWorld(-1)


def test_dac_fifo_drops_late_samples_and_counts_them() -> None:
    fifo = DacFifo(1)
    fifo.push(0, np.arange(10.0).reshape(10, 1))
    out, covered = fifo.play(4, 3)
    assert out[:, 0].tolist() == [4.0, 5.0, 6.0] and covered.tolist() == [True] * 3
    assert fifo.late_samples == 4 and fifo.level == 3
    assert fifo.discard(2) == 2 and fifo.play(7, 3)[0][:, 0].tolist() == [0.0, 0.0, 9.0]


def test_scaling_round_trip_is_exact_for_int16() -> None:
    counts = np.array([[-32768, 0, 1, 32767]], dtype=np.int16)
    back = from_full_scale(to_full_scale(counts, INT16), INT16)
    np.testing.assert_array_equal(back, counts)
    assert from_full_scale(np.array([[1.5]]), SampleFormat.INT24).tolist() == [[8388607]]
