"""A towed-target tank run as an ophyd-async detector: :class:`TankRunDetector`.

``trigger()`` runs one tank run of an experiment (:func:`hil.experiments.tank_run.
run_experiment`: the board transmits and captures, the stage makes its passes, the receiver
estimates live, everything goes into ``run.h5``) and then writes the run's ``run.log``,
``summary.json`` and report figures, as ``hil tank-run`` does. Its reading holds values of
fixed shape only, the same for every run (so every event matches the descriptor):

- ``recording``: the path of the run's ``run.h5`` (the samples, telemetry, estimates);
- summary figures (estimates, range and speed RMSE, detection rate hinted): estimates,
  scored estimates, range and speed RMSE (m, m/s), detection rate, dropped samples, loopback
  latency (samples), signal recorded (s); ``error`` and ``interrupted``.

The estimates and the stage telemetry, whose lengths differ from run to run, go in their own
event streams, one event per estimate or telemetry report (:func:`hil.bluesky.plans.
tank_streams`, which :func:`~hil.bluesky.plans.towed_pass` calls).

A run that fails after it started (an alarm, a stalled board) still reports what it
recorded, and its status fails with the run's error, so the RunEngine ends the bluesky run
with ``exit_status = "fail"``. The experiment's devices are opened by the run itself: a
simulated experiment (``sim://board`` and ``sim://stage``) starts the built-in simulated tank.

Stopping: a RunEngine pause (Ctrl-C, ``RE.request_pause()``) stops the run in flight safely
(transmission off, stage held, the recording closed with its stop event, ``summary.json``
saying ``interrupted: true``) and waits for that; ``RE.resume()`` then repeats the trigger from
its checkpoint as a new run. ``stop()``, an abort and ``unstage()`` stop it the same way.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from bluesky.protocols import Pausable, Stoppable, Triggerable
from ophyd_async.core import AsyncStatus, StandardReadable, soft_signal_r_and_setter
from ophyd_async.core import StandardReadableFormat as Format

from hil.estimation.base import Estimate
from hil.experiments.experiment import Experiment
from hil.experiments.tank_run import LiveView, RunOutcome, run_experiment

_LOG = logging.getLogger(__name__)

#: Summary fields read as scalars: (summary key, signal name, type, units, hinted).
_FIGURES: tuple[tuple[str, str, type, str, bool], ...] = (
    ("estimates", "estimates", int, "", True),
    ("scored_estimates", "scored_estimates", int, "", False),
    ("range_rmse_m", "range_rmse_m", float, "m", True),
    ("speed_rmse_mps", "speed_rmse_mps", float, "m/s", True),
    ("detection_rate", "detection_rate", float, "", True),
    ("dropped_samples", "dropped_samples", int, "", False),
    ("loopback_latency_samples", "latency_samples", int, "samples", False),
    ("signal_s", "signal_s", float, "s", False),
)


class StreamRow:
    """One row of a table of equal-length 1-D arrays as a bluesky readable: ``read()`` gives
    the fields at :attr:`index` (scalars, so every event has the descriptor's shape)."""

    def __init__(self, name: str, columns: dict[str, tuple[str, np.ndarray]]) -> None:
        self.name = name
        self.parent = None
        #: The row ``read()`` gives.
        self.index = 0
        self.columns = columns

    def __len__(self) -> int:
        """The number of rows."""
        return len(next(iter(self.columns.values()))[1])

    def describe(self) -> dict[str, Any]:
        """Data keys ``<name>-<field>``: float scalars with their units."""
        return {
            f"{self.name}-{field}": {
                "source": f"{self.name}:{field}",
                "dtype": "number",
                "shape": [],
                "dtype_numpy": "<f8",
                "units": units,
            }
            for field, (units, _) in self.columns.items()
        }

    def read(self) -> dict[str, Any]:
        """The fields at :attr:`index`."""
        now = time.time()
        return {
            f"{self.name}-{field}": {"value": float(values[self.index]), "timestamp": now}
            for field, (_, values) in self.columns.items()
        }

    def describe_configuration(self) -> dict[str, Any]:
        """No configuration."""
        return {}

    def read_configuration(self) -> dict[str, Any]:
        """No configuration."""
        return {}


class TankRunError(RuntimeError):
    """A tank run that stopped with an error or was interrupted (the message says which);
    what it recorded until then is in the detector's reading."""


class TankRunDetector(StandardReadable, Triggerable, Stoppable, Pausable):
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
    virtual_time:
        Run the built-in simulated tank in this process on virtual time (deterministic,
        as fast as the CPU allows; ``sim://`` devices only, as ``hil tank-run
        --virtual-time``).
    on_estimates:
        Called with each batch of the receiver's estimates as the run makes them (on the
        run's thread).
    name:
        The device name (prefix of its data keys).
    """

    def __init__(
        self,
        experiment: Experiment,
        *,
        runs_dir: Path | None = None,
        report: bool = True,
        virtual_time: bool = False,
        on_estimates: Callable[[list[Estimate]], None] | None = None,
        name: str = "",
    ) -> None:
        self.experiment = experiment
        self._runs_dir = runs_dir
        self._report = report
        self._virtual_time = virtual_time
        self._on_estimates = on_estimates
        #: Set to stop the run in flight (by stop, pause, unstage); cleared by each trigger.
        self.stop_requested = threading.Event()
        self._stop_success = True
        self._running: asyncio.Future[tuple[RunOutcome, dict[str, Any]]] | None = None
        #: The outcome and summary of the last triggered run (None before one).
        self.outcome: RunOutcome | None = None
        self.summary: dict[str, Any] | None = None
        self._setters: dict[str, Any] = {}
        self._rows: dict[str, StreamRow] = {}
        with self.add_children_as_readables(Format.HINTED_UNCACHED_SIGNAL):
            for _, signal, kind, units, hinted in _FIGURES:
                if hinted:
                    setattr(self, signal, self._signal(signal, kind, kind(0), units))
        with self.add_children_as_readables(Format.UNCACHED_SIGNAL):
            self.recording = self._signal("recording", str, "", "")
            for _, signal, kind, units, hinted in _FIGURES:
                if not hinted:
                    setattr(self, signal, self._signal(signal, kind, kind(0), units))
            self.error = self._signal("error", str, "", "")
            self.interrupted = self._signal("interrupted", bool, False, "")
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

    # ------------------------------------------------------------------ trigger
    @AsyncStatus.wrap
    async def trigger(self) -> None:
        """Run the experiment once. Fails with :class:`TankRunError` if the run stopped on
        an error, or was stopped by ``stop(success=False)``, ``unstage()`` or an abort; one
        stopped by a pause or ``stop(success=True)`` completes with what it recorded."""
        self.stop_requested.clear()
        self._stop_success = True
        folder = self.new_run_folder()
        self._running = asyncio.ensure_future(asyncio.to_thread(self._run, folder))
        try:
            outcome, summary = await asyncio.shield(self._running)
        finally:
            self._running = None
        self.outcome, self.summary = outcome, summary
        self._publish(outcome, summary)
        stopped_on_request = outcome.interrupted and self.stop_requested.is_set()
        failed = bool(outcome.error) and not stopped_on_request
        if failed or (stopped_on_request and not self._stop_success):
            raise TankRunError(
                f"tank run in {folder} stopped: {outcome.error or 'interrupted'}; what it"
                " recorded is in run.h5"
            )

    def _run(self, folder: Path) -> tuple[RunOutcome, dict[str, Any]]:
        from hil.outputs import release_output_folder

        try:
            return self._run_in(folder)
        finally:
            release_output_folder(folder)

    def _run_in(self, folder: Path) -> tuple[RunOutcome, dict[str, Any]]:
        from hil.experiments.run_log import log_outcome
        from hil.experiments.run_report import write_report
        from hil.experiments.run_scoring import summarize, write_summary
        from hil.logs import run_log

        with run_log(folder):
            _LOG.info("tank run %r into %s (a bluesky trigger)", self.experiment.name, folder)
            outcome = run_experiment(
                self.experiment,
                folder=folder,
                view=LiveView(enabled=False),
                on_estimates=self._on_estimates,
                stop=self.stop_requested,
                virtual_time=self._virtual_time,
            )
            summary = summarize(outcome)
            write_summary(outcome, summary)
            if self._report:
                summary["figures"] = [str(p) for p in write_report(outcome)]
            log_outcome(outcome, summary)
        return outcome, summary

    # ------------------------------------------------------------------ stopping
    async def stop(self, success: bool = True) -> None:
        """Stop the run in flight safely and wait for its end (nothing when idle): its
        trigger completes with what it recorded (``success``) or fails."""
        self._stop_success = success
        await self._stop_and_wait()

    async def pause(self) -> None:
        """A RunEngine pause: the run in flight stops safely (its folder keeps what it
        recorded, ``interrupted: true``); ``RE.resume()`` triggers a new run."""
        await self.stop(success=True)

    async def resume(self) -> None:
        """Nothing to do: the RunEngine repeats the trigger from its checkpoint."""

    def unstage(self) -> AsyncStatus:
        """Stop a run in flight (an abort, a failed plan), then unstage the signals. The
        stop is requested at once, before the returned status runs: the RunEngine calls
        ``unstage`` on its way out without awaiting it."""
        if self._running is not None:
            self._stop_success = False
            self.stop_requested.set()
        return self._unstage_after_stop()

    @AsyncStatus.wrap
    async def _unstage_after_stop(self) -> None:
        await self._stop_and_wait()
        await super().unstage()

    async def _stop_and_wait(self) -> None:
        running = self._running
        if running is None:
            return
        self.stop_requested.set()
        await asyncio.wait({running})

    # ------------------------------------------------------------------ reading
    def _publish(self, outcome: RunOutcome, summary: dict[str, Any]) -> None:
        put = self._setters
        h5 = outcome.folder / "run.h5"
        put["recording"](str(h5) if h5.exists() else "")
        for key, signal, kind, _, _ in _FIGURES:
            value = summary.get(key)
            put[signal](kind(value) if value is not None else (np.nan if kind is float else -1))
        put["error"](outcome.error or ("interrupted" if outcome.interrupted else ""))
        put["interrupted"](bool(outcome.interrupted))

    def stream_rows(self) -> dict[str, StreamRow]:
        """The last run's variable-length data as one readable per event stream:
        ``estimates`` and ``telemetry`` (columns ``{field: (units, 1-D array)}`` of equal
        lengths; no rows before a run). The same readables every run, so a stream keeps
        one descriptor over several triggers."""
        outcome = self.outcome
        est = outcome.estimates if outcome is not None else []
        tel = outcome.telemetry if outcome is not None else None

        def column(values: Any) -> np.ndarray:
            return np.asarray(values, dtype=np.float64).reshape(-1)

        columns = {
            "estimates": {
                "estimate_time_s": ("s", column([e.t_s for e in est])),
                "estimate_range_m": ("m", column([e.range_m for e in est])),
                "estimate_speed_mps": ("m/s", column([e.speed_mps for e in est])),
            },
            "telemetry": {
                "stage_time_s": ("s", column(tel.host_time_s if tel else [])),
                "stage_position_m": ("m", column(tel.position_m if tel else [])),
                "stage_velocity_mps": ("m/s", column(tel.velocity_mps if tel else [])),
            },
        }
        for stream, table in columns.items():
            row = self._rows.setdefault(stream, StreamRow(self.name, table))
            row.name, row.columns, row.index = self.name, table, 0
        return dict(self._rows)
