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

``sim://stage`` starts the simulated GRBL controller on a pty and returns a transport to it
(its ``simulator`` attribute is the ``SimulatedGrblOnPty``); closing it stops the
simulator. ``sim://stage?via=memory`` runs the controller in the reader's thread instead
(:class:`MemoryStageLink`; ``simulator`` is the ``SimulatedGrbl``). Keyword options:
``config`` (a ``GrblSimConfig``), ``clock`` (an injected ``now()``;
:class:`~hil.devices.grbl.GrblStage` passes its own clock's).
"""

from __future__ import annotations

from typing import Any

from hil.errors import ConfigError
from hil.transports.base import Transport
from hil.transports.serial_transport import open_serial

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


class MemoryStageLink:
    """A transport wired straight into a simulated GRBL controller that runs in the reader's
    thread: every read and write first brings the controller up to its clock's present.

    No thread and no pty: with an injected clock the conversation is deterministic, and a
    read with nothing to say returns ``b""`` at once (the driver's wait then advances the
    clock). ``simulator`` is the ``SimulatedGrbl``.
    """

    def __init__(self, grbl: Any, *, timeout: float, url: str = "sim://stage?via=memory") -> None:
        self.simulator = grbl
        self.timeout = timeout
        self.url = url
        self._rx = bytearray()
        self._open = True
        grbl.data_to_send()  # the power-up banner: nobody was listening yet
        grbl.connection_made()

    def read(self, size: int) -> bytes:
        """Up to ``size`` bytes the controller has sent by now (``b""`` if none)."""
        self.simulator.tick()
        self._rx += self.simulator.data_to_send()
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    def write(self, data: bytes) -> int:
        """Hand ``data`` to the controller at the present time."""
        self.simulator.tick()
        self.simulator.receive_data(bytes(data))
        return len(data)

    def close(self) -> None:
        """Hang up (idempotent)."""
        if self._open:
            self._open = False
            self.simulator.connection_lost()


_STAGE_VIAS = ("pty", "memory")


def open_sim_stage(query: dict[str, str], options: dict[str, Any], timeout: float) -> Transport:
    """Start the simulated GRBL controller (``?via=pty``, the default, or ``?via=memory``)
    and return a transport to it."""
    extra = sorted(set(query) - {"via"})
    if extra:
        raise ConfigError(
            "sim://stage option", extra[0], "via", "other settings: pass config= instead"
        )
    via = query.get("via", "pty")
    if via not in _STAGE_VIAS:
        raise ConfigError("via", via, "one of pty, memory", "e.g. sim://stage?via=memory")
    if via == "memory":
        import time

        from sim_devices.stage import SimulatedGrbl

        clock = options.get("clock") or time.monotonic
        return MemoryStageLink(SimulatedGrbl(options.get("config"), clock=clock), timeout=timeout)
    from sim_devices.stage import SimulatedGrblOnPty

    sim = SimulatedGrblOnPty(options.get("config"), clock=options.get("clock")).start()
    transport = open_serial(sim.port_name, timeout=timeout, on_close=sim.close)
    transport.url = "sim://stage"
    transport.simulator = sim  # type: ignore[attr-defined]
    return transport
