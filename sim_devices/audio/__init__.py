"""The simulated full-duplex audio interface (:mod:`.simulated`): the callback contract of
:mod:`hil.devices.audio.contract` with a pluggable world, on an injected clock or virtual
time. ``hil.devices.audio.SimulatedDuplex`` and ``hil.devices.audio.simulated`` still
name it (resolved lazily)."""

from sim_devices.audio.simulated import (
    DigitalLoopbackWorld,
    RealtimeClock,
    SimulatedDuplex,
    World,
)

__all__ = ["DigitalLoopbackWorld", "RealtimeClock", "SimulatedDuplex", "World"]
