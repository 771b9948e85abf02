"""``sim://board`` and ``sim://stage``: simulated devices started on demand.

``sim_devices`` is imported here lazily, inside the openers, so the host package never
depends on the simulators at import time (DESIGN.md import rules).

``sim://board`` query options: ``via=memory`` (default; the board runs in the reader's
thread), ``via=pty`` (behind a raw pseudo-terminal, served by a thread) or ``via=usb``
(behind the pyusb backend object, opened as ``usb://1209:ca50``); ``delay`` (loopback
delay, samples) and ``gain`` (loopback gain, linear); ``impl=python`` (default: the Python
simulated board) or ``impl=c`` (the C reference firmware of ``firmware_protocol/c``, built if
needed and served on a pty by its own process in real time: ``via`` must be ``pty`` or
absent, and the keyword options below do not apply). Keyword options: ``clock`` (an
injected ``now()``; default real time), ``world``, ``spec``, ``faults``. The returned
transport has a ``simulator`` attribute: what serves it (for fault injection in tests).

``sim://stage`` starts the simulated GRBL controller on a pty and returns the open serial
port (a serial-like object :class:`~hil.devices.grbl.GrblStage` accepts); closing it stops
the simulator. Keyword options: ``config`` (a ``GrblSimConfig``), ``clock``.
"""

from __future__ import annotations

from typing import Any

from hil.errors import ConfigError
from hil.transports.base import Transport
from hil.transports.serial_transport import SerialTransport, open_serial

_VIAS = ("memory", "pty", "usb")
_IMPLS = ("python", "c")


def _int_option(query: dict[str, str], name: str, default: int) -> int:
    raw = query.get(name)
    if raw is None:
        return default
    try:
        return int(raw)
    except ValueError:
        raise ConfigError(name, raw, "an integer", "e.g. ?delay=100") from None


def open_sim_board(query: dict[str, str], options: dict[str, Any], timeout: float) -> Transport:
    """Start a simulated board (see the module docstring) and return a transport to it."""
    from sim_devices.board import (
        BoardPort,
        LoopbackWorld,
        MemoryBoardLink,
        SimulatedBoard,
        SimulatedBoardOnPty,
    )

    impl = query.get("impl", "python")
    if impl not in _IMPLS:
        raise ConfigError("impl", impl, f"one of {', '.join(_IMPLS)}", "e.g. sim://board?impl=c")
    if impl == "c":
        return _open_c_board(query, options, timeout)
    via = query.get("via", "memory")
    if via not in _VIAS:
        raise ConfigError("via", via, f"one of {', '.join(_VIAS)}", "e.g. sim://board?via=pty")
    world = options.get("world")
    if world is None:
        try:
            gain = float(query.get("gain", "1.0"))
        except ValueError:
            raise ConfigError("gain", query["gain"], "a number (linear)") from None
        world = LoopbackWorld(_int_option(query, "delay", 0), gain)
    kwargs: dict[str, Any] = {
        "spec": options.get("spec"),
        "clock": options.get("clock"),
        "world": world,
        "faults": options.get("faults"),
    }
    url = "sim://board?" + "&".join(f"{k}={v}" for k, v in sorted(query.items()))
    if via == "pty":
        sim = SimulatedBoardOnPty(**kwargs).start()
        transport = open_serial(sim.port_name, timeout=timeout, on_close=sim.close)
        transport.url = url
        transport.simulator = sim  # type: ignore[attr-defined]
        return transport
    board = SimulatedBoard(**kwargs)
    if via == "usb":
        from hil.transports.usb_transport import UsbTransport
        from sim_devices.board.usb_backend import PRODUCT_ID, VENDOR_ID, SimulatedUsbBackend

        backend = SimulatedUsbBackend(board)
        usb = UsbTransport(VENDOR_ID, PRODUCT_ID, backend=backend, timeout=timeout, url=url)
        usb.simulator = backend  # type: ignore[attr-defined]
        return usb
    link = MemoryBoardLink(BoardPort(board), timeout=timeout, url=url)
    link.simulator = link.port  # type: ignore[attr-defined]
    return link


def _open_c_board(query: dict[str, str], options: dict[str, Any], timeout: float) -> Transport:
    """The C reference firmware's pty server, opened as a serial port."""
    from sim_devices.board.c_firmware import CFirmwareOnPty

    if query.get("via", "pty") != "pty":
        raise ConfigError("via", query["via"], "pty (or absent) with impl=c", "sim://board?impl=c")
    given = sorted(k for k in ("clock", "world", "spec", "faults") if options.get(k) is not None)
    if given:
        raise ConfigError(
            "options",
            ", ".join(given),
            "none with impl=c",
            "the C firmware runs in real time with a loopback cable; use impl=python for"
            " an injected clock, another world, spec or faults",
        )
    try:
        gain = float(query.get("gain", "1.0"))
    except ValueError:
        raise ConfigError("gain", query["gain"], "a number (linear)") from None
    sim = CFirmwareOnPty(delay_samples=_int_option(query, "delay", 0), gain=gain)
    transport = open_serial(sim.port_name, timeout=timeout, on_close=sim.close)
    transport.url = "sim://board?" + "&".join(f"{k}={v}" for k, v in sorted(query.items()))
    transport.simulator = sim  # type: ignore[attr-defined]
    return transport


class SimStagePort:
    """The serial port of a simulated GRBL stage; closing it stops the simulator.

    Offers what :class:`~hil.devices.grbl.GrblStage` uses of a serial port (``read``,
    ``write``, ``in_waiting``, ``reset_input_buffer``, ``timeout``, ``close``) and the
    transport contract's ``url``.
    """

    def __init__(self, transport: SerialTransport, simulator: Any) -> None:
        self._transport = transport
        self.port = transport.port
        self.simulator = simulator
        self.url = "sim://stage"

    @property
    def timeout(self) -> float:
        """Read timeout, s."""
        return float(self.port.timeout)

    @timeout.setter
    def timeout(self, value: float) -> None:
        self.port.timeout = value

    @property
    def in_waiting(self) -> int:
        """Bytes ready to read."""
        return int(self.port.in_waiting)

    def read(self, size: int = 1) -> bytes:
        """pyserial semantics: wait for ``size`` bytes or the timeout."""
        return bytes(self.port.read(size))

    def write(self, data: bytes) -> int:
        """Write all of ``data``."""
        return self._transport.write(data)

    def reset_input_buffer(self) -> None:
        """Drop unread input."""
        self.port.reset_input_buffer()

    def close(self) -> None:
        """Close the port and stop the simulator."""
        self._transport.close()


def open_sim_stage(query: dict[str, str], options: dict[str, Any], timeout: float) -> Any:
    """Start the simulated GRBL controller on a pty; return its open serial port."""
    from sim_devices.stage import SimulatedGrblOnPty

    if query:
        raise ConfigError(
            "sim://stage options", sorted(query), "none in the URL", "pass config= instead"
        )
    sim = SimulatedGrblOnPty(options.get("config"), clock=options.get("clock")).start()
    transport = open_serial(sim.port_name, timeout=timeout, on_close=sim.close)
    return SimStagePort(transport, sim)
