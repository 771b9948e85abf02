"""The board driver's links on their own (:mod:`hil.devices.board_link`): the shared part
(queue, flush, one read handed to the driver, a loss recorded once) and what each form does
when the link drops: the threaded link's reader reconnects, and a reader that fails is raised
by the next wait; the virtual-time link stays lost and its wait says so. No board and no
protocol: a transport scripted by the test and hooks that record what the link asked."""

from __future__ import annotations

import itertools
import threading
from dataclasses import dataclass, field

import pytest

from hil.devices.board import Board
from hil.devices.board_errors import BoardError
from hil.devices.board_link import LinkHooks, ThreadedBoardLink
from hil.devices.board_link_virtual import VirtualTimeBoardLink
from hil.devices.clock import VirtualClock
from hil.errors import TransportClosedError, TransportTimeoutError
from sim_devices.stage.clock import ManualClock

URL = "test://link"
GUARD_S = 30.0  # deadlock guard of the threaded waits, real seconds (never reached)


class ScriptedTransport:
    """Reads give the scripted chunks, then ``b""``; once unplugged, reads and writes raise."""

    timeout = 0.0
    url = URL

    def __init__(self, chunks: list[bytes] | None = None) -> None:
        self.chunks = list(chunks or [])
        self.written: list[bytes] = []
        self.unplugged = threading.Event()

    def read(self, size: int) -> bytes:
        if self.unplugged.is_set():
            raise TransportClosedError(f"{URL}: unplugged")
        return self.chunks.pop(0)[:size] if self.chunks else b""

    def write(self, data: bytes) -> int:
        if self.unplugged.is_set():
            raise TransportClosedError(f"{URL}: unplugged")
        self.written.append(data)
        return len(data)

    def close(self) -> None:
        pass


@dataclass
class Recorder:
    """Hooks that record what the link asked of the driver."""

    received: list[bytes] = field(default_factory=list)
    lost: list[str] = field(default_factory=list)
    reconnects: int = 0
    close_on: bytes | None = None  # a chunk that ends the session
    reconnect_error: BaseException | None = None

    def receive(self, data: bytes) -> str | None:
        self.received.append(data)
        return "the board closed the session" if data == self.close_on else None

    def reconnect(self) -> None:
        self.reconnects += 1
        if self.reconnect_error is not None:
            raise self.reconnect_error

    def hooks(self) -> LinkHooks:
        return LinkHooks(
            url=lambda: URL,
            receive=self.receive,
            link_lost=self.lost.append,
            refusal=lambda: None,
            feed_dac=lambda: False,
            keepalive_if_due=lambda: None,
            next_keepalive_s=lambda: None,
            dac_pending=lambda: False,
            reconnect=self.reconnect,
        )


def test_queued_frames_are_written_in_order_in_one_write() -> None:
    link = ThreadedBoardLink(ManualClock(), Recorder().hooks())
    transport = ScriptedTransport()
    link.connect(transport)
    with link.lock:
        link.queue(b"\x01\x02")
        link.queue(b"\x03")
    assert link.queued
    link.flush()
    assert transport.written == [b"\x01\x02\x03"] and not link.queued


def test_a_new_transport_drops_the_frames_queued_for_the_old_one() -> None:
    link = ThreadedBoardLink(ManualClock(), Recorder().hooks())
    link.connect(ScriptedTransport())
    with link.lock:
        link.queue(b"old session")
    fresh = ScriptedTransport()
    link.connect(fresh)
    link.flush()
    assert fresh.written == [] and link.up


def test_pump_hands_what_it_read_to_the_driver_and_a_closed_session_is_one_loss() -> None:
    recorder = Recorder(close_on=b"bye")
    link = ThreadedBoardLink(ManualClock(), recorder.hooks())
    link.connect(ScriptedTransport([b"abc", b"bye"]))
    assert link.pump_once() is True
    assert link.pump_once() is False
    assert link.pump_once() is False  # down: nothing read
    assert recorder.received == [b"abc", b"bye"]
    assert recorder.lost == ["the board closed the session"] and not link.up


