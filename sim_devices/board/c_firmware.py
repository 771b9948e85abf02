"""The C reference firmware (``firmware_protocol/c``) as a device under test and on a pty.

:func:`build` runs ``make host`` there (a C99 compiler and make are needed; the build is
incremental). :class:`CBoardStepper` loads the shared library with :mod:`ctypes` and steps
the firmware on an injected board clock, exactly as
:class:`~sim_devices.board.stepper.PythonBoardStepper` steps the Python board, so both run
the same golden conversations and conformance tests. :class:`CFirmwareOnPty` runs the
firmware's pty server (real time) for every tool that opens a serial port.
:class:`CFirmwareDevice` puts the firmware behind a Python HAL (an injected clock and any
:mod:`world <sim_devices.board.worlds>`, e.g. the acoustic tank) as a sans-IO device, and
:class:`CFirmwareBoardOnPty` serves that on a pty like
:class:`~sim_devices.board.on_pty.SimulatedBoardOnPty`.
"""

from __future__ import annotations

import ctypes
import shutil
import subprocess
import threading
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar

import numpy as np

import firmware_protocol
from firmware_protocol import SampleFormat
from firmware_protocol.conversations import BOARD
from hil.errors import DeviceUnavailable

FIRMWARE_DIR = Path(firmware_protocol.__file__).with_name("c")
"""The C sources and their Makefile."""
BUILD_DIR = FIRMWARE_DIR / "build"
LIBRARY = BUILD_DIR / "libcasfw_sim.so"
PTY_SERVER = BUILD_DIR / "casfw-pty"

_build_lock = threading.Lock()


class CFirmwareUnavailable(DeviceUnavailable, RuntimeError):
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


_NOW = ctypes.CFUNCTYPE(ctypes.c_uint64)
_IO = ctypes.CFUNCTYPE(
    None,
    ctypes.c_uint64,
    ctypes.c_uint32,
    ctypes.POINTER(ctypes.c_double),
    ctypes.c_uint,
    ctypes.POINTER(ctypes.c_double),
    ctypes.c_uint,
)
_START = ctypes.CFUNCTYPE(None)

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
        lib.casfw_ext_size.restype = ctypes.c_size_t
        lib.casfw_ext_init.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Config), _NOW, _IO, _START]
        lib.casfw_ext_receive.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_size_t]
        lib.casfw_ext_service.argtypes = [ctypes.c_void_p]
        lib.casfw_ext_take.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t]
        lib.casfw_ext_take.restype = ctypes.c_size_t
        lib.casfw_ext_link_lost.argtypes = [ctypes.c_void_p]
        lib.casfw_ext_index_at.argtypes = [ctypes.c_void_p, ctypes.c_uint64]
        lib.casfw_ext_index_at.restype = ctypes.c_uint64
        lib.casfw_ext_counter.argtypes = [ctypes.c_void_p, ctypes.c_int]
        lib.casfw_ext_counter.restype = ctypes.c_uint32
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
    def frames_ok(self) -> int:
        """Intact frames the firmware's receiver handled."""
        return int(self._lib.casfw_sim_counter(self._mem, 0))

    @property
    def frame_errors(self) -> int:
        """Damaged frames dropped by the firmware's receiver."""
        return int(self._lib.casfw_sim_counter(self._mem, 1))

    @property
    def adc_clipped_samples(self) -> int:
        """ADC values clipped at conversion since power-up."""
        return int(self._lib.casfw_sim_counter(self._mem, 5))


def default_board() -> dict[str, Any]:
    """The board the C firmware plays by default: that of :class:`BoardSpec` defaults
    (1 MS/s first, 2 + 2 channels, every format, a 2^18-frame DAC buffer)."""
    from sim_devices.board.spec import BoardSpec

    spec = BoardSpec()
    return {
        "dac_channels": spec.dac_channels,
        "adc_channels": spec.adc_channels,
        "formats": [f.name for f in spec.formats],
        "sample_rates_hz": list(spec.sample_rates_hz),
        "dac_buffer_samples": spec.dac_buffer_samples,
        "adc_buffer_samples": spec.adc_buffer_samples,
        "max_frame_len": spec.max_frame_len,
        "gain_min_cdb": spec.gain_min_cdb,
        "gain_max_cdb": spec.gain_max_cdb,
        "firmware": list(spec.firmware),
        "board_serial": spec.board_serial,
        "sync_interval_ns": round(spec.sync_interval_s * 1e9),
        "status_interval_ns": round(spec.status_interval_s * 1e9),
        "temperature_cdeg": round(spec.temperature_c * 100),
    }


