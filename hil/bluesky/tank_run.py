"""A towed-target tank run as an ophyd-async detector: :class:`TankRunDetector`.

``trigger()`` runs one tank run of an experiment (:func:`hil.experiments.tank_run.
run_experiment`: the board transmits and captures, the stage makes its passes, the receiver
estimates live, everything goes into ``run.h5``) and then writes the run's ``summary.json``
and report figures, as ``hil tank-run`` does. Its reading is the run's data:

- ``recording``: the path of the run's ``run.h5`` (the samples, telemetry, estimates);
- summary figures: estimates, scored estimates, range and speed RMSE (m, m/s), detection
  rate, dropped samples, loopback latency (samples);
- the stage telemetry the run recorded (``stage_time_s`` on the driver's clock,
  ``stage_position_m``, ``stage_velocity_mps``: the towed pass as the stage reported it)
  and the estimates (``estimate_time_s``, ``estimate_range_m``, ``estimate_speed_mps``),
  as 1-D arrays.

A run that fails after it started (an alarm, a stalled board) still reports what it
recorded, and its status fails with the run's error, so the RunEngine ends the bluesky run
with ``exit_status = "fail"``. The experiment's devices are opened by the run itself: a
simulated experiment (``sim://board`` and ``sim://stage``) starts the built-in simulated tank.

The run blocks on a worker thread; it cannot be interrupted from the RunEngine (a bluesky
pause or abort waits for the pass to end): stop a real run at the stage's e-stop.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import numpy as np
from bluesky.protocols import Triggerable
from ophyd_async.core import Array1D, AsyncStatus, StandardReadable, soft_signal_r_and_setter
from ophyd_async.core import StandardReadableFormat as Format

from hil.experiments.experiment import Experiment
from hil.experiments.tank_run import LiveView, RunOutcome, run_experiment

#: Summary fields read as scalars: (summary key, signal name, type, units).
_FIGURES: tuple[tuple[str, str, type, str], ...] = (
    ("estimates", "estimates", int, ""),
    ("scored_estimates", "scored_estimates", int, ""),
    ("range_rmse_m", "range_rmse_m", float, "m"),
    ("speed_rmse_mps", "speed_rmse_mps", float, "m/s"),
    ("detection_rate", "detection_rate", float, ""),
    ("dropped_samples", "dropped_samples", int, ""),
    ("loopback_latency_samples", "latency_samples", int, "samples"),
    ("signal_s", "signal_s", float, "s"),
)


class TankRunError(RuntimeError):
    """A tank run that stopped with an error or was interrupted (the message says which);
    what it recorded until then is in the detector's reading."""


