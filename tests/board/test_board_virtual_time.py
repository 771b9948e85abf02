"""The Board driver on virtual time: no threads, the simulated board in memory on one
:class:`~hil.devices.clock.VirtualClock`, every wait slept on that clock. Values, not timing:
what the loopback returns is what was transmitted, two runs give identical bytes, a silent
board times out after the virtual timeout without any wall-clock wait."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from hil.acquisition import AnnotationKind
from hil.devices.board import Board
from hil.devices.board_link_virtual import VirtualTimeBoardLink
from hil.devices.board_settings import BoardSettings
from hil.devices.clock import MonotonicClock, VirtualClock
from hil.errors import ConfigError, TransportClosedError, TransportTimeoutError
from sim_devices.board import BoardPort, FaultPlan, LoopbackWorld, MemoryBoardLink, SimulatedBoard

RATE_HZ = 192_000
DELAY = 53  # loopback cable, samples


def source(k: int, n: int) -> np.ndarray:
    """A deterministic transmission: a 5 kHz tone with a slow ramp, full scale 0.5."""
    t = (k + np.arange(n)) / RATE_HZ
    return 0.5 * np.sin(2 * np.pi * 5000.0 * t) * np.minimum(1.0, t / 0.05)


def streamed(seconds: float, faults: FaultPlan | None = None) -> tuple[Board, np.ndarray, int]:
    """Open, configure and start a board on virtual time, capture ``seconds`` of loopback."""
    clock = VirtualClock(tick_s=0.001)
    sim = SimulatedBoard(clock=clock, world=LoopbackWorld(DELAY), faults=faults)
    link = MemoryBoardLink(BoardPort(sim), timeout=0.0)
    settings = BoardSettings(sample_rate_hz=RATE_HZ, dac_channels=1, adc_channels=2)
    board = Board(link, settings=settings, virtual_time=clock, ring_seconds=4.0).open()
    board.configure()
    first = board.start(source)
    end = first + round(seconds * RATE_HZ)
    assert board.wait_for_samples(end, timeout_s=seconds + 1.0)
    data = board.read(first, end - first)
    return board, data, first


def test_no_thread_runs_beside_the_host_on_virtual_time() -> None:
    before = threading.active_count()
    board, _, _ = streamed(0.05)
    assert threading.active_count() == before
    board.close()


def test_the_loopback_returns_the_transmission_delayed_by_the_cable() -> None:
    board, data, _ = streamed(0.5)
    expected = np.round(source(0, data.shape[0] - DELAY) * 32767.0)
    got = data[DELAY:, 0].astype(float)
    np.testing.assert_allclose(got, expected, atol=1.0)
    assert not np.any(data[:DELAY, 0])
    assert board.ring is not None and board.ring.missing == 0
    assert board.annotations.of_kind(AnnotationKind.DAC_UNDERRUN) == []
    board.close()


def test_two_runs_on_virtual_time_are_identical() -> None:
    runs = [streamed(0.3) for _ in range(2)]
    (a, da, fa), (b, db, fb) = runs
    assert fa == fb
    np.testing.assert_array_equal(da, db)
    assert a.clock_fit is not None and b.clock_fit is not None
    assert a.clock_fit.pairs == b.clock_fit.pairs
    for board in (a, b):
        board.close()


def test_a_silent_board_times_out_after_the_virtual_timeout() -> None:
    clock = VirtualClock(tick_s=0.001)
    sim = SimulatedBoard(clock=clock, world=LoopbackWorld(0))
    link = MemoryBoardLink(BoardPort(sim), timeout=0.0)
    sim.receive_data = lambda data: None  # type: ignore[method-assign]  # hears nothing
    board = Board(link, virtual_time=clock, command_timeout_s=2.5)
    with pytest.raises(TransportTimeoutError, match=r"no VERSION within 2\.5 s of virtual time"):
        board.open()
    assert clock.now() == pytest.approx(2.5, abs=0.0011)


def test_an_unplugged_board_is_a_disconnect_and_the_next_command_fails() -> None:
    faults = FaultPlan()
    board, _, _ = streamed(0.1, faults)
    faults.disconnect()
    assert board.wait_for_samples(10**9, timeout_s=0.5) is False
    assert [a.kind for a in board.annotations.of_kind(AnnotationKind.DISCONNECT)] == [
        AnnotationKind.DISCONNECT
    ]
    with pytest.raises(TransportClosedError):
        board.stop()


def test_virtual_time_and_another_clock_are_refused() -> None:
    with pytest.raises(ConfigError, match=r"clock = .* give only virtual_time"):
        Board("sim://board", clock=MonotonicClock(), virtual_time=VirtualClock())


def _count_board_ticks(monkeypatch: pytest.MonkeyPatch) -> dict[str, int]:
    """Count the simulated board's ticks from now on (``["n"]``)."""
    ticks = {"n": 0}
    real_tick = SimulatedBoard.tick

    def counted(self: SimulatedBoard) -> None:
        ticks["n"] += 1
        real_tick(self)

    monkeypatch.setattr(SimulatedBoard, "tick", counted)
    return ticks


