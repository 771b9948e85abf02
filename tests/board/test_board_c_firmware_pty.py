"""The C reference firmware served on a pty (``hil sim-serve board --impl c`` and
``sim://board?impl=c``), driven by the real host driver.

The firmware runs in its own process in real time; the tests wait on events (samples in the
ring, replies) with deadlock guards, never on elapsed time. The build needs ``cc`` and
``make``: without them these tests skip, except under ``HIL_REQUIRE_SYSTEM_DEPS=1`` (CI).
"""

from __future__ import annotations

import io
import threading
from collections.abc import Callable
from contextlib import redirect_stdout

import numpy as np
import pytest
import serial

from firmware_protocol import NEED_DATA, Capabilities, Connection, Role, State
from firmware_protocol import Version as VersionMessage
from hil.cli.main import build_parser
from hil.devices.board import Board
from hil.devices.board_settings import BoardSettings
from hil.errors import ConfigError
from hil.transports import open_transport
from sim_devices.board import c_firmware

RATE_HZ = 96_000
DELAY = 37
WAIT_S = 30.0  # deadlock guard, real seconds


@pytest.fixture(autouse=True)
def _c_toolchain(require_system: Callable[[bool, str], None]) -> None:
    missing = c_firmware.toolchain_missing()
    require_system(missing is None, f"C firmware not buildable: {missing}")


def test_sim_serve_board_impl_c_prints_a_port_speaking_the_protocol() -> None:
    from hil.cli import sim_serve

    args = build_parser().parse_args(["sim-serve", "board", "--impl", "c"])
    stop, out, status = threading.Event(), io.StringIO(), []

    def run() -> None:
        with redirect_stdout(out):
            status.append(sim_serve.run(args, stop))

    thread = threading.Thread(target=run)
    thread.start()
    try:
        for _ in range(int(WAIT_S * 1000)):
            if out.getvalue().endswith("\n"):
                break
            threading.Event().wait(0.001)
        port_name = out.getvalue().strip()
        assert port_name.startswith("/dev/")  # the first line is the pty, as for Python
        port = serial.serial_for_url(port_name, timeout=5)
        host = Connection(Role.HOST)
        port.write(host.send(host.make_hello()))
        host.receive_data(port.read_until(b"\x00") + port.read_until(b"\x00"))
        version, caps = host.next_event(), host.next_event()
        assert isinstance(version, VersionMessage) and version.board_serial == 0x0B0A4D01
        assert isinstance(caps, Capabilities) and caps.sample_rates_hz[0] == 1_000_000
        assert host.next_event() is NEED_DATA and host.state is State.READY
        port.close()
    finally:
        stop.set()
        thread.join()
    assert status == [0]


def test_impl_c_refuses_options_it_cannot_honour() -> None:
    with pytest.raises(ConfigError, match=r"via = 'memory'.*pty"):
        open_transport("sim://board?impl=c&via=memory")
    with pytest.raises(ConfigError, match=r"impl = 'rust'.*one of python, c"):
        open_transport("sim://board?impl=rust")


def test_board_driver_streams_through_the_c_firmware() -> None:
    transport = open_transport(f"sim://board?impl=c&delay={DELAY}", timeout=0.05)
    board = Board(transport, keepalive_ms=500, ring_seconds=2.0)
    rng = np.random.default_rng(5)
    dac = rng.integers(-20000, 20000, (RATE_HZ, 2)).astype(np.int16)  # 1 s
    try:
        board.open()
        assert board.version is not None and board.version.protocol_major == 2
        board.configure(BoardSettings(sample_rate_hz=RATE_HZ))
        first = board.start(iter([dac]))
        n = RATE_HZ // 2
        assert board.wait_for_samples(first + n, WAIT_S)
        board.stop()
        assert board.state is State.STOPPED
        # Every index from the start exactly once; the ADC hears the DAC 37 samples late.
        expected = np.zeros((n, 2), dtype=np.int16)
        expected[DELAY:] = dac[: n - DELAY]
        np.testing.assert_array_equal(board.read(first, n), expected)
        assert board.gaps.gap_samples == board.gaps.overlap_samples == 0
        stats = board.protocol_stats
        assert stats["crc_errors"] == stats["cobs_errors"] == stats["sequence_gaps"] == 0
        assert board.last_status is not None and board.last_status.dac_underruns == 0
    finally:
        board.close()
        transport.close()
