"""The C reference firmware (``firmware_protocol/c``) as a device under test and on a pty.

:func:`build` runs ``make host`` there (a C99 compiler and make are needed; the build is
incremental). :class:`CBoardStepper` loads the shared library with :mod:`ctypes` and steps
the firmware on an injected board clock, exactly as
:class:`~sim_devices.board.stepper.PythonBoardStepper` steps the Python board, so both run
the same golden conversations and conformance tests. :class:`CFirmwareOnPty` runs the
firmware's pty server (real time) for every tool that opens a serial port.
"""

from __future__ import annotations

import ctypes
import shutil
import subprocess
import threading
from pathlib import Path
from types import TracebackType
from typing import Any

import firmware_protocol
from firmware_protocol import SampleFormat
from firmware_protocol.conversations import BOARD

FIRMWARE_DIR = Path(firmware_protocol.__file__).with_name("c")
"""The C sources and their Makefile."""
BUILD_DIR = FIRMWARE_DIR / "build"
LIBRARY = BUILD_DIR / "libcasfw_sim.so"
PTY_SERVER = BUILD_DIR / "casfw-pty"

_build_lock = threading.Lock()


class CFirmwareUnavailable(RuntimeError):
    """The C firmware cannot be built here (no compiler or make, or the build failed)."""


def toolchain_missing() -> str | None:
    """Why the host build cannot run here (a missing tool), or None if it can."""
    for tool in ("make", "cc"):
        if shutil.which(tool) is None:
            return (
                f"'{tool}' is not installed: install a C compiler and make"
                " (Debian: apt-get install gcc make) to build firmware_protocol/c"
            )
    return None


def build() -> None:
    """``make host`` in ``firmware_protocol/c`` (incremental); raises CFirmwareUnavailable."""
    missing = toolchain_missing()
    if missing:
        raise CFirmwareUnavailable(missing)
    with _build_lock:
        result = subprocess.run(
            ["make", "-s", "-C", str(FIRMWARE_DIR), "host"],
            capture_output=True,
            text=True,
            check=False,
        )
    if result.returncode != 0:
        raise CFirmwareUnavailable(
            f"building the C firmware failed (make -C {FIRMWARE_DIR} host):\n"
            + (result.stderr or result.stdout)[-2000:]
        )


class _Config(ctypes.Structure):
    """``casfw_config`` of ``casfw.h``, field for field."""

    _fields_ = [
        ("dac_channels", ctypes.c_uint8),
        ("adc_channels", ctypes.c_uint8),
        ("formats", ctypes.c_uint8),
        ("n_rates", ctypes.c_uint8),
        ("sample_rates_hz", ctypes.c_uint32 * 32),
        ("dac_buffer_samples", ctypes.c_uint32),
        ("adc_buffer_samples", ctypes.c_uint32),
        ("max_frame_len", ctypes.c_uint16),
        ("gain_min_cdb", ctypes.c_int16),
        ("gain_max_cdb", ctypes.c_int16),
        ("fw_major", ctypes.c_uint8),
        ("fw_minor", ctypes.c_uint8),
        ("fw_patch", ctypes.c_uint16),
        ("board_serial", ctypes.c_uint32),
        ("sync_interval_ns", ctypes.c_uint64),
        ("status_interval_ns", ctypes.c_uint64),
        ("temperature_cdeg", ctypes.c_int16),
    ]


def _config(board: dict[str, Any]) -> _Config:
    rates = board["sample_rates_hz"]
    cfg = _Config()
    cfg.dac_channels = board["dac_channels"]
    cfg.adc_channels = board["adc_channels"]
    cfg.formats = sum(SampleFormat[name].mask_bit for name in board["formats"])
    cfg.n_rates = len(rates)
    for i, rate in enumerate(rates):
        cfg.sample_rates_hz[i] = rate
    cfg.dac_buffer_samples = board["dac_buffer_samples"]
    cfg.adc_buffer_samples = board["adc_buffer_samples"]
    cfg.max_frame_len = board["max_frame_len"]
    cfg.gain_min_cdb = board["gain_min_cdb"]
    cfg.gain_max_cdb = board["gain_max_cdb"]
    cfg.fw_major, cfg.fw_minor, cfg.fw_patch = board["firmware"]
    cfg.board_serial = board["board_serial"]
    cfg.sync_interval_ns = board["sync_interval_ns"]
    cfg.status_interval_ns = board["status_interval_ns"]
    cfg.temperature_cdeg = board["temperature_cdeg"]
    return cfg