class CFirmwareDevice:
    """The C firmware as a sans-IO device (the :class:`~sim_devices.pty_endpoint.PtyEndpoint`
    contract) whose HAL is Python: ``clock()`` (s) is board time and ``world(dac, first)``
    (:mod:`sim_devices.board.worlds`) is the analog path between its DAC and ADC.

    Attributes ``dac_underruns``, ``adc_overruns``, ``adc_clipped_samples`` and
    :meth:`sample_index` mirror
    :class:`~sim_devices.board.core.SimulatedBoard`, so a simulated tank can use either.
    """

    def __init__(
        self,
        clock: Callable[[], float],
        world: Callable[..., Any],
        board: dict[str, Any] | None = None,
    ) -> None:
        self._lib = library()
        self.clock = clock
        self.world = world
        self._mem = ctypes.create_string_buffer(self._lib.casfw_ext_size())
        self._out = ctypes.create_string_buffer(1 << 16)
        # The callbacks must outlive the firmware: keep them on the instance.
        self._now_cb = _NOW(lambda: max(0, round(self.clock() * 1e9)))
        self._io_cb = _IO(self._sample_io)
        self._start_cb = _START(self._stream_start)
        cfg = _config(board or default_board())
        self._lib.casfw_ext_init(
            self._mem, ctypes.byref(cfg), self._now_cb, self._io_cb, self._start_cb
        )

    def _sample_io(self, first: int, n: int, dac: Any, n_dac: int, adc: Any, n_adc: int) -> None:
        dac_block = np.ctypeslib.as_array(dac, shape=(n, n_dac)).copy()
        out = np.asarray(self.world(dac_block, first), dtype=np.float64)
        adc_block = np.ctypeslib.as_array(adc, shape=(n, n_adc))
        adc_block[:] = 0.0
        k = min(out.shape[1], n_adc)
        adc_block[:, :k] = out[:, :k]

    def _stream_start(self) -> None:
        reset = getattr(self.world, "reset", None)
        if callable(reset):
            reset()

    # --- the sans-IO device contract -----------------------------------------------------
    def receive_data(self, data: bytes) -> None:
        """Bytes from the host."""
        self._lib.casfw_ext_receive(self._mem, data, len(data))

    def data_to_send(self) -> bytes:
        """Bytes for the host."""
        parts = []
        while n := self._lib.casfw_ext_take(self._mem, self._out, len(self._out)):
            parts.append(ctypes.string_at(self._out, n))
        return b"".join(parts)

    def tick(self) -> None:
        """One service pass at the clock's present."""
        self._lib.casfw_ext_service(self._mem)

    def connection_made(self) -> None:
        """A host opened the link (the firmware waits for its HELLO)."""

    def connection_lost(self) -> None:
        """The host went away: back to IDLE."""
        self._lib.casfw_ext_link_lost(self._mem)

    # --- inspection (as SimulatedBoard) ---------------------------------------------------
    def sample_index(self, now: float | None = None) -> int:
        """The board sample clock at ``now`` (s; default: the clock's present)."""
        t = self.clock() if now is None else now
        return int(self._lib.casfw_ext_index_at(self._mem, max(0, round(t * 1e9))))

    @property
    def dac_underruns(self) -> int:
        """DAC underruns since power-up."""
        return int(self._lib.casfw_ext_counter(self._mem, 0))

    @property
    def adc_overruns(self) -> int:
        """ADC overruns since power-up."""
        return int(self._lib.casfw_ext_counter(self._mem, 1))

    @property
    def adc_clipped_samples(self) -> int:
        """ADC values clipped at conversion since power-up (the count behind the latched
        ADC_CLIPPING alarm, as :attr:`SimulatedBoard.adc_clipped_samples`)."""
        return int(self._lib.casfw_ext_counter(self._mem, 2))


R = TypeVar("R")


class CFirmwareBoardOnPty:
    """A :class:`CFirmwareDevice` served on a pty (the interface of
    :class:`~sim_devices.board.on_pty.SimulatedBoardOnPty`: ``port_name``, ``call``,
    ``start``, ``close``)."""

    def __init__(
        self,
        *,
        clock: Callable[[], float],
        world: Callable[..., Any],
        poll_interval: float = 0.001,
    ) -> None:
        from sim_devices.pty_endpoint import PtyEndpoint

        self.board = CFirmwareDevice(clock, world)
        self.endpoint = PtyEndpoint(self.board, poll_interval=poll_interval)
        self.port_name = self.endpoint.port_name

    def call(self, fn: Callable[[CFirmwareDevice], R]) -> R:
        """Run ``fn(board)`` under the endpoint's device lock."""
        with self.endpoint.lock:
            return fn(self.board)

    def start(self) -> CFirmwareBoardOnPty:
        """Start serving (returns self)."""
        self.endpoint.start()
        return self

    def close(self) -> None:
        """Stop serving; the host sees a hang-up."""
        self.endpoint.close()


def stop_process(process: subprocess.Popen[str]) -> None:
    """Terminate a child (killed if it has not ended 5 s later) and close its pipes;
    idempotent."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    for stream in (process.stdout, process.stderr):
        if stream is not None:
            stream.close()


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
        stop_process(self.process)

    def __enter__(self) -> CFirmwareOnPty:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
