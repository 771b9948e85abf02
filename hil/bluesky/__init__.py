"""bluesky/ophyd-async devices and plans for the tank (the ``bluesky`` extra).

A lab that runs its beamline-style experiments with bluesky drives the testbench from its
RunEngine:

- :class:`~hil.bluesky.stage.GrblStageDevice`: the GRBL tow stage as a movable
  (position readback in m, ``set`` moves, ``stop`` is a feed hold);
- :class:`~hil.bluesky.tank_run.TankRunDetector`: a towed-target tank run as a triggerable
  detector whose data is the run's recording (``run.h5``), its summary figures and the
  stage telemetry and estimates it recorded;
- :func:`~hil.bluesky.plans.towed_pass`: the plan of one towed pass.

Nothing here is imported by ``hil`` itself: ``import hil.bluesky`` needs
``pip install 'cas-hil[bluesky]'`` (docs/bluesky.md).
"""

from __future__ import annotations

from hil.bluesky.plans import tank_shot, tank_streams, towed_pass
from hil.bluesky.stage import GrblStageDevice
from hil.bluesky.tank_run import TankRunDetector

__all__ = ["GrblStageDevice", "TankRunDetector", "tank_shot", "tank_streams", "towed_pass"]
