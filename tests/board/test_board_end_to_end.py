"""The Board driver against the simulated board firmware: over a real pty, in memory and
through the pyusb backend object, at the tank-board rate (1 MS/s, 2 channels, int16), on an
injected clock that the test advances (no wall-clock pacing, no timed assertions)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import numpy as np
import pytest

from firmware_protocol import SampleFormat, State
from hil.acquisition import AnnotationKind
from hil.devices.board import Board, ReconnectPolicy
from hil.devices.board_dac_feeder import DacFeeder, ResumedSource
from hil.devices.board_settings import to_wire_samples
from hil.signals.presets import get_preset
from hil.signals.synthesis import BlockSynthesizer
from hil.signals.waveforms import build_schedule
from hil.transports import open_transport
from sim_devices.board import (
    BoardPort,
    FaultPlan,
    LoopbackWorld,
    MemoryBoardLink,
    SimulatedBoard,
)
from sim_devices.stage.clock import ManualClock

DELAY = 37  # loopback cable, samples
RATE_HZ = 1_000_000
WAIT_S = 20.0  # deadlock guard for one step, real seconds (never reached when things work)


def wait_until(done: Callable[[], bool], what: str, timeout_s: float = WAIT_S) -> None:
    """Poll ``done`` until True; fail the test with ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not done():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.0005)


def stream_for(
    board: Board,
    clock: ManualClock,
    seconds: float,
    step_s: float = 0.005,
    dac_level: Callable[[], int] | None = None,
) -> int:
    """Advance the shared clock by ``seconds`` in steps, waiting each step until the host
    holds every ADC sample the board clock has reached (and, with ``dac_level``, until the
    board's DAC FIFO holds at least two steps). Returns the board index reached."""
    steps = round(seconds / step_s)
    index = 0
    for _ in range(steps):
        if dac_level is not None:
            need = 2 * round(step_s * RATE_HZ)
            wait_until(lambda f=dac_level, k=need: f() >= k, "the DAC feeder")  # type: ignore[misc]
        clock.advance(step_s)
        index = round(clock.now() * 1e9) * RATE_HZ // 10**9  # the board clock, SPEC 5.3
        if board.start_index is not None and index > board.start_index:
            assert board.wait_for_samples(index, WAIT_S), f"ADC samples up to {index}"
    return index


def tank_board_synth() -> BlockSynthesizer:
    spec = get_preset("tank-board").spec()
    assert spec.fs_hz == RATE_HZ
    return BlockSynthesizer(build_schedule(spec), spec.fs_hz, amplitude=0.5)


def expected_loopback(first: int, n: int, delay: int = DELAY) -> np.ndarray:
    """What the ADC must hold at indices first .. first+n-1 for a stream started at
    ``first`` and fed from the tank-board synthesizer: the DAC samples ``delay`` late."""
    dac = tank_board_synth().render(0, n - delay)
    out = np.zeros((n, 2), dtype=np.int16)
    out[delay:] = to_wire_samples(dac, SampleFormat.INT16, 2)
    return out


@pytest.mark.slow
def test_pty_stream_at_tank_board_rate_loses_nothing() -> None:
    clock = ManualClock()
    transport = open_transport(f"sim://board?via=pty&delay={DELAY}", clock=clock)
    sim = transport.simulator  # type: ignore[attr-defined]
    board = Board(transport, clock=clock, keepalive_ms=None)
    try:
        board.open()
        board.configure()
        first = board.start(tank_board_synth().blocks(4096))
        level = lambda: sim.call(lambda b: b.snapshot().dac_buffer_level)  # noqa: E731
        end = stream_for(board, clock, 0.2 + 2.5, dac_level=level)
        n = end - first
        assert n >= 2_400_000
        # Every index from the start present exactly once, nothing missing or repeated.
        assert board.samples_received == n and board.ring is not None
        assert board.ring.written == n and board.ring.missing == 0
        assert board.gaps.gap_samples == board.gaps.overlap_samples == 0
        assert board.annotations.all() == []
        stats = board.protocol_stats
        damage = ("cobs_errors", "crc_errors", "bad_headers", "oversize_frames", "sequence_gaps")
        assert [stats[k] for k in damage] == [0] * len(damage)
        np.testing.assert_array_equal(board.read(first, n), expected_loopback(first, n))
        assert sim.call(lambda b: b.dac_underruns) == 0
        board.stop()
        assert board.state is State.STOPPED
    finally:
        board.close()
        transport.close()


