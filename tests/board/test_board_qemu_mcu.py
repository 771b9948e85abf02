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

import os
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
#: What the emulated UART carries when QEMU has a core to itself, bytes/s (measured in
#: firmware_protocol/c/mcu/mps2_an386.c), and the firmware's largest frame and DAC buffer.
UART_BYTES_PER_S = 64_000
MAX_FRAME_BYTES = 8192
PRELOAD_BYTES = 4096 * 2 * 2  # its DAC buffer: 4096 frames of 2 int16 channels


def uart_seconds(n_bytes: int) -> float:
    """Seconds the emulated UART takes to carry ``n_bytes`` on this machine now: at its rate
    times the share of a core QEMU can expect (cores / the load average, at most 1)."""
    cores = os.cpu_count() or 1
    share = min(1.0, cores / max(os.getloadavg()[0], 1e-9))
    return n_bytes / (UART_BYTES_PER_S * share)


@pytest.fixture(autouse=True)
def _tools(require_system: Callable[[bool, str], None]) -> None:
    missing = qemu_mcu.tools_missing()
    require_system(missing is None, f"Cortex-M4 build or QEMU unavailable: {missing}")


def test_cortex_m4_image_fits_a_small_mcu() -> None:
    report = qemu_mcu.build_image()
    sizes = re.search(r"^\s*(\d+)\s+(\d+)\s+(\d+)", report, re.M)
    assert sizes is not None, report
    text, data, bss = (int(v) for v in sizes.groups())
    assert 4_000 < text < 64_000  # flash: code and constants, bytes
    assert data + bss < 256_000  # RAM without the stack: fixed buffers only, no heap


@pytest.mark.slow
def test_board_driver_completes_a_session_on_the_emulated_mcu() -> None:
    rng = np.random.default_rng(7)
    dac = rng.integers(-20000, 20000, (2 * RATE_HZ, 2)).astype(np.int16)
    with qemu_mcu.QemuBoard() as mcu:
        transport = open_serial(mcu.port_name, timeout=0.05)
        # The board's watchdog is fed by whole host frames: it must outlast the largest one
        # crossing the UART, or it fires mid-preload and empties the DAC buffer (on a busy
        # machine QEMU's UART slows to a few kB/s). Timeouts are 20 times what the UART
        # needs now (the watchdog for one frame, START's reply for the preload ahead of it),
        # at least the driver's own; the start lead covers the preload twice (a START
        # refused as passed is retried with the lead doubled).
        board = Board(
            transport,
            keepalive_ms=min(65_535, max(1000, round(20e3 * uart_seconds(MAX_FRAME_BYTES)))),
            command_timeout_s=max(5.0, 20 * uart_seconds(PRELOAD_BYTES + MAX_FRAME_BYTES)),
            ring_seconds=4.0,
            start_lead_s=min(10.0, max(2.0, 2 * uart_seconds(PRELOAD_BYTES))),
        )
        try:
            board.open()
            assert board.version is not None and board.version.board_serial == 0x4D500386
            assert board.capabilities is not None
            assert board.capabilities.sample_rates_hz == (16_000, 8_000)
            board.configure(BoardSettings(sample_rate_hz=RATE_HZ))
            first = board.start(iter([dac]))
            n = RATE_HZ // 2
            assert board.wait_for_samples(first + n, WAIT_S)
            # Read before STOP: on a slow UART STOP waits behind the DAC data already sent,
            # while the board streams on into the ring.
            got = board.read(first, n)
            board.stop()
            assert board.state is State.STOPPED
            # The loopback cable has no delay: the ADC holds what the DAC played, sample for
            # sample, and silence only where the DAC ran dry (an emulator starved of CPU
            # feeds its UART late; each such run is counted as a DAC underrun).
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