def test_the_threaded_reader_reconnects_and_a_failed_reader_is_raised_by_the_next_wait() -> None:
    recorder = Recorder(reconnect_error=TransportClosedError(f"{URL}: gave up"))
    link = ThreadedBoardLink(ManualClock(), recorder.hooks())
    transport = ScriptedTransport()
    link.open(lambda: link.connect(transport))
    try:
        transport.unplugged.set()
        with pytest.raises(BoardError, match=r"^test://link: reader failed$") as caught:
            link.wait(lambda: False, GUARD_S, "a reply")
        assert isinstance(caught.value.__cause__, TransportClosedError)
        assert recorder.reconnects == 1
        assert recorder.lost == [f"{URL}: unplugged"]
    finally:
        link.close()


def test_a_threaded_wait_without_reader_pumps_and_times_out_naming_what_it_waited_for() -> None:
    link = ThreadedBoardLink(ManualClock(), Recorder().hooks())
    link.connect(ScriptedTransport())
    with pytest.raises(TransportTimeoutError, match=r"test://link: no VERSION within 0\.01 s"):
        link.wait(lambda: False, 0.01, "VERSION")


class SteppingMonotonic:
    """A stand-in for ``time.monotonic`` that moves 1 s at every reading: a wait's deadline
    is then reached by counting its own checks, not by how fast this machine runs them."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        self.now += 1.0
        return self.now


def test_a_wait_that_sees_progress_waits_on_and_one_that_sees_none_times_out(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from hil.devices import board_link

    link = ThreadedBoardLink(ManualClock(), Recorder().hooks())
    link.connect(ScriptedTransport())
    monkeypatch.setattr(board_link.time, "monotonic", SteppingMonotonic())
    link._reader = threading.Thread(target=lambda: None)  # a reader, not this thread
    checks = itertools.count()

    def moving() -> int:  # grows at every look of the wait
        return next(checks)

    # About 30 checks, each seconds of "time" later, with a 5 s timeout: it waits on while the
    # awaited thing moves.
    link.wait(lambda: moving() >= 99, 5.0, "a reply", progress=moving)
    with pytest.raises(TransportTimeoutError, match=r"^test://link: no a reply within 5.0 s"):
        link.wait(lambda: False, 5.0, "a reply", progress=lambda: 7)


def test_the_virtual_link_stays_lost_and_its_wait_says_so() -> None:
    clock = VirtualClock(tick_s=0.001)
    recorder = Recorder()
    link = VirtualTimeBoardLink(clock, recorder.hooks())
    transport = ScriptedTransport([b"hello"])
    link.open(lambda: link.connect(transport))
    clock.sleep(0.002)
    assert recorder.received == [b"hello"]
    transport.unplugged.set()
    with pytest.raises(TransportClosedError, match=r"link lost while waiting for a reply"):
        link.wait(lambda: False, 1.0, "a reply")
    assert clock.now() == pytest.approx(0.003)  # lost at the first tick of the wait
    assert recorder.reconnects == 0 and recorder.lost == [f"{URL}: unplugged"]
    link.close()
    clock.sleep(0.01)
    assert recorder.received == [b"hello"]  # detached: the clock no longer services it


def test_the_virtual_link_times_out_on_virtual_time() -> None:
    clock = VirtualClock(tick_s=0.001)
    link = VirtualTimeBoardLink(clock, Recorder().hooks())
    link.open(lambda: link.connect(ScriptedTransport()))
    with pytest.raises(TransportTimeoutError, match=r"no SYNC within 0\.5 s of virtual time"):
        link.wait(lambda: False, 0.5, "SYNC")
    assert clock.now() == pytest.approx(0.5)
    link.close()


def test_a_connect_that_fails_leaves_nothing_attached_to_the_clock() -> None:
    clock = VirtualClock(tick_s=0.001)
    recorder = Recorder()
    link = VirtualTimeBoardLink(clock, recorder.hooks())
    transport = ScriptedTransport([b"never read"])

    def connect() -> None:
        link.connect(transport)
        raise TransportClosedError(f"{URL}: refused")

    with pytest.raises(TransportClosedError, match="refused"):
        link.open(connect)
    clock.sleep(0.01)
    assert recorder.received == []


def test_the_driver_chooses_its_link_once_from_its_clock() -> None:
    assert isinstance(Board("sim://board")._link, ThreadedBoardLink)
    clock = VirtualClock()
    board = Board("sim://board", virtual_time=clock)
    assert isinstance(board._link, VirtualTimeBoardLink) and board._clock is clock
