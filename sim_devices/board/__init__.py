"""Simulated transducer board firmware: the DEVICE role of :mod:`firmware_protocol`.

- :class:`SimulatedBoard` (:mod:`.core`): sans-IO firmware on an injected sample clock.
- :class:`BoardSpec` (:mod:`.spec`): channels, formats, rates, buffers, identity.
- Worlds (:mod:`.worlds`): what the ADC captures from the DAC output
  (:class:`LoopbackWorld`; the acoustic channel plugs into the same hook).
- :class:`FaultPlan` (:mod:`.faults`): faults on demand.
- Runners: :class:`MemoryBoardLink` (in process), :class:`SimulatedBoardOnPty` (raw pty),
  :class:`SimulatedUsbBackend` (a pyusb backend object, :mod:`.usb_backend`; imported
  lazily because it needs pyusb).
"""

from sim_devices.board.core import BoardSnapshot, SimulatedBoard
from sim_devices.board.faults import FaultCounters, FaultPlan
from sim_devices.board.on_pty import SimulatedBoardOnPty
from sim_devices.board.port import BoardPort, MemoryBoardLink
from sim_devices.board.spec import BoardSpec
from sim_devices.board.worlds import LoopbackWorld, SilentWorld, World

__all__ = [
    "BoardPort",
    "BoardSnapshot",
    "BoardSpec",
    "FaultCounters",
    "FaultPlan",
    "LoopbackWorld",
    "MemoryBoardLink",
    "SilentWorld",
    "SimulatedBoard",
    "SimulatedBoardOnPty",
    "World",
]
