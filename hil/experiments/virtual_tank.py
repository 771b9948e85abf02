"""The built-in simulated tank in this process, on virtual time.

The simulated GRBL controller and the simulated board run in the host's own thread, behind
in-memory links, with the acoustic tank (:func:`~hil.experiments.sim_tank.build_tank_world`)
between them, all on one :class:`~hil.devices.clock.VirtualClock`: time passes only while
the host waits, and then every simulated millisecond the board driver's link is serviced
as its threads would on real time, but for the milliseconds on which nothing is due: while
the host waits for samples (the simulated board then captures the skipped span at the next
service, the same samples at the same instants) and while the board captures nothing (until
its next SYNC or STATUS, or the host's next KEEPALIVE): see
``VirtualTimeBoardLink.quiet_until_ns`` in :mod:`hil.devices.board_link_virtual`. A run is
therefore

- deterministic: the same experiment and seed give identical estimates and recording tables,
  however loaded the machine;
- as fast as the CPU allows: nothing waits on the wall clock (the homing and positioning
  moves take no wall time at all);
- held in one thread: no pseudo-terminals, no child process.

It is what the tests of the run logic use (``hil tank-run --virtual-time``); the default
demo runs the same devices on ptys in real time
(:class:`~hil.experiments.sim_tank.SimulatedTankProcess`), as real hardware is driven.

Everything from :mod:`sim_devices` is imported inside the functions (DESIGN: the host never
imports simulated devices at module level).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hil.devices.clock import VirtualClock
from hil.experiments.experiment import Experiment
from hil.experiments.sim_tank import build_tank_world, tank_stage_config

if TYPE_CHECKING:
    from hil.acquisition.device import StreamingDevice
    from hil.experiments.live.stops import DeviceLostError
    from hil.transports.base import Transport
    from hil.transports.sim import MemoryStageLink

#: Spacing of the instants the board's link may be serviced, s of virtual time: SYNC reaches
#: the host at most this late (1.5 mm of a 1.5 m/s tow).
SERVICE_TICK_S = 0.001


class VirtualTank:
    """The simulated stage and board of ``exp`` in this process, on :attr:`virtual_time`
    (see the module docstring). :attr:`stage_target` and :attr:`board_target` are the links
    the drivers open instead of URLs."""

    def __init__(self, exp: Experiment, *, tick_s: float = SERVICE_TICK_S) -> None:
        from hil.transports.sim import MemoryStageLink
        from sim_devices.board import BoardPort, FaultPlan, MemoryBoardLink, SimulatedBoard
        from sim_devices.stage import SimulatedGrbl

        clock = VirtualClock(tick_s)
        self.clock = clock
        self.virtual_time: VirtualClock | None = clock
        self._grbl = SimulatedGrbl(tank_stage_config(), clock=clock)
        self.stage_target: MemoryStageLink = MemoryStageLink(
            self._grbl, timeout=0.0, url="sim://stage (in process, virtual time)"
        )
        #: The simulated board's faults on demand (``faults.disconnect()``: unplugged).
        self.board_faults = FaultPlan()
        self._board = SimulatedBoard(
            clock=clock, world=build_tank_world(exp, self._carriage), faults=self.board_faults
        )
        self.board_target: Transport = MemoryBoardLink(
            BoardPort(self._board), timeout=0.0, url="sim://board (in process, virtual time)"
        )
        self._offset = 0.0

    def open_daq(self, fs: float) -> StreamingDevice:
        """The simulated board behind its in-memory link, open and configured at ``fs`` Hz
        on :attr:`virtual_time`."""
        from hil.devices.table import WATCHDOG_MS, open_board

        board = open_board(self.board_target, fs, self.clock, WATCHDOG_MS, self.virtual_time)
        board.configure()
        return board

    def align(self, rate_hz: float) -> None:
        """Tie world time (device sample / rate) to the clock (after CONFIGURE)."""
        now = self.clock.now()
        self._offset = now - self._board.sample_index(now) / rate_hz

    def _carriage(self, world_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._grbl.tick()  # every alarm and hold up to now applied before the plan is read
        return self._grbl.carriage_motion(self.stage_time(world_t))

    def stage_time(self, world_t: np.ndarray) -> np.ndarray:
        """Clock time (s) of world times (s)."""
        return np.asarray(world_t, dtype=np.float64) + self._offset

    def true_stage_position(self, clock_t: np.ndarray) -> np.ndarray:
        """The simulated carriage's true position (m) at clock times (s)."""
        return np.asarray(self._grbl.true_position(np.asarray(clock_t, dtype=np.float64)))

    @property
    def dac_underruns(self) -> int:
        """DAC underruns the simulated board counted."""
        return int(self._board.dac_underruns)

    @property
    def adc_overruns(self) -> int:
        """ADC overruns the simulated board counted."""
        return int(self._board.adc_overruns)

    @property
    def adc_clipped_samples(self) -> int:
        """ADC values the simulated board clipped at conversion."""
        return int(self._board.adc_clipped_samples)

    def lost(self, grace_s: float = 0.0) -> DeviceLostError | None:
        """Never: the simulation is this process."""
        return None

    def close(self) -> None:
        """Nothing to stop: the drivers closed the links."""
