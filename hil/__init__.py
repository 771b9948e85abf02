"""Host side of the CAS hardware-in-the-loop testbench.

Signals (HFC-CW and comparison waveforms), estimators (GCAS and baselines), device drivers,
acquisition, experiments and the ``hil`` command line. The host never imports
:mod:`sim_devices` at module level: simulated devices are reached lazily through the
device table (:mod:`hil.devices.table`, ``sim://...``) and the evaluation engine.

The main entry points are attributes of the package, imported on first use (PEP 562), so
``import hil`` stays as fast as the ``hil`` command's start::

    import hil
    schedule = hil.check_design(hil.get_preset("att").spec("random-cyclic"))
    fig = hil.spectrogram_figure(schedule, 100_000.0, 0.2)      # a matplotlib Figure
    run = hil.load_arrays("runs/x/run.h5")                        # NumPy arrays
    estimates = hil.replay("runs/x/run.h5")                        # re-run the live receiver

>>> import hil
>>> sorted(set(hil.__all__) - set(dir(hil)))
[]
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS: dict[str, str] = {
    # waveforms and schedules
    "get_preset": "hil.signals.presets",
    "check_design": "hil.signals.presets",
    "BlockSynthesizer": "hil.signals.synthesis",
    "HopSchedule": "hil.signals.schedule",
    "read_schedule_file": "hil.signals.schedule_file",
    "match_schedule": "hil.signals.schedule_match",
    # receivers
    "make_receiver": "hil.estimation.registry",
    "RECEIVERS": "hil.estimation.registry",
    "Estimate": "hil.estimation.base",
    # runs, recordings, replay
    "load_experiment": "hil.experiments.experiment",
    "parse_experiment": "hil.experiments.experiment",
    "run_experiment": "hil.experiments.tank_run",
    "RunRecording": "hil.recording.reader",
    "replay": "hil.recording.replay",
    "compare_estimates": "hil.recording.replay",
    "load_arrays": "hil.recording.arrays",
    # figures (matplotlib Figures, no backend switch)
    "spectrogram_figure": "hil.signals.plots",
    "occupancy_figure": "hil.signals.plots",
    "ambiguity_figure": "hil.signals.plots",
    "time_codeword_map_figure": "hil.experiments.codeword_map",
    # devices, calibration, data
    "open_transport": "hil.transports.registry",
    "open_stage": "hil.devices.table",
    "discover": "hil.devices.discovery",
    "CalibrationStore": "hil.experiments.calibration.store",
    "scenario_path": "hil.data",
    "sweeps_dir": "hil.data",
    "ConfigError": "hil.errors",
    "HilError": "hil.errors",
    "DeviceError": "hil.errors",
    "main": "hil.cli.main",
}
"""Public name -> the module defining it."""

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    """Import the module of an exported name on first access and cache the name here."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'hil' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
