"""The GRBL tow stage as an ophyd-async movable: :class:`GrblStageDevice`.

It wraps the driver :class:`~hil.devices.grbl.GrblStage` (opened by URL through the transport
registry: ``sim://stage``, ``serial:///dev/ttyUSB0``, ...). The driver blocks (it waits on its
clock for GRBL's answers), so every call runs on one worker thread of the device, in order;
the event loop stays free. Units are SI: position m, speed m/s.

- ``connect()`` opens the port and reads GRBL's settings and status; :meth:`close` closes it.
- ``set(x)`` moves to ``x`` m at ``speed`` (a configuration signal, m/s; default GRBL's max
  rate ``$110``); the status completes when the move has (``G4 P0`` answered), and fails
  with the driver's error (a soft limit, an alarm, a feed hold).
- ``stop()`` sends a feed hold at once (a realtime byte, not queued behind the move), then
  cancels the held move (GRBL keeps its position).
- :meth:`make_ready` leaves a power-up or alarm lock the way a tank run does (home with
  ``$H`` when homing is enabled, else unlock ``$X``).

The readback (``<name>-position``, hinted), velocity and machine state come from GRBL's
status reports: refreshed at most every :data:`_WATCH_S` s of wall time while a move runs
(from the reports the driver reads anyway) and from a status query at every read.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

from bluesky.protocols import Movable, Stoppable
from ophyd_async.core import (
    DEFAULT_TIMEOUT,
    AsyncStatus,
    DeviceMock,
    StandardReadable,
    soft_signal_r_and_setter,
    soft_signal_rw,
)
from ophyd_async.core import StandardReadableFormat as Format

from hil.devices.clock import Clock
from hil.devices.grbl import GrblStage
from hil.devices.grbl_protocol import FEED_HOLD
from hil.devices.stage import StageStatus
from hil.devices.stage_errors import StageError

#: Wall seconds between readback refreshes while a move runs (a display rate, not a poll:
#: the driver polls GRBL at its own <= 5 Hz and the device republishes its last report).
_WATCH_S = 0.1

T = TypeVar("T")


class GrblStageDevice(StandardReadable, Movable[float], Stoppable):
    """One-axis GRBL stage (X) as an ophyd-async device.

    Parameters
    ----------
    url:
        Transport URL of the controller (:mod:`hil.transports.registry`), e.g.
        ``"sim://stage"``, ``"sim://stage?via=memory"``, ``"/dev/ttyUSB0"``.
    clock:
        The driver's clock (default the wall clock); a simulated clock runs moves in
        milliseconds (see :class:`~hil.devices.clock.Clock`).
    soft_limits:
        Optional (low, high) m inside GRBL's machine range ``[-$130, 0]``.
    transport_options:
        More options for the transport opener (``config=`` a ``GrblSimConfig`` for
        ``sim://stage``).
    name:
        The device name (prefix of its data keys).
    """

    def __init__(
        self,
        url: str,
        *,
        clock: Clock | None = None,
        soft_limits: tuple[float, float] | None = None,
        transport_options: Mapping[str, Any] | None = None,
        name: str = "",
    ) -> None:
        self.url = url
        self._driver = GrblStage(
            url, clock=clock, soft_limits=soft_limits, transport_options=transport_options
        )
        self._opened = False
        self._mock_mode = False
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"grbl-{url}")
        with self.add_children_as_readables(Format.HINTED_SIGNAL):
            self.position, self._set_position = soft_signal_r_and_setter(float, math.nan, units="m")
        with self.add_children_as_readables():
            self.velocity, self._set_velocity = soft_signal_r_and_setter(float, 0.0, units="m/s")
            self.state, self._set_state = soft_signal_r_and_setter(str, "")
        with self.add_children_as_readables(Format.CONFIG_SIGNAL):
            #: Speed of the moves ``set`` makes, m/s; NaN (the default) is GRBL's max rate.
            self.speed = soft_signal_rw(float, math.nan, units="m/s")
            self.low_limit, self._set_low = soft_signal_r_and_setter(float, math.nan, units="m")
            self.high_limit, self._set_high = soft_signal_r_and_setter(float, math.nan, units="m")
        super().__init__(name=name)

    # ------------------------------------------------------------------ lifecycle
    async def connect(
        self,
        mock: bool | DeviceMock = False,
        timeout: float = DEFAULT_TIMEOUT,
        force_reconnect: bool = False,
    ) -> None:
        """Connect the signals, then (not in mock mode) open the controller: reset, ``$$``
        settings, a status report."""
        await super().connect(mock=mock, timeout=timeout, force_reconnect=force_reconnect)
        self._mock_mode = bool(mock)
        if mock or (self._opened and not force_reconnect):
            return
        if self._opened:
            await self.close()
        await self._call(self._driver.open)
        self._opened = True
        low, high = self._driver.limits
        self._set_low(low)
        self._set_high(high)
        await self._refresh()

    async def close(self) -> None:
        """Close the port (a changed acceleration is restored first by the driver)."""
        if self._opened:
            self._opened = False
            await self._call(self._driver.close)

    @property
    def driver(self) -> GrblStage:
        """The underlying driver (open after ``connect()``); call it only between moves."""
        return self._driver

    # ------------------------------------------------------------------ readable
    async def read(self) -> dict[str, Any]:
        """The readable signals after a fresh status query (position, velocity, state)."""
        await self._refresh()
        return await super().read()

    async def _refresh(self) -> None:
        self._publish(await self._call(self._driver.status))

    def _publish(self, status: StageStatus | None) -> None:
        if status is not None:
            self._set_position(status.position)
            self._set_velocity(status.velocity)
            self._set_state(status.state.name)

    # ------------------------------------------------------------------ motion
    @AsyncStatus.wrap
    async def set(self, value: float) -> None:
        """Move to ``value`` m at :attr:`speed` (NaN: the max rate ``$110``)."""
        self._require_open()
        speed = await self.speed.get_value()
        v = self._driver.settings.max_rate if math.isnan(speed) else speed
        move = asyncio.get_running_loop().run_in_executor(
            self._executor, lambda: self._driver.move_to(float(value), v)
        )
        try:
            while not move.done():
                await asyncio.wait({move}, timeout=_WATCH_S)
                self._publish(self._driver.last_status)
            final = await move
        finally:
            self._publish(self._driver.last_status)
        self._publish(final)

    async def stop(self, success: bool = True) -> None:
        """Feed hold at once, then cancel the held move (position kept, no alarm)."""
        if not self._opened:
            return
        self.hold_now()
        # The move in flight sees the hold and ends (its status fails); then the cancel.
        self._publish(await self._call(self._driver.stop))

    def hold_now(self) -> None:
        """Send GRBL a feed hold (``!``) now, from the caller's thread: a realtime byte
        goes out at any time, also while a move waits for its end on the worker thread."""
        with contextlib.suppress(StageError, OSError):
            self._driver.transport.write(FEED_HOLD)

    @AsyncStatus.wrap
    async def make_ready(self) -> None:
        """Out of an alarm or power-up lock: home (``$H``, homing enabled) or unlock
        (``$X``); nothing when already idle."""
        self._require_open()
        self._publish(await self._call(self._driver.make_ready))

    # ------------------------------------------------------------------ helpers
    async def _call(self, func: Callable[[], T]) -> T:
        return await asyncio.get_running_loop().run_in_executor(self._executor, func)

    def _require_open(self) -> None:
        if self._mock_mode:
            raise StageError(
                f"{self.name or 'the stage'} ({self.url}) is connected in mock mode: it has no"
                " controller to move; for a simulated stage connect it for real to"
                " sim://stage (or sim://stage?via=memory)"
            )
        if not self._opened:
            raise StageError(
                f"{self.name or 'the stage'} ({self.url}) is not connected: await"
                " device.connect() (or use ophyd_async.core.init_devices) first"
            )
