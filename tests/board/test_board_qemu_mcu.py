"""The C reference firmware on an emulated Cortex-M4 (QEMU ``mps2-an386``), its UART0 on a
host pty, driven by the real :class:`~hil.devices.board.Board` driver: handshake, configure,
stream, stop, at a rate the emulated UART carries on an idle machine (8 kS/s x 2 channels,
int16).

QEMU's MPS2 has no DAC or ADC, so the firmware's analog path is a software loopback cable;
everything else is the firmware as a real board would run it. Needs ``make``,
``arm-none-eabi-gcc`` and ``qemu-system-arm``: without them these tests skip, except under
``HIL_REQUIRE_SYSTEM_DEPS=1`` (CI), where they fail. QEMU runs in real time: the test waits
on events (samples in the ring) with deadlock guards, never on elapsed time, and derives the
board's watchdog, its command timeout and the start lead from what the emulated UART carries,
measured at the start of the session (:func:`measured_uart_bytes_per_s`). What the UART
carries falls a hundredfold on a loaded machine (:func:`measured_uart_bytes_per_s`), so the
session asks it for no real-time throughput: the DAC samples compared are the whole DAC
source, in the board's DAC buffer before START, and their ADC replies fit the firmware's
link buffer.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable

import numpy as np
import pytest

from firmware_protocol import State
from hil.devices.board import Board
from hil.devices.board_settings import BoardSettings
from hil.transports.base import Transport
from hil.transports.serial_transport import open_serial
from sim_devices.board import qemu_mcu

RATE_HZ = 8_000
WAIT_S = 60.0  # deadlock guard, real seconds
#: The firmware's largest frame, bytes.
MAX_FRAME_BYTES = 8192
#: Sample frames the DAC plays and the ADC gives back, compared sample for sample: the whole
#: DAC source, within the firmware's DAC buffer (4096 frames), so all of it is sent before
#: START (the preload) and nothing after; its ADC frames (4 KB) within the firmware's link
#: buffer (CASFW_TX_BYTES = 20 KB), so none is lost while the UART is slow.
N_SAMPLES = 1024
PRELOAD_BYTES = N_SAMPLES * 2 * 2  # 2 int16 channels
#: Bytes of the probe that measures what the emulated UART carries now: empty frames (COBS
#: delimiters) the firmware skips, sent ahead of the handshake.
PROBE_BYTES = 2048
#: Deadlock guard of the probe (the handshake behind it) and bound on every timeout derived
#: from its rate, real seconds.
PROBE_GUARD_S = 120.0
#: Bound on the first start lead, real seconds (a refused START is retried with the lead
#: doubled, twice).
MAX_START_LEAD_S = 30.0


def measured_uart_bytes_per_s(transport: Transport, board: Board) -> float:
    """What QEMU's emulated UART carries from the host now, bytes/s: :data:`PROBE_BYTES`
    zero bytes written ahead of the board's handshake (``board.open()``), whose reply comes
    once the firmware has taken them, over the wall time to that reply (the handshake's own
    time counted in: the rate comes out low, the timeouts derived from it long).

    The UART's intake is one byte per pass of QEMU's main loop, and each pass needs both of
    QEMU's threads scheduled in turn: QEMU 7.2's CMSDK APB UART holds one received byte,
    refuses the next while it is held (no overrun: the firmware never sees one) and does not
    call ``qemu_chr_fe_accept_input()`` when the firmware reads it
    (``hw/char/cmsdk-apb-uart.c``), so the main loop reads the pty again only when the
    emulated MCU, polling its UART, wakes it; the main loop then waits for QEMU's lock,
    which the MCU takes for every register read. Measured on this 2-core machine: 64 kB/s
    idle; with 8 busy loops beside it (load 13-20), 120-200 B/s, the main-loop thread 79 %
    of the time in ``poll`` waiting for the MCU and the MCU's thread runnable throughout on
    5-7 % of a core (strace: one 1-byte ``readv`` per main-loop pass). Neither QEMU's
    settings nor the firmware's polling change it: both threads on one core (``taskset``),
    single-threaded TCG and ``-icount shift=5,sleep=off`` took 136-181 B/s at the same
    load; an MCU idling in WFI between passes (tried) cut QEMU's idle CPU from 0.42 to 0.05
    cores but took bytes that draw no reply at one per 1 ms tick (1.3-1.8 kB/s).
    """
    t0 = time.monotonic()
    transport.write(bytes(PROBE_BYTES))
    board.open()
    return PROBE_BYTES / (time.monotonic() - t0)


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
    dac = rng.integers(-20000, 20000, (N_SAMPLES, 2)).astype(np.int16)
    with qemu_mcu.QemuBoard() as mcu:
        transport = open_serial(mcu.port_name, timeout=0.05)
        board = Board(transport, command_timeout_s=PROBE_GUARD_S, ring_seconds=4.0)
        try:
            rate = measured_uart_bytes_per_s(transport, board)

            def uart_s(n_bytes: int, times: float) -> float:
                return min(PROBE_GUARD_S, times * n_bytes / rate)

            # The board's watchdog is fed by whole host frames: it must outlast the largest
            # one crossing the UART, or it fires mid-preload and empties the DAC buffer.
            # Timeouts are 20 times what the UART needs at the measured rate (the watchdog
            # for one frame, START's reply for the preload ahead of it), at least the
            # driver's own; the start lead covers the preload twice (a START refused as
            # passed is retried with the lead doubled).
            board.keepalive_ms = min(65_535, max(1000, round(1e3 * uart_s(MAX_FRAME_BYTES, 20))))
            board.command_timeout_s = max(5.0, uart_s(PRELOAD_BYTES + MAX_FRAME_BYTES, 20))
            board.start_lead_s = min(MAX_START_LEAD_S, max(2.0, uart_s(PRELOAD_BYTES, 2)))
            assert board.version is not None and board.version.board_serial == 0x4D500386
            assert board.capabilities is not None
            assert board.capabilities.sample_rates_hz == (16_000, 8_000)
            board.configure(BoardSettings(sample_rate_hz=RATE_HZ))
            first = board.start(iter([dac]))
            # The first sample comes a start lead after START (the last attempt's: 4 leads).
            assert board.wait_for_samples(first + N_SAMPLES, WAIT_S + 4 * board.start_lead_s), (
                f"UART measured at {rate:.0f} B/s"
            )
            got = board.read(first, N_SAMPLES)
            board.stop()
            assert board.state is State.STOPPED
            # The loopback cable has no delay: the ADC holds what the DAC played, sample for
            # sample (all of it was in the DAC buffer before START; the DAC runs dry after).
            np.testing.assert_array_equal(got, dac)
            # Nothing lost or damaged on the link. The board streams on until STOP: where
            # its link buffer fills faster than the UART drains it, it drops whole ADC
            # frames as overruns (sample gaps past the compared samples, counted by the
            # board), never part of a frame.
            stats = board.protocol_stats
            assert stats["crc_errors"] == stats["cobs_errors"] == stats["sequence_gaps"] == 0
        finally:
            board.close()
            transport.close()