def _memory_board(
    clock: ManualClock, faults: FaultPlan | None = None
) -> tuple[BoardPort, MemoryBoardLink]:
    world = LoopbackWorld(DELAY)
    port = BoardPort(SimulatedBoard(clock=clock, world=world, faults=faults), poll_s=0.0002)
    return port, MemoryBoardLink(port, timeout=0.005)


@pytest.mark.parametrize("fault", ["drop_bytes", "flip_bit", "garbage"])
def test_damaged_frame_is_counted_annotated_and_the_stream_resyncs(fault: str) -> None:
    clock = ManualClock()
    faults = FaultPlan(seed=9)
    port, link = _memory_board(clock, faults)
    board = Board(link, clock=clock, keepalive_ms=None)
    with board:
        board.configure()
        first = board.start(tank_board_synth().blocks(4096))
        level = lambda: port.call(lambda b: b.snapshot().dac_buffer_level)  # noqa: E731
        stream_for(board, clock, 0.25, dac_level=level)
        getattr(faults, fault)()
        end = stream_for(board, clock, 0.05, dac_level=level)
        frame = port.call(lambda b: b.adc_frame_samples)
        assert board.frame_errors >= 1
        seq_gaps = board.annotations.of_kind(AnnotationKind.SEQUENCE_GAP)
        gaps = board.annotations.of_kind(AnnotationKind.GAP)
        assert len(seq_gaps) == 1 and seq_gaps[0].length == 1  # exactly one frame lost
        assert len(gaps) == 1 and 0 < gaps[0].length <= frame  # resync within one frame
        lost = gaps[0]
        assert board.samples_received == end - first - lost.length
        # Everything after the lost frame arrived and is the right content.
        after = lost.sample_index + lost.length
        np.testing.assert_array_equal(
            board.read(after, end - after), expected_loopback(first, end - first)[after - first :]
        )


def test_adc_overrun_and_dac_underrun_are_reported_and_annotated() -> None:
    clock = ManualClock()
    faults = FaultPlan()
    port, link = _memory_board(clock, faults)
    with Board(link, clock=clock, keepalive_ms=None) as board:
        board.configure()
        first = board.start(tank_board_synth().blocks(4096))
        stream_for(board, clock, 0.25)
        faults.adc_overrun(1234)
        faults.dac_underrun(3000)
        level = lambda: port.call(lambda b: b.snapshot().dac_buffer_level)  # noqa: E731
        end = stream_for(board, clock, 0.6, dac_level=level)
        gaps = board.annotations.of_kind(AnnotationKind.GAP)
        assert [g.length for g in gaps] == [1234]
        assert board.samples_received == end - first - 1234
        assert len(board.annotations.of_kind(AnnotationKind.ADC_OVERRUN)) == 1
        assert len(board.annotations.of_kind(AnnotationKind.DAC_UNDERRUN)) == 1
        assert board.last_status is not None
        assert (board.last_status.adc_overruns, board.last_status.dac_underruns) == (1, 1)
        assert board.frame_errors == 0 and board.sequence_gaps == 0


