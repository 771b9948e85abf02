"""Bytes keep flowing through :class:`sim_devices.pty_endpoint.PtyEndpoint` while the device
computes a slow tick, and the simulated board keeps its DAC FIFO fed through such ticks.

The tank run's simulated board computes its acoustic world once per 100 ms tick; a moving
target made a tick take 0.2 s. When one thread both ran the ticks and moved the bytes, only
what the pty buffers (about 14 KB) left between two ticks: ADC data piled up in the
endpoint, CREDIT messages waited behind it, and the host could not refill the DAC FIFO in
time (an intermittent DAC underrun in ``hil tank-run``). These tests fail on that design.

Real time, real ptys; no assertion on a duration: the slow ticks only create the conditions,
and what is checked is counts of bytes, their order and the board's underrun counter.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
import pytest
import serial

from hil.devices.board import Board
from hil.devices.board_settings import BoardSettings
from sim_devices.board import BoardSpec, SimulatedBoardOnPty
from sim_devices.pty_endpoint import PtyEndpoint
from tests.thread_lateness import LatenessProbe

TICK_S = 0.15  # how long each slow tick takes, s
#: A stall of the whole process this long (s, a third of the test's 0.68 s DAC FIFO) can run
#: the FIFO dry whatever the pump does (tests/thread_lateness.py).
FIFO_STALL_S = 0.22
CHUNK = 48_000  # bytes a slow tick produces (more than the pty buffers, about 14 KB)


def busy(seconds: float) -> None:
    """Hold the CPU (and the GIL, between switch intervals) for ``seconds``, as a world
    computing in Python and NumPy does."""
    end = time.monotonic() + seconds
    x = 0
    while time.monotonic() < end:
        x += 1


class SlowProducer:
    """Each tick computes for :data:`TICK_S` and then emits :data:`CHUNK` bytes of a running
    counter. It records, when each tick's computing ends, how many bytes the host has read
    (``host_read``, set by the test) and how many host bytes it has received."""

    def __init__(self, *, compute: bool, ticks: int) -> None:
        self.compute = compute
        self.ticks_left = ticks
        self.host_read: Callable[[], int] = lambda: 0
        self.host_read_at_tick: list[int] = []
        self.received = bytearray()
        self.received_at_tick: list[int] = []
        self._out = bytearray()
        self._next = 0
        self.connected = threading.Event()
        self.done = threading.Event()

    def connection_made(self) -> None:
        self.connected.set()

    def receive_data(self, data: bytes) -> None:
        self.received += data

    def data_to_send(self) -> bytes:
        out, self._out = bytes(self._out), bytearray()
        return out

    def tick(self) -> None:
        if not self.connected.is_set():
            return  # nothing to measure before the host holds the port
        if self.ticks_left == 0:
            self.done.set()
            return
        busy(TICK_S) if self.compute else time.sleep(TICK_S)
        self.host_read_at_tick.append(self.host_read())
        self.received_at_tick.append(len(self.received))
        counter = (np.arange(self._next, self._next + CHUNK) % 251).astype(np.uint8)
        self._out += counter.tobytes()
        self._next += CHUNK
        self.ticks_left -= 1


def read_all(port: serial.Serial, n: int, sink: bytearray) -> None:
    """Read whatever arrives until ``n`` bytes came (or a silence of the port's timeout)."""
    while len(sink) < n:
        chunk = port.read(max(1, min(port.in_waiting, n - len(sink))))
        if not chunk:
            return
        sink += chunk


@pytest.mark.slow
@pytest.mark.parametrize("compute", [False, True], ids=["sleeping-tick", "computing-tick"])
def test_output_leaves_while_the_device_ticks(compute: bool) -> None:
    ticks = 8
    device = SlowProducer(compute=compute, ticks=ticks)
    got = bytearray()
    device.host_read = lambda: len(got)
    with PtyEndpoint(device, poll_interval=0.01) as endpoint:
        # The reader waits out a silence of up to 30 s: on a machine busy with other work
        # the last tick's bytes can take seconds to be scheduled out.
        port = serial.serial_for_url(endpoint.port_name, timeout=30)
        reader = threading.Thread(target=read_all, args=(port, ticks * CHUNK, got))
        reader.start()
        assert device.done.wait(60), "the device never finished its ticks"
        reader.join(60)
        port.close()
        expected = (np.arange(ticks * CHUNK) % 251).astype(np.uint8).tobytes()
        assert bytes(got) == expected, f"{len(got)} of {len(expected)} bytes"  # all, in order
        assert endpoint.output_backlog == 0
    # While tick k computed, the output of the ticks before it reached the host, give or
    # take what one tick's scheduling leaves queued (a computing tick holds the GIL: the I/O
    # thread runs between its switch intervals; 27 KB measured on a busy machine). The old
    # single-thread pump let out one pty buffer (about 14 KB) per tick, so the host fell
    # 34 KB further behind at every tick: more than a whole tick's output by the second.
    behind = [k * CHUNK - read for k, read in enumerate(device.host_read_at_tick)]
    assert max(behind) < CHUNK, behind


@pytest.mark.slow
def test_host_bytes_arrive_while_the_device_ticks() -> None:
    # 192 KB written at once while ticks of 0.15 s run: the I/O thread takes them in as the
    # host writes, so the device has all of them by its third tick after the write. The
    # old pump read only between ticks, one pty buffer at a time.
    device = SlowProducer(compute=False, ticks=12)
    payload = (np.arange(192_000) % 253).astype(np.uint8).tobytes()
    with PtyEndpoint(device, poll_interval=0.01) as endpoint:
        port = serial.serial_for_url(endpoint.port_name, timeout=5, write_timeout=10)
        drain = threading.Thread(target=read_all, args=(port, 12 * CHUNK, bytearray()))
        drain.start()
        assert device.connected.wait(10)
        port.write(payload)
        written_at = len(device.received_at_tick)  # ticks finished before the write ended
        assert device.done.wait(30)
        drain.join(30)
        port.close()
    assert bytes(device.received) == payload
    # written_at + 2: the tick right after the write may begin before the I/O thread has
    # read the last bytes out of the pty (the old pump fails this too: 4 KB per tick).
    later = device.received_at_tick[written_at + 2 :]
    assert later and later[0] == len(payload), device.received_at_tick


class FailingDevice:
    def receive_data(self, data: bytes) -> None:
        pass

    def data_to_send(self) -> bytes:
        return b""

    def tick(self) -> None:
        raise ValueError("world exploded at sample 42")


def test_a_failing_device_stops_the_endpoint_and_close_reports_it() -> None:
    endpoint = PtyEndpoint(FailingDevice(), poll_interval=0.001).start()
    deadline = time.monotonic() + 10
    while not endpoint._stop.is_set() and time.monotonic() < deadline:
        time.sleep(0.001)
    assert endpoint._stop.is_set()  # the failure stopped both threads by itself
    with pytest.raises(RuntimeError, match=r"pty endpoint pump failed: ValueError.*sample 42"):
        endpoint.close()


class SlowWorld:
    """A board world that takes :data:`TICK_S` per call (the tank's acoustic world with a
    moving target took 0.2 s per 100 ms tick) and returns silence on two ADC inputs."""

    def __call__(self, dac_block: np.ndarray, first_sample: int, /) -> np.ndarray:
        time.sleep(TICK_S)
        return np.zeros((dac_block.shape[0], 2))


@pytest.mark.slow
def test_board_keeps_its_dac_fed_through_slow_world_ticks() -> None:
    # 48 kHz, 2 ADC channels int16: 192 KB/s of ADC data, 29 KB per slow tick. A 32768-sample
    # DAC FIFO holds 0.68 s. With the old pump the CREDIT messages fell 80 ms further behind
    # the ADC data at every tick and the FIFO ran dry within about 2 s.
    rate = 48_000
    spec = BoardSpec(dac_buffer_samples=1 << 15)
    settings = BoardSettings(sample_rate_hz=rate, dac_channels=1, adc_channels=2)
    tone = 0.25 * np.sin(2 * np.pi * 1000.0 / rate * np.arange(rate))

    def source(k: int, n: int) -> np.ndarray:
        return np.resize(np.roll(tone, -(k % rate)), n)

    with (
        LatenessProbe() as probe,
        SimulatedBoardOnPty(spec, world=SlowWorld(), poll_interval=0.1) as sim,
        Board(sim.port_name, settings=settings, ring_seconds=8.0) as board,
    ):
        board.configure()
        start = board.start(source)
        end = start + 4 * rate  # 4 s of streaming
        assert board.wait_for_samples(end, timeout_s=30), "the board stopped streaming"
        backlog = sim.endpoint.output_backlog
        underruns = sim.call(lambda b: b.dac_underruns)
        late = sim.call(lambda b: b._fifo.late_samples)
        board.stop()
    seen = (
        f"underruns {underruns}, late samples {late}, backlog {backlog} B, {probe.longest_s=:.3f} s"
    )
    print(seen)
    # The pump's credits keep pace with its ADC data: the output queue stays short.
    assert backlog < 60_000, seen  # at most about two ticks' output still queued
    # So the FIFO never runs dry, unless the machine kept this process (its host writer and
    # the simulated board both) off the CPUs for a third of the FIFO's 0.68 s.
    if probe.longest_s < FIFO_STALL_S:
        assert underruns == 0, seen
        assert late == 0, seen
    assert board.ring is not None and board.ring.missing == 0
