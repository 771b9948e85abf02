"""The simulated GRBL controller behind a real raw pseudo-terminal.

>>> import serial
>>> with SimulatedGrblOnPty(GrblSimConfig()) as sim:
...     port = serial.serial_for_url(sim.port_name, timeout=2)
...     _ = port.write(b"$I\\n")
...     port.read_until(b"ok\\r\\n").splitlines()[-3:]
...     port.close()
[b'[VER:1.1h.20190830:]', b'[OPT:V,15,128]', b'ok']
"""

from __future__ import annotations

import time
from collections.abc import Callable
from types import TracebackType
from typing import TypeVar

from sim_devices.pty_endpoint import PtyEndpoint
from sim_devices.stage.config import GrblSimConfig
from sim_devices.stage.controller import SimStatus, SimulatedGrbl

R = TypeVar("R")


class SimulatedGrblOnPty:
    """A :class:`SimulatedGrbl` served on a pty; open :attr:`port_name` with the driver.

    Parameters
    ----------
    config:
        Machine settings.
    clock:
        ``None`` for real-time pacing (the wall clock, :func:`time.monotonic`), or an
        injected ``now()`` callable such as :class:`~sim_devices.stage.clock.ManualClock`.
    """

    def __init__(
        self, config: GrblSimConfig | None = None, clock: Callable[[], float] | None = None
    ) -> None:
        self.grbl = SimulatedGrbl(config, clock=clock or time.monotonic)
        self.grbl.data_to_send()  # power-up banner: nobody is listening yet
        self.endpoint = PtyEndpoint(self.grbl)
        self.port_name = self.endpoint.port_name

    def call(self, fn: Callable[[SimulatedGrbl], R]) -> R:
        """Run ``fn(grbl)`` under the endpoint's device lock (safe from any thread)."""
        with self.endpoint.lock:
            return fn(self.grbl)

    def status(self) -> SimStatus:
        """The simulator's state now."""
        return self.call(lambda g: g.status())

    def start(self) -> SimulatedGrblOnPty:
        self.endpoint.start()
        return self

    def close(self) -> None:
        self.endpoint.close()

    def __enter__(self) -> SimulatedGrblOnPty:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