def test_disconnect_triggers_reconnect_with_backoff_and_streaming_resumes(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.DEBUG, logger="hil.devices.board")
    clock = ManualClock()
    faults = FaultPlan()
    port, link = _memory_board(clock, faults)
    attempts: list[float] = []

    def replug_on_third_attempt() -> MemoryBoardLink:
        attempts.append(clock.now())
        if len(attempts) == 3:
            faults.replug()
        return MemoryBoardLink(port, timeout=0.005)

    board = Board(
        link,
        clock=clock,
        keepalive_ms=None,
        reconnect=ReconnectPolicy(first_delay_s=0.05, factor=2.0, max_attempts=6),
        transport_factory=replug_on_third_attempt,
    )
    with board:
        board.configure()
        first = board.start(tank_board_synth().blocks(4096))
        stream_for(board, clock, 0.25)
        t_lost = clock.now()
        port.call(lambda b: b.faults.disconnect())
        wait_until(lambda: board.reconnects == 1, "the reconnect")
        # Backoff: waits of 0.05, 0.1 and 0.2 s of the (injected) clock before the attempts.
        assert np.allclose(np.diff([t_lost, *attempts]), [0.05, 0.1, 0.2])
        kinds = [a.kind for a in board.annotations.all()]
        assert kinds[:2] == [AnnotationKind.DISCONNECT, AnnotationKind.RECONNECT], (
            board.annotations.all()
        )
        resumed = board.start_index
        assert resumed is not None and resumed > first
        end = stream_for(board, clock, 0.3)
        gaps = board.annotations.of_kind(AnnotationKind.GAP)
        assert len(gaps) == 1 and gaps[0].sample_index + gaps[0].length == resumed
        assert board.ring is not None and board.ring.end_index == end
        assert board.state is State.STREAMING
    # The loss, the failed attempts and the reconnect are in the board's debug log.
    logged = [r.getMessage().split(": ", 1)[1] for r in caplog.records if ": " in r.getMessage()]
    losses = [m for m in logged if m.startswith(("link lost", "reconnect"))]
    assert losses[0].startswith("link lost: ")
    assert [m.split(":")[0] for m in losses[1:]] == [
        "reconnect attempt 1 failed",
        "reconnect attempt 2 failed",
        "reconnected after 3 attempt(s)",
    ]


def test_watchdog_expiry_stops_the_board_and_is_annotated() -> None:
    clock = ManualClock()
    port, link = _memory_board(clock)
    # A long timeout arms the watchdog without letting the fast injected clock trip it.
    with Board(link, clock=clock, keepalive_ms=60000) as board:
        board.configure()
        board.start()
        stream_for(board, clock, 0.25)
        port.call(lambda b: b.faults.expire_watchdog())
        clock.advance(0.001)
        wait_until(lambda: board.annotations.count(AnnotationKind.WATCHDOG) == 1, "watchdog")
        assert board.state is State.STOPPED
        assert port.call(lambda b: b.snapshot().state) is State.STOPPED
        held = board.ring.end_index if board.ring else None
        clock.advance(0.2)
        assert board.wait_for_samples((held or 0) + 1, 0.1) is False  # nothing more comes


def test_usb_bulk_transport_streams_with_zero_loss() -> None:
    from sim_devices.board.usb_backend import SimulatedUsbBackend

    clock = ManualClock()
    backend = SimulatedUsbBackend(SimulatedBoard(clock=clock, world=LoopbackWorld(DELAY)))
    board = Board(
        "usb://1209:ca50",
        clock=clock,
        keepalive_ms=None,
        transport_options={"usb_backend": backend, "timeout": 0.005},
    )
    with board:
        assert board.capabilities is not None and backend.opened == 1
        board.configure()
        first = board.start(tank_board_synth().blocks(4096))
        end = stream_for(board, clock, 0.2 + 0.5)
        n = end - first
        assert board.samples_received == n and board.gaps.gap_samples == 0
        assert board.annotations.all() == []
        np.testing.assert_array_equal(board.read(first, n), expected_loopback(first, n))


