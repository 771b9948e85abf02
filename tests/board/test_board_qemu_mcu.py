"""The C reference firmware on an emulated Cortex-M4 (QEMU ``mps2-an386``), its UART0 on a
host pty, driven by the real :class:`~hil.devices.board.Board` driver: handshake, configure,
stream, stop, at a rate the emulated UART carries (8 kS/s x 2 channels, int16).

QEMU's MPS2 has no DAC or ADC, so the firmware's analog path is a software loopback cable;
everything else is the firmware as a real board would run it. Needs ``make``,
``arm-none-eabi-gcc`` and ``qemu-system-arm``: without them these tests skip, except under
``HIL_REQUIRE_SYSTEM_DEPS=1`` (CI), where they fail. QEMU runs in real time: the test waits
on events (samples in the ring) with a deadlock guard, never on elapsed time.
"""

from __future__ import annotations

import re
from collections.abc import Callable

import numpy as np
import pytest

from firmware_protocol import State
from hil.devices.board import Board
from hil.devices.board_settings import BoardSettings
from hil.transports.serial_transport import open_serial
from sim_devices.board import qemu_mcu

RATE_HZ = 8_000
WAIT_S = 60.0  # deadlock guard, real seconds


@pytest.fixture(autouse=True)
def _tools(require_system: Callable[[bool, str], None]) -> None:
    missing = qemu_mcu.tools_missing()
    require_system(missing is None, f"Cortex-M4 build or QEMU unavailable: {missing}")


def test_cortex_m4_image_fits_a_small_mcu() -> None:
    report = qemu_mcu.build_image()
    text, data, bss = (
        int(v) for v in re.search(r"^\s*(\d+)\s+(\d+)\s+(\d+)", report, re.M).groups()
    )  # type: ignore[union-attr]
    assert 4_000 < text < 64_000  # flash: code and constants, bytes
    assert data + bss < 256_000  # RAM without the stack: fixed buffers only, no heap


@pytest.mark.slow
def test_board_driver_completes_a_session_on_the_emulated_mcu() -> None:
    rng = np.random.default_rng(7)
    dac = rng.integers(-20000, 20000, (2 * RATE_HZ, 2)).astype(np.int16)
    with qemu_mcu.QemuBoard() as mcu:
        transport = open_serial(mcu.port_name, timeout=0.05)
        # The start lead covers the DAC preload over the emulated UART (about 64 kB/s: 0.5 s
        # for the firmware's 16 k-sample buffer, several times that when QEMU shares a busy
        # machine); a START refused as passed is retried with the lead doubled (4, 8 s).
        board = Board(transport, keepalive_ms=1000, ring_seconds=4.0, start_lead_s=2.0)
        try:
            board.open()
            assert board.version is not None and board.version.board_serial == 0x4D500386
            assert board.capabilities is not None
            assert board.capabilities.sample_rates_hz == (16_000, 8_000)
            board.configure(BoardSettings(sample_rate_hz=RATE_HZ))
            first = board.start(iter([dac]))
            n = RATE_HZ // 2
            assert board.wait_for_samples(first + n, WAIT_S)
            board.stop()
            assert board.state is State.STOPPED
            # The loopback cable has no delay: the ADC holds what the DAC played, sample for
            # sample, and silence only where the DAC ran dry (an emulator starved of CPU
            # feeds its UART late; each such run is counted as a DAC underrun).
            got = board.read(first, n)
            equal = np.all(got == dac[:n], axis=1)
            silent = np.all(got == 0, axis=1)
            assert np.all(equal | silent)
            assert np.count_nonzero(equal) >= 0.9 * n
            assert board.last_status is not None
            assert np.all(equal) or board.last_status.dac_underruns >= 1
            assert board.gaps.gap_samples == 0
            stats = board.protocol_stats
            assert stats["crc_errors"] == stats["cobs_errors"] == stats["sequence_gaps"] == 0
        finally:
            board.close()
            transport.close()
