"""The GRBL tow stage as an ophyd-async movable: :class:`GrblStageDevice`.

It follows ophyd-async's movable conventions (:class:`ophyd_async.core.StandardMovable`)
over the driver :class:`~hil.devices.grbl.GrblStage` (opened by URL through the device
table, :mod:`hil.devices.table`: ``sim://stage``, ``serial:///dev/ttyUSB0``, ...). The
driver blocks (it waits on its clock for GRBL's answers), so every driver call runs on one
worker thread of the device, in order; the event loop stays free.
Units are SI: position m, speed m/s.

- ``connect()`` opens the port and reads GRBL's settings and status; :meth:`close` closes it.
  ``connect(mock=True)`` opens nothing: a ``set`` arrives at once (ophyd-async's instant
  mock), still checked against the soft limits.
- ``set(x, timeout=CALCULATE_TIMEOUT)`` moves to ``x`` m at ``speed`` (a configuration
  signal, m/s; NaN, the default, is GRBL's max rate ``$110``). The status reports progress
  (a watchable status: current, initial, target position) and completes when the move has;
  it fails with the driver's error (an alarm, a feed hold not asked for by ``stop``) or, past
  its timeout (the move's duration plus :data:`TIMEOUT_MARGIN_S`), after holding the stage.
- ``check_value(x)`` refuses a target outside the soft limits (what ``set`` checks first;
  bluesky's ``check_limits`` calls it); ``locate()`` gives setpoint and readback.
- ``stop(success)`` sends a feed hold at once (a realtime byte, not queued behind the move),
  then cancels the held move (GRBL keeps its position). With ``success=True`` (a RunEngine
  pause) the move's status completes where the stage stopped, so ``RE.resume()`` repeats the
  move from its checkpoint and reaches the target; with ``success=False`` it fails.
- :meth:`make_ready` leaves a power-up or alarm lock the way a tank run does (home with
  ``$H`` when homing is enabled, else unlock ``$X``).

The readback (data key ``<name>``, hinted, m), velocity and machine state come from GRBL's
status reports: refreshed at most every :data:`_WATCH_S` s of wall time while a move runs
(from the reports the driver reads anyway) and from a status query at every read.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property
from typing import Any, TypeVar

from ophyd_async.core import (
    DEFAULT_TIMEOUT,
    AsyncStatus,
    DeviceMock,
    MovableLogic,
    SignalR,
    SignalRW,
    StandardMovable,
    StandardReadable,
    soft_signal_r_and_setter,
    soft_signal_rw,
)
from ophyd_async.core import StandardReadableFormat as Format

from hil.devices.clock import Clock
from hil.devices.grbl import GrblStage
from hil.devices.grbl_protocol import FEED_HOLD
from hil.devices.stage import StageStatus
from hil.devices.stage_errors import StageError, StageHeldError, check_within_limits
from hil.devices.table import open_stage

#: Wall seconds between readback refreshes while a move runs (a display rate, not a poll:
#: the driver polls GRBL at its own <= 5 Hz and the device republishes its last report).
_WATCH_S = 0.1

#: Seconds a move may take beyond its planned duration (distance / speed plus the
#: acceleration and deceleration) before its status fails: GRBL's answers and a loaded host.
TIMEOUT_MARGIN_S = DEFAULT_TIMEOUT

T = TypeVar("T")


@dataclass
class GrblMoveLogic(MovableLogic[float]):
    """How :class:`GrblStageDevice` moves, checks and stops (ophyd-async's movable hooks)."""

    device: GrblStageDevice

    async def check_move(self, new_position: float) -> None:
        """Refuse (:class:`~hil.devices.stage_errors.StageLimitError`) a target outside the
        soft limits; nothing is sent. Connected, the driver's own rule
        (:meth:`~hil.devices.grbl.GrblStage.check_position`); in mock mode or before
        connecting, the same rule on the limits given."""
        name = f"{self.device.name or 'stage'} target"
        if self.device.opened:
            self.device.driver.check_position(name, float(new_position))
        else:
            check_within_limits(name, float(new_position), self.device.soft_limits())

    async def calculate_timeout(self, old_position: float, new_position: float) -> float | None:
        """The move's planned duration (s, cruise plus acceleration and deceleration at
        ``$120``) plus :data:`TIMEOUT_MARGIN_S`; None (no timeout) in mock mode."""
        if self.device.mock_mode:
            return None
        self.device.require_open()
        v = await self.device.move_speed()
        accel = self.device.driver.settings.acceleration
        distance = abs(new_position - old_position) if math.isfinite(old_position) else 0.0
        return distance / v + 2.0 * v / accel + TIMEOUT_MARGIN_S

    async def move(self, new_position: float, timeout: Callable[[], float | None]) -> None:
        """The move on the controller (the default logic in mock mode)."""
        if self.device.mock_mode:
            await super().move(new_position, timeout)
            return
        await self.device.drive_to(
            float(new_position), timeout(), getattr(timeout, "timeout", None)
        )

    async def stop(self) -> None:
        """Feed hold now, then cancel the held move once the driver is free."""
        await self.device.hold_and_cancel()


def _consume(future: asyncio.Future[Any]) -> None:
    if not future.cancelled():
        future.exception()


class GrblStageDevice(StandardReadable, StandardMovable[float]):
    """One-axis GRBL stage (X) as an ophyd-async movable.

    Parameters
    ----------
    url:
        Stage URL of the controller (:mod:`hil.devices.table`), e.g.
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
        The device name: the readback's data key, the prefix of the others.
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
        self._soft_limits = soft_limits
        self._driver = open_stage(
            url,
            field="url",
            clock=clock,
            soft_limits=soft_limits,
            transport_options=transport_options,
        )
        self._opened = False
        self._mock_mode = False
        self._holding = False
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
        #: The last target ``set`` was given (m): ``locate()``'s setpoint.
        self.setpoint = soft_signal_rw(float, math.nan, units="m")
        super().__init__(name=name)

    @cached_property
    def movable_logic(self) -> GrblMoveLogic:
        """The move, check and stop hooks (:class:`GrblMoveLogic`)."""
        setpoint: SignalRW[float] = self.setpoint
        readback: SignalR[float] = self.position
        return GrblMoveLogic(setpoint=setpoint, readback=readback, device=self)

    # ------------------------------------------------------------------ lifecycle
    async def connect(
        self,
        mock: bool | DeviceMock = False,
        timeout: float = DEFAULT_TIMEOUT,
        force_reconnect: bool = False,
    ) -> None:
        """Connect the signals, then (not in mock mode) open the controller: reset, ``$$``
        settings, a status report. In mock mode the readback starts at 0 (home)."""
        await super().connect(mock=mock, timeout=timeout, force_reconnect=force_reconnect)
        self._mock_mode = bool(mock)
        if mock:
            from ophyd_async.core import set_mock_value

            set_mock_value(self.position, 0.0)
            set_mock_value(self.state, "IDLE")
            low, high = self.soft_limits()
            set_mock_value(self.low_limit, low)
            set_mock_value(self.high_limit, high)
            return
        if self._opened and not force_reconnect:
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

    @property
    def opened(self) -> bool:
        """The controller's port is open (``connect()`` without ``mock``); the driver's
        limits and settings are read."""
        return self._opened

    @property
    def mock_mode(self) -> bool:
        """Connected with ``mock=True``: no controller, moves arrive at once."""
        return self._mock_mode

    def soft_limits(self) -> tuple[float, float]:
        """(low, high) m a target must lie in: the controller's ``[-$130, 0]`` narrowed by
        the ``soft_limits`` given (before connecting or in mock mode: those, else
        ``(-inf, 0]``)."""
        if self._opened:
            return self._driver.limits
        if self._soft_limits is not None:
            return self._soft_limits
        return -math.inf, 0.0

    # ------------------------------------------------------------------ readable
    async def read(self) -> dict[str, Any]:
        """The readable signals after a fresh status query (position, velocity, state)."""
        if not self._mock_mode:
            await self._refresh()
        return await super().read()

    async def _refresh(self) -> None:
        self.require_open()
        self._publish(await self._call(self._driver.status))

    def _publish(self, status: StageStatus | None) -> None:
        if status is not None:
            self._set_position(status.position)
            self._set_velocity(status.velocity)
            self._set_state(status.state.name)

    # ------------------------------------------------------------------ motion
    async def move_speed(self) -> float:
        """The speed a move runs at (m/s): :attr:`speed`, or ``$110`` when NaN."""
        speed = await self.speed.get_value()
        return self._driver.settings.max_rate if math.isnan(speed) else speed

    async def drive_to(
        self, x: float, timeout_s: float | None, whole_timeout_s: float | None = None
    ) -> None:
        """Move to ``x`` m on the controller, publishing the readback as it goes. A feed
        hold asked for by :meth:`stop` ends the move quietly (the movable's stop rule
        decides the status); past ``timeout_s`` (s left of the move's ``whole_timeout_s``)
        the stage is held and the move fails."""
        self.require_open()
        v = await self.move_speed()
        await self.setpoint.set(x)
        self._holding = False
        move = asyncio.get_running_loop().run_in_executor(
            self._executor, lambda: self._driver.move_to(x, v)
        )
        loop = asyncio.get_running_loop()
        deadline = None if timeout_s is None else loop.time() + timeout_s
        try:
            while not move.done():
                left = None if deadline is None else deadline - loop.time()
                if left is not None and left <= 0.0:
                    await self.hold_and_cancel()
                    with contextlib.suppress(StageError):
                        await move
                    raise TimeoutError(
                        f"{self.name or 'stage'} ({self.url}): the move to {x:g} m did not end"
                        f" within its timeout {whole_timeout_s or timeout_s:.3g} s; the stage"
                        " was held where it stood: check the controller (hil stage status),"
                        " or give set() a longer timeout (default: the move's planned"
                        f" duration plus {TIMEOUT_MARGIN_S:g} s)"
                    )
                wait = _WATCH_S if left is None else min(_WATCH_S, left)
                await asyncio.wait({move}, timeout=wait)
                self._publish(self._driver.last_status)
            final: StageStatus | None = await move
        except StageHeldError:
            if not self._holding:
                raise  # held by someone else (a hold button, the controller): a failure
            final = self._driver.last_status
        finally:
            # A cancelled wait (the movable's stop) leaves the driver's move to end on its
            # thread: its outcome is read here so that it is never reported as unretrieved.
            move.add_done_callback(_consume)
            self._publish(self._driver.last_status)
        self._publish(final)

    async def hold_and_cancel(self) -> None:
        """Feed hold at once, then cancel the held move (position kept, no alarm)."""
        if self._mock_mode or not self._opened:
            return
        self._holding = True
        self.hold_now()
        # The move in flight sees the hold and ends; then the cancel on the driver's thread.
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
        self.require_open()
        self._publish(await self._call(self._driver.make_ready))

    # ------------------------------------------------------------------ helpers
    async def _call(self, func: Callable[[], T]) -> T:
        return await asyncio.get_running_loop().run_in_executor(self._executor, func)

    def require_open(self) -> None:
        """Refuse (StageError) when the controller is not open: connect() first."""
        if not self._opened:
            raise StageError(
                f"{self.name or 'the stage'} ({self.url}) is not connected: await"
                " device.connect() (or use ophyd_async.core.init_devices) first",
                url=self.url,
            )
