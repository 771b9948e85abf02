"""Simulated GRBL 1.1h motion stage: a sans-IO controller, its motion model and a pty host.

- :class:`SimulatedGrbl` (:mod:`.controller`): the controller core on an injected clock.
- :class:`GrblSimConfig` (:mod:`.config`): its settings (stock GRBL 1.1h by default).
- :mod:`.motion`, :mod:`.planner`, :mod:`.homing`: profiles, look-ahead, homing cycles.
- :class:`SimulatedGrblOnPty` (:mod:`.on_pty`): the controller behind a raw pty.
- :class:`ManualClock` (:mod:`.clock`): simulated time for tests.
"""

from sim_devices.stage.clock import ManualClock
from sim_devices.stage.config import GrblSimConfig
from sim_devices.stage.controller import GrblState, SimStatus, SimulatedGrbl
from sim_devices.stage.on_pty import SimulatedGrblOnPty

__all__ = [
    "GrblSimConfig",
    "GrblState",
    "ManualClock",
    "SimStatus",
    "SimulatedGrbl",
    "SimulatedGrblOnPty",
]