def test_callable_source_is_asked_for_consecutive_samples() -> None:
    """A ``source(k, n)`` callable must be asked for fresh, consecutive sample numbers,
    also when one burst takes several blocks from it (regression: the same first index was
    asked again within a burst, so the DAC repeated its first block)."""
    clock = ManualClock()
    port, link = _memory_board(clock)
    synth = tank_board_synth()
    calls: list[tuple[int, int]] = []

    def source(k: int, n: int) -> np.ndarray:
        calls.append((k, n))
        return synth.render(k, n)

    with Board(link, clock=clock, keepalive_ms=None) as board:
        board.configure()
        first = board.start(source)
        level = lambda: port.call(lambda b: b.snapshot().dac_buffer_level)  # noqa: E731
        end = stream_for(board, clock, 0.3, dac_level=level)
        n = end - first
        np.testing.assert_array_equal(board.read(first, n), expected_loopback(first, n))
    starts = [c[0] for c in calls]
    assert starts[0] == 0  # sample numbers of the transmission: sample k plays at first + k
    assert all(b == a + n_a for (a, n_a), b in zip(calls, starts[1:], strict=False))


class GatedWrites:
    """A transport whose next write of ``size`` bytes or more, once armed, blocks until the
    test releases it (a link that cannot take a DAC burst for a while)."""

    def __init__(self, inner: MemoryBoardLink, size: int) -> None:
        self.inner, self.size = inner, size
        self.url, self.timeout = inner.url, inner.timeout
        self.armed = False
        self.blocked = threading.Event()
        self.release = threading.Event()

    def read(self, size: int) -> bytes:
        return self.inner.read(size)

    def write(self, data: bytes) -> int:
        if self.armed and len(data) >= self.size:
            self.armed = False
            self.blocked.set()
            assert self.release.wait(WAIT_S), "the test never released the write"
        return self.inner.write(data)

    def close(self) -> None:
        self.release.set()
        self.inner.close()


def _stream_until_a_dac_write_blocks(
    board: Board, clock: ManualClock, port: BoardPort, gate: GatedWrites
) -> tuple[int, Callable[[], int]]:
    """Start streaming, then arm the gate: the board grants credit as its FIFO drains and the
    writer's next burst blocks. Returns the first board index and the DAC level probe."""
    board.configure()
    first = board.start(tank_board_synth().blocks(4096))
    level = lambda: port.call(lambda b: b.snapshot().dac_buffer_level)  # noqa: E731
    stream_for(board, clock, 0.25, dac_level=level)
    gate.armed = True
    while not gate.blocked.is_set():
        stream_for(board, clock, 0.01)
        assert clock.now() < 5.0, "no DAC burst was written"
    return first, level


def test_adc_data_keeps_flowing_while_a_dac_write_blocks() -> None:
    """A DAC burst that blocks in the transport must not stop the reader: frames are encoded
    under the session lock but written outside it (regression: the write held the lock the
    reader needs, so every full link stalled ADC capture, by up to 24 ms at 1 MS/s)."""
    clock = ManualClock()
    port, link = _memory_board(clock)
    gate = GatedWrites(link, 8192)
    with Board(gate, clock=clock, keepalive_ms=None) as board:
        first, _ = _stream_until_a_dac_write_blocks(board, clock, port, gate)
        before = board.ring.end_index if board.ring else None
        assert before is not None
        end = stream_for(board, clock, 0.1)  # fails in wait_for_samples if the reader stalls
        assert board.ring is not None and board.ring.end_index is not None
        assert board.ring.end_index >= end >= before + 90_000
        sent_while_blocked = board.dac_samples_sent
        gate.release.set()
        # The queued burst and everything after it reach the board in order.
        wait_until(
            lambda: port.call(lambda b: b.dac_samples_received) >= sent_while_blocked,
            "the queued DAC frames",
        )
        assert board.protocol_stats["sequence_gaps"] == 0
        assert port.call(lambda b: b.conn.stats.sequence_gaps) == 0
        board.stop()
    assert first < before


