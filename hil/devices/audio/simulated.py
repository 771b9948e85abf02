"""Where the simulated audio interface was: it lives in :mod:`sim_devices.audio.simulated`
(the simulated devices' package); its names are resolved from there when asked for, so
``from hil.devices.audio.simulated import SimulatedDuplex`` keeps working (DESIGN: the host
imports simulated devices only lazily)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sim_devices.audio.simulated import (
        Clock,
        DigitalLoopbackWorld,
        ManualClock,
        RealtimeClock,
        SimulatedDuplex,
        World,
    )

#: The names this module resolves from :mod:`sim_devices.audio.simulated`.
NAMES = (
    "Clock",
    "DigitalLoopbackWorld",
    "ManualClock",
    "RealtimeClock",
    "SimulatedDuplex",
    "World",
)
__all__ = [
    "Clock",
    "DigitalLoopbackWorld",
    "ManualClock",
    "RealtimeClock",
    "SimulatedDuplex",
    "World",
]


def __getattr__(name: str) -> Any:
    """``name`` from :mod:`sim_devices.audio.simulated`."""
    if name in NAMES:
        from sim_devices.audio import simulated

        return getattr(simulated, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