def test_skipping_the_quiet_ticks_changes_no_byte(monkeypatch: pytest.MonkeyPatch) -> None:
    """The virtual-time link skips the ticks on which the simulated board only captures
    samples short of the awaited index (``VirtualTimeBoardLink.quiet_until_ns``): the same
    samples, SYNC pairs and instants as a run that services the link at every tick, with far
    fewer board ticks."""
    ticks = _count_board_ticks(monkeypatch)
    quiet = streamed(0.3)
    quiet_ticks, ticks["n"] = ticks["n"], 0
    monkeypatch.setattr(VirtualTimeBoardLink, "quiet_until_ns", lambda self: None)
    every = streamed(0.3)
    (a, da, fa), (b, db, fb) = quiet, every
    assert fa == fb
    np.testing.assert_array_equal(da, db)
    assert a.clock_fit is not None and b.clock_fit is not None
    assert a.clock_fit.pairs == b.clock_fit.pairs
    assert a._clock.now() == b._clock.now()
    assert a.samples_received == b.samples_received
    assert quiet_ticks < ticks["n"] / 3
    for board in (a, b):
        board.close()


def test_the_simulated_board_is_quiet_only_while_it_has_nothing_else_due() -> None:
    clock = VirtualClock(tick_s=0.001)
    faults = FaultPlan()
    sim = SimulatedBoard(clock=clock, world=LoopbackWorld(DELAY), faults=faults)
    link = MemoryBoardLink(BoardPort(sim), timeout=0.0)
    settings = BoardSettings(sample_rate_hz=RATE_HZ, dac_channels=1, adc_channels=1)
    board = Board(link, settings=settings, virtual_time=clock, ring_seconds=4.0).open()
    board.configure()
    first = board.start(source)
    assert board.wait_for_samples(first + 1000, timeout_s=1.0)
    now = round(clock.now() * 1e9)
    index = sim.sample_index()
    assert now < link.quiet_until_ns(index + RATE_HZ, 1 << 16) <= now + 100_000_000  # a SYNC
    # the awaited index bounds it: 96 samples at 192 kHz is 0.5 ms
    assert link.quiet_until_ns(index + 96, 1 << 16) == sim._ns_at_index(index + 96)
    # so does the read size: 8 kB hold one ADC frame of mono int16 (2035 samples)
    frame = sim.adc_frame_samples
    assert link.quiet_until_ns(index + RATE_HZ, 8192) <= sim._ns_at_index(index + frame)
    assert link.quiet_until_ns(index + RATE_HZ, 4096) == now  # not even one frame fits
    faults.adc_overrun(10)  # a pending fault is due at once
    assert link.quiet_until_ns(first + RATE_HZ, 1 << 16) == now
    board.close()


def idle_then_streamed() -> tuple[Board, SimulatedBoard, list[tuple[int, float]], np.ndarray]:
    """Configure a board on virtual time, leave it idle (configured, not capturing) for
    1.3 s while the host sleeps in 70 ms steps, as a stage driver polls while it homes, then
    stream 0.1 s. Returns the driver, the simulated board, the SYNC pairs of the idle span
    and the samples."""
    clock = VirtualClock(tick_s=0.001)
    sim = SimulatedBoard(clock=clock, world=LoopbackWorld(DELAY))
    link = MemoryBoardLink(BoardPort(sim), timeout=0.0)
    settings = BoardSettings(sample_rate_hz=RATE_HZ, dac_channels=1, adc_channels=1)
    board = Board(link, settings=settings, virtual_time=clock, keepalive_ms=300).open()
    board.configure()
    for _ in range(19):
        clock.sleep(0.07)
    assert board.clock_fit is not None
    idle_pairs = board.clock_fit.pair_list()
    first = board.start(source)
    assert board.wait_for_samples(first + 19_200, timeout_s=1.0)
    return board, sim, idle_pairs, board.read(first, 19_200)


def test_skipping_the_ticks_of_an_idle_board_changes_no_byte(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """While the simulated board captures nothing, the link sleeps past the ticks before
    its next SYNC, STATUS or the host's next KEEPALIVE: the same SYNC pairs, keepalives,
    status reports and samples as servicing every tick, with a tick per event instead of
    one a millisecond."""
    ticks = _count_board_ticks(monkeypatch)
    quiet = idle_then_streamed()
    quiet_ticks, ticks["n"] = ticks["n"], 0
    monkeypatch.setattr(VirtualTimeBoardLink, "quiet_until_ns", lambda self: None)
    every = idle_then_streamed()
    (a, sim_a, pairs_a, data_a), (b, sim_b, pairs_b, data_b) = quiet, every
    # a SYNC each 0.1 s of the 1.33 s idle span (the first, at CONFIGURE, before the fit)
    assert [t for _, t in pairs_a] == pytest.approx([0.001 + 0.1 * k for k in range(1, 14)])
    assert pairs_a == pairs_b
    assert sim_a.host_frames == sim_b.host_frames  # the keepalives arrived alike
    assert a.last_status == b.last_status
    np.testing.assert_array_equal(data_a, data_b)
    assert a._clock.now() == b._clock.now()
    assert ticks["n"] > 1330  # every millisecond of the idle span
    assert quiet_ticks < ticks["n"] / 4
    for board in (a, b):
        board.close()