def test_a_host_that_fell_behind_skips_to_the_board_clock_and_the_waveform_stays_aligned() -> None:
    """The DAC FIFO runs dry while the host cannot write (a long stall): afterwards the host
    skips the samples whose time has passed instead of sending them late, so transmission
    resumes at once and every sample played is the one of its board index."""
    clock = ManualClock()
    port, link = _memory_board(clock)
    gate = GatedWrites(link, 8192)
    with Board(gate, clock=clock, keepalive_ms=None) as board:
        first, level = _stream_until_a_dac_write_blocks(board, clock, port, gate)
        stream_for(board, clock, 0.6)  # longer than the 262 ms FIFO: it runs dry
        assert port.call(lambda b: b.dac_underruns) >= 1
        assert board.dac_samples_skipped == 0
        gate.release.set()
        end = stream_for(board, clock, 0.6, dac_level=level)
        skipped = board.dac_samples_skipped
        # Skipped: from where the host stood to start_lead_s (0.2 s) past the ADC stream,
        # which the 0.6 s stall had put 0.35-0.6 s ahead of it.
        assert 500_000 < skipped < 850_000
        notes = [a for a in board.annotations.all() if "skipped" in a.detail]
        assert len(notes) == 1 and notes[0].length == skipped
        resumed = notes[0].sample_index + skipped  # 0.2 s past the ADC stream at the skip
        assert notes[0].sample_index < resumed - 200_000 < end
        # From where transmission resumed: the loopback of exactly the samples of those board
        # indices (and silence in the span skipped, before it).
        n, m = end - first, end - (resumed + DELAY)
        assert m >= 100_000
        np.testing.assert_array_equal(board.read(end - m, m), expected_loopback(first, n)[-m:])
        assert not board.read(resumed - 1000, 1000).any()
        board.stop()


@pytest.mark.parametrize("kind", ["iterable", "reader", "callable"])
def test_dac_feeder_skip_drops_exactly_the_next_samples(kind: str) -> None:
    synth = tank_board_synth()
    ref = to_wire_samples(synth.render(0, 30_000), SampleFormat.INT16, 1)
    sources = {
        "iterable": lambda: tank_board_synth().blocks(4096),
        "reader": tank_board_synth,
        "callable": lambda: synth.render,
    }
    feeder = DacFeeder(sources[kind](), SampleFormat.INT16, 1, 1000)
    a = feeder.take(100)
    feeder.skip(9_000)
    b = feeder.take(5_000)
    assert a is not None and b is not None and feeder.next_index == 1000 + 9_000
    np.testing.assert_array_equal(a, ref[:100])
    np.testing.assert_array_equal(b[: min(5_000, b.shape[0])], ref[9_100 : 9_100 + b.shape[0]])


def test_a_refused_start_is_retried_later_with_the_same_samples() -> None:
    """The preload outlasts the start lead (here the source's first call takes 0.3 s of board
    time, the lead is 0.2 s): the board refuses START as its index has passed; the driver
    stops it, doubles the lead and starts again, and sample 0 still plays at the index
    start() returns."""
    clock = ManualClock()
    port, link = _memory_board(clock)
    synth = tank_board_synth()
    calls: list[tuple[int, int]] = []

    def slow_source(k: int, n: int) -> np.ndarray:
        if not calls:
            clock.advance(0.3)  # a host busy elsewhere while it fills the DAC buffer
        calls.append((k, n))
        return synth.render(k, n)

    with Board(link, clock=clock, keepalive_ms=None) as board:
        board.configure()
        first_try = board.board_index_now() + 200_000
        first = board.start(slow_source)
        # Retried with twice the lead, from the clock after the 0.3 s.
        assert first == first_try + 300_000 + 200_000
        level = lambda: port.call(lambda b: b.snapshot().dac_buffer_level)  # noqa: E731
        end = stream_for(board, clock, 0.7, dac_level=level)  # to 1.0 s: 0.3 s streamed
        n = end - first
        assert n == 300_000
        np.testing.assert_array_equal(board.read(first, n), expected_loopback(first, n))
        retries = board.annotations.of_kind(AnnotationKind.START_RETRY)
        assert [(a.sample_index, a.length) for a in retries] == [(first, 1)]
        assert f"at {first_try} with a 0.2 s lead" in retries[0].detail
        assert "started at" in retries[0].detail and "0.4 s lead" in retries[0].detail
        board.stop()
    # The samples sent for the refused start were sent again, not asked for again.
    starts = [c[0] for c in calls]
    assert starts[0] == 0
    assert all(b == a + n_a for (a, n_a), b in zip(calls, starts[1:], strict=False))