class TankRunDetector(StandardReadable, Triggerable):
    """One towed-target tank run per trigger.

    Parameters
    ----------
    experiment:
        The validated experiment (:func:`hil.experiments.experiment.load_experiment` or
        :func:`~hil.experiments.experiment.parse_experiment`).
    runs_dir:
        Folder for the run folders (default the experiment's ``run.output_dir``); each
        trigger makes ``<runs_dir>/<run.name>-<YYYYmmdd-HHMMSS>[-k]``.
    report:
        Also write the report figures (``range_speed.png``, ...) after ``summary.json``.
    name:
        The device name (prefix of its data keys).
    """

    def __init__(
        self,
        experiment: Experiment,
        *,
        runs_dir: Path | None = None,
        report: bool = True,
        name: str = "",
    ) -> None:
        self.experiment = experiment
        self._runs_dir = runs_dir
        self._report = report
        #: The outcome and summary of the last triggered run (None before one).
        self.outcome: RunOutcome | None = None
        self.summary: dict[str, Any] | None = None
        self._setters: dict[str, Any] = {}
        with self.add_children_as_readables(Format.HINTED_UNCACHED_SIGNAL):
            self.recording = self._signal("recording", str, "", "")
        with self.add_children_as_readables(Format.UNCACHED_SIGNAL):
            for _, signal, kind, units in _FIGURES:
                setattr(self, signal, self._signal(signal, kind, kind(0), units))
            self.error = self._signal("error", str, "", "")
            for signal, units in (
                ("stage_time_s", "s"),
                ("stage_position_m", "m"),
                ("stage_velocity_mps", "m/s"),
                ("estimate_time_s", "s"),
                ("estimate_range_m", "m"),
                ("estimate_speed_mps", "m/s"),
            ):
                setattr(self, signal, self._signal(signal, Array1D[np.float64], None, units))
        with self.add_children_as_readables(Format.CONFIG_SIGNAL):
            tow = experiment.tow
            self.experiment_name = self._signal("experiment_name", str, experiment.name, "")
            self.board_url = self._signal("board_url", str, experiment.board_url, "")
            self.stage_url = self._signal("stage_url", str, experiment.stage_url, "")
            self.tow_start_m = self._signal("tow_start_m", float, tow.start_m, "m")
            self.tow_end_m = self._signal("tow_end_m", float, tow.end_m, "m")
            self.tow_speed_mps = self._signal("tow_speed_mps", float, tow.speed_mps, "m/s")
            self.tow_repeats = self._signal("tow_repeats", int, tow.repeats, "")
        super().__init__(name=name)

    def _signal(self, key: str, kind: Any, initial: Any, units: str) -> Any:
        signal, setter = soft_signal_r_and_setter(kind, initial, units=units or None)
        self._setters[key] = setter
        return signal

    def new_run_folder(self) -> Path:
        """A new, empty folder for the next run (two runs in one second get ``-2``, ``-3``,
        ... suffixes; :func:`hil.experiments.live.plan.new_run_folder`)."""
        import datetime as dt

        from hil.experiments.live.plan import new_run_folder

        exp = self.experiment
        out_dir = self._runs_dir if self._runs_dir is not None else exp.output_dir
        return new_run_folder(out_dir, exp.name, None, dt.datetime.now())

    @AsyncStatus.wrap
    async def trigger(self) -> None:
        """Run the experiment once; fails with :class:`TankRunError` if the run did."""
        folder = self.new_run_folder()
        outcome, summary = await asyncio.to_thread(self._run, folder)
        self.outcome, self.summary = outcome, summary
        self._publish(outcome, summary)
        if outcome.error or outcome.interrupted:
            raise TankRunError(
                f"tank run in {folder} stopped: {outcome.error or 'interrupted'}; what it"
                " recorded is in run.h5"
            )

    def _run(self, folder: Path) -> tuple[RunOutcome, dict[str, Any]]:
        from hil.experiments.run_report import write_report
        from hil.experiments.run_scoring import summarize, write_summary

        outcome = run_experiment(self.experiment, folder=folder, view=LiveView(enabled=False))
        summary = summarize(outcome)
        write_summary(outcome, summary)
        if self._report:
            summary["figures"] = [str(p) for p in write_report(outcome)]
        return outcome, summary

    def _publish(self, outcome: RunOutcome, summary: dict[str, Any]) -> None:
        put = self._setters
        h5 = outcome.folder / "run.h5"
        put["recording"](str(h5) if h5.exists() else "")
        for key, signal, kind, _ in _FIGURES:
            value = summary.get(key)
            put[signal](kind(value) if value is not None else (np.nan if kind is float else -1))
        put["error"](outcome.error or ("interrupted" if outcome.interrupted else ""))
        tel, est = outcome.telemetry, outcome.estimates
        put["stage_time_s"](np.asarray(tel.host_time_s, dtype=np.float64))
        put["stage_position_m"](np.asarray(tel.position_m, dtype=np.float64))
        put["stage_velocity_mps"](np.asarray(tel.velocity_mps, dtype=np.float64))
        put["estimate_time_s"](np.array([e.t_s for e in est], dtype=np.float64))
        put["estimate_range_m"](np.array([e.range_m for e in est], dtype=np.float64))
        put["estimate_speed_mps"](np.array([e.speed_mps for e in est], dtype=np.float64))
