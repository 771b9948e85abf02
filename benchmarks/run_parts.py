"""Where a tank run on virtual time spends its CPU: exclusive process CPU time per part.

:func:`measure_parts` wraps the entry points of each part (:data:`PARTS`) for the duration of
a ``with`` block; time spent inside a part's entry point, less what nested parts took, is
charged to it (a stack, so ``world`` inside ``board`` counts once, for the world). What no
part claims is ``rest`` (setup, preflight, the run's own loop, the report). The wrappers cost
about a microsecond a call, so the breakdown comes from a run of its own, not the timed one.

Used by ``benchmarks/bench_virtual_run.py``.
"""

from __future__ import annotations

import functools
import importlib
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

#: part name -> (module, attribute path) of its entry points. Order: the breakdown's order.
PARTS: dict[str, tuple[tuple[str, str], ...]] = {
    "world: target echoes": (("sim_devices.acoustics.grid_echo", "EchoBank.block"),),
    "world: tank's own echoes": (("sim_devices.acoustics.tank_response", "TankEchoes.generate"),),
    "world: reverberation": (
        ("sim_devices.acoustics.reverberation", "VolumeReverberation.generate"),
    ),
    "world: noise": (("sim_devices.acoustics.noise_generator", "ShapedNoiseGenerator.generate"),),
    "world: rest": (("sim_devices.acoustics.dac_world", "ScheduleWorld.__call__"),),
    "stage (simulated GRBL, its link)": (
        ("sim_devices.stage.controller", "SimulatedGrbl.tick"),
        ("sim_devices.stage.controller", "SimulatedGrbl.receive_data"),
        ("sim_devices.stage.controller", "SimulatedGrbl.carriage_motion"),
        ("hil.transports.sim", "MemoryStageLink.read"),
        ("hil.transports.sim", "MemoryStageLink.write"),
    ),
    "board (simulated firmware)": (
        ("sim_devices.board.core", "SimulatedBoard.tick"),
        ("sim_devices.board.core", "SimulatedBoard.receive_data"),
    ),
    "board driver (host service)": (
        ("hil.devices.board_link_virtual", "VirtualTimeBoardLink._service"),
    ),
    "virtual clock": (
        ("hil.devices.clock", "VirtualClock.sleep"),
        ("hil.devices.clock", "VirtualClock.wait_until"),
    ),
    "first-arrival readout": (
        ("hil.estimation.first_arrival", "FirstArrivalReadout.first_arrival"),
    ),
    "receiver (GCAS, canceller, tracker)": (("hil.acquisition.feed", "ReceiverFeed.feed"),),
    "recording": (
        ("hil.experiments.live.recorder", "RunRecorder.samples"),
        ("hil.experiments.live.recorder", "RunRecorder.estimates"),
        ("hil.experiments.live.recorder", "RunRecorder.telemetry"),
        ("hil.experiments.live.recorder", "RunRecorder.sync"),
        ("hil.recording.writer", "RunWriter.close"),
    ),
}


class _Ledger:
    """Exclusive CPU seconds per part (a stack of the parts entered)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {name: 0.0 for name in PARTS}
        self._stack: list[str] = []
        self._mark = time.process_time()

    def _charge(self) -> None:
        now = time.process_time()
        if self._stack:
            self.seconds[self._stack[-1]] += now - self._mark
        self._mark = now

    def wrap(self, part: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(fn)
        def timed(*args: Any, **kwargs: Any) -> Any:
            self._charge()
            self._stack.append(part)
            try:
                return fn(*args, **kwargs)
            finally:
                self._charge()
                self._stack.pop()

        return timed


@contextmanager
def measure_parts() -> Iterator[dict[str, float]]:
    """Within the block, CPU time is charged to :data:`PARTS`; the dict it yields holds the
    seconds per part once the block ends (``rest``: the block's CPU no part claimed)."""
    ledger = _Ledger()
    undo: list[tuple[Any, str, Any]] = []
    for part, entries in PARTS.items():
        for module, path in entries:
            owner_name, attr = path.split(".")
            owner = getattr(importlib.import_module(module), owner_name)
            original = owner.__dict__[attr]
            undo.append((owner, attr, original))
            setattr(owner, attr, ledger.wrap(part, original))
    result: dict[str, float] = {}
    cpu0 = time.process_time()
    try:
        yield result
    finally:
        total = time.process_time() - cpu0
        for owner, attr, original in reversed(undo):
            setattr(owner, attr, original)
        result.update(ledger.seconds)
        result["rest"] = total - sum(ledger.seconds.values())
        result["total"] = total