@pytest.mark.parametrize("kind", ["iterable", "reader", "callable"])
def test_dac_feeder_restart_sends_the_same_samples_from_sample_0(kind: str) -> None:
    ref = to_wire_samples(tank_board_synth().render(0, 20_000), SampleFormat.INT16, 1)
    sources = {
        "iterable": lambda: tank_board_synth().blocks(4096),
        "reader": tank_board_synth,
        "callable": lambda: tank_board_synth().render,
    }
    feeder = DacFeeder(sources[kind](), SampleFormat.INT16, 1, 1000)
    sent = [feeder.take(3000), feeder.take(2000)]
    assert sent[0] is not None and sent[1] is not None
    feeder.sent([sent[0], sent[1]])
    feeder.next_index += 5000
    feeder.restart_at(7000)
    assert feeder.next_index == 7000
    again = [feeder.take(4000), feeder.take(6000)]
    assert again[0] is not None and again[1] is not None
    np.testing.assert_array_equal(
        np.concatenate([*again]), ref[: again[0].shape[0] + again[1].shape[0]]
    )
    feeder.started()
    with pytest.raises(RuntimeError, match="after started"):
        feeder.restart_at(9000)


def test_restart_of_an_ended_source_sends_what_it_gave() -> None:
    block = np.linspace(-0.5, 0.5, 500)
    feeder = DacFeeder([block], SampleFormat.INT16, 1, 0)
    taken = feeder.take(1000)
    assert taken is not None and feeder.take(1000) is None and feeder.exhausted
    feeder.sent([taken])
    feeder.restart_at(100)
    assert not feeder.exhausted
    again = feeder.take(1000)
    assert again is not None
    np.testing.assert_array_equal(again, taken)
    assert feeder.take(1000) is None and feeder.exhausted


def test_a_resumed_source_skips_by_reading_and_passes_its_end_on() -> None:
    """After a reconnect the remaining samples of the old feeder are a sequential source:
    a late-DAC skip drops exactly the next samples (each later sample keeps its place), and
    when the old source ends the new feeder is exhausted (a preload can finish)."""
    ref = to_wire_samples(tank_board_synth().render(0, 30_000), SampleFormat.INT16, 1)
    old = DacFeeder(tank_board_synth().blocks(4096), SampleFormat.INT16, 1, 0)
    head = old.take(2500)
    assert head is not None
    resumed = DacFeeder(ResumedSource(old), SampleFormat.INT16, 1, 50_000)
    a = resumed.take(1000)
    resumed.skip(7000)
    b = resumed.take(3000)
    assert a is not None and b is not None
    np.testing.assert_array_equal(a, ref[2500 : 2500 + a.shape[0]])
    start_b = 2500 + a.shape[0] + 7000
    np.testing.assert_array_equal(b, ref[start_b : start_b + b.shape[0]])

    short = DacFeeder([np.full(300, 0.25)], SampleFormat.INT16, 1, 0)
    assert short.take(100) is not None
    tail = DacFeeder(ResumedSource(short), SampleFormat.INT16, 1, 1000)
    rest = tail.take(1000)
    assert rest is not None and rest.shape[0] == 200
    assert tail.take(1000) is None and tail.exhausted