_lib: ctypes.CDLL | None = None


def library() -> ctypes.CDLL:
    """The built shared library (built on first use)."""
    global _lib
    if _lib is None:
        build()
        lib = ctypes.CDLL(str(LIBRARY))
        lib.casfw_sim_size.restype = ctypes.c_size_t
        lib.casfw_config_size.restype = ctypes.c_size_t
        lib.casfw_sim_init.argtypes = [
            ctypes.c_void_p,
            ctypes.POINTER(_Config),
            ctypes.c_uint32,
            ctypes.c_double,
        ]
        lib.casfw_sim_step.argtypes = [
            ctypes.c_void_p,
            ctypes.c_uint64,
            ctypes.c_char_p,
            ctypes.c_size_t,
        ]
        lib.casfw_sim_receive.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_size_t]
        lib.casfw_sim_take.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t]
        lib.casfw_sim_take.restype = ctypes.c_size_t
        lib.casfw_sim_counter.argtypes = [ctypes.c_void_p, ctypes.c_int]
        lib.casfw_sim_counter.restype = ctypes.c_uint32
        if lib.casfw_config_size() != ctypes.sizeof(_Config):
            raise CFirmwareUnavailable(
                f"casfw_config is {lib.casfw_config_size()} bytes in C but"
                f" {ctypes.sizeof(_Config)} in c_firmware._Config: update one to match the other"
            )
        _lib = lib
    return _lib


class CBoardStepper:
    """The C firmware powered up at board time 0, on a loopback cable, stepped on board time.

    Parameters
    ----------
    board:
        The board description (default: the golden conversations' board).
    delay_samples, gain:
        The loopback cable.
    """

    name = "c"

    def __init__(
        self, board: dict[str, Any] = BOARD, *, delay_samples: int = 0, gain: float = 1.0
    ) -> None:
        self._lib = library()
        self._mem = ctypes.create_string_buffer(self._lib.casfw_sim_size())
        self._out = ctypes.create_string_buffer(1 << 16)
        self._lib.casfw_sim_init(self._mem, ctypes.byref(_config(board)), delay_samples, gain)

    def step(self, t_ns: int, host: bytes) -> bytes:
        """Service at ``t_ns`` (ns, not before the last step), then receive ``host``."""
        self._lib.casfw_sim_step(self._mem, t_ns, host, len(host))
        return self._take()

    def receive(self, host: bytes) -> bytes:
        """Receive ``host`` without a service pass; the bytes sent in answer."""
        self._lib.casfw_sim_receive(self._mem, host, len(host))
        return self._take()

    def _take(self) -> bytes:
        parts = []
        while n := self._lib.casfw_sim_take(self._mem, self._out, len(self._out)):
            parts.append(ctypes.string_at(self._out, n))
        return b"".join(parts)

    @property
    def frame_errors(self) -> int:
        """Damaged frames dropped by the firmware's receiver."""
        return int(self._lib.casfw_sim_counter(self._mem, 1))


class CFirmwareOnPty:
    """The C firmware's pty server (``casfw-pty``) in a child process, in real time.

    :attr:`port_name` is the pty to open like a serial port. Closing stops the process (the
    host sees a hang-up).
    """

    def __init__(self, *, delay_samples: int = 0, gain: float = 1.0) -> None:
        build()
        self.process = subprocess.Popen(
            [str(PTY_SERVER), "--delay", str(delay_samples), "--gain", repr(float(gain))],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert self.process.stdout is not None
        line = self.process.stdout.readline().strip()
        if not line:
            _, err = self.process.communicate(timeout=5)
            raise CFirmwareUnavailable(f"casfw-pty did not start: {err.strip() or 'no output'}")
        self.port_name = line

    def close(self) -> None:
        """Stop the server (idempotent)."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        for stream in (self.process.stdout, self.process.stderr):
            if stream is not None:
                stream.close()

    def __enter__(self) -> CFirmwareOnPty:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
