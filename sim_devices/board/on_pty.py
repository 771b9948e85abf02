"""The simulated board behind a real raw pseudo-terminal.

>>> import serial
>>> from firmware_protocol import Connection, Role
>>> with SimulatedBoardOnPty() as sim:
...     port = serial.serial_for_url(sim.port_name, timeout=2)
...     host = Connection(Role.HOST)
...     _ = port.write(host.send(host.make_hello()))
...     host.receive_data(port.read_until(b"\\x00"))
...     host.next_event().protocol_major
...     port.close()
2
"""

from __future__ import annotations

from collections.abc import Callable
from types import TracebackType
from typing import TypeVar

from firmware_protocol import cobs
from sim_devices.board.core import SimulatedBoard
from sim_devices.board.faults import FaultPlan
from sim_devices.board.spec import BoardSpec
from sim_devices.board.worlds import World
from sim_devices.pty_endpoint import PtyEndpoint

R = TypeVar("R")


class SimulatedBoardOnPty:
    """A :class:`SimulatedBoard` served on a pty; open :attr:`port_name` with the driver.

    Parameters
    ----------
    spec, world, faults:
        As for :class:`SimulatedBoard`.
    clock:
        ``None`` for real-time pacing (:func:`time.monotonic`), or an injected ``now()``.
    poll_interval:
        Longest wait (s) between two board ticks.
    """

    def __init__(
        self,
        spec: BoardSpec | None = None,
        *,
        clock: Callable[[], float] | None = None,
        world: World | None = None,
        faults: FaultPlan | None = None,
        poll_interval: float = 0.001,
    ) -> None:
        self.board = SimulatedBoard(spec, clock=clock, world=world, faults=faults)
        self.endpoint = PtyEndpoint(self.board, poll_interval=poll_interval)
        self.port_name = self.endpoint.port_name

    def call(self, fn: Callable[[SimulatedBoard], R]) -> R:
        """Run ``fn(board)`` under the endpoint's device lock (safe from any thread)."""
        with self.endpoint.lock:
            return fn(self.board)

    def start(self) -> SimulatedBoardOnPty:
        """Start serving (returns self)."""
        cobs.warm_up()  # the device thread must not stall in its first ADC frame
        self.endpoint.start()
        return self

    def close(self) -> None:
        """Stop serving; the host sees a hang-up."""
        self.endpoint.close()

    def __enter__(self) -> SimulatedBoardOnPty:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
