"""Run a sweep into a folder: manifest, streamed results, resume, progress, summary.

>>> import tempfile
>>> from hil.evaluation.runners import SerialRunner
>>> from hil.evaluation.sweep_file import sweep_from_dict
>>> spec = sweep_from_dict({"sweep": {"name": "doc", "trial": "waveform_af_sidelobe",
...                                   "trials_per_point": 2, "seed": 1},
...                         "grid": {"n_tones": [4, 5]}})
>>> with tempfile.TemporaryDirectory() as out:
...     outcome = run_sweep(spec, out, SerialRunner(), show_progress=False)
>>> outcome.ran, outcome.n_ok, [row["n_tones"] for row in outcome.rows]
(4, 4, [4, 5])
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TextIO

from hil.errors import ConfigError
from hil.evaluation.aggregate import latest_records, summarise, write_summary_csv
from hil.evaluation.progress import Progress
from hil.evaluation.registry import load_trial, trial_reporter
from hil.evaluation.runners import Runner
from hil.evaluation.spec import SweepSpec
from hil.evaluation.store import SweepStore
from hil.interrupts import RunInterrupted, interruption, stops_deferred


@dataclass(frozen=True)
class SweepOutcome:
    """What a (possibly resumed) sweep produced.

    ``records``: the latest record of every finished trial, by trial id; ``rows``: the
    summary per grid point; ``ran``: trials run by this call; ``skipped``: trials found
    finished on disk; ``elapsed_s``: wall time of this call's trials, s; ``reports``: the
    files the trial's report wrote (none for a trial without one, or an incomplete sweep).
    """

    spec: SweepSpec
    store: SweepStore
    records: list[dict[str, Any]]
    rows: list[dict[str, Any]]
    ran: int
    skipped: int
    elapsed_s: float
    reports: tuple[Path, ...] = ()

    @property
    def n_ok(self) -> int:
        """Finished trials that returned a result."""
        return sum(r["status"] == "ok" for r in self.records)

    @property
    def n_failed(self) -> int:
        """Finished trials that raised."""
        return len(self.records) - self.n_ok

    @property
    def complete(self) -> bool:
        """Every trial of the grid has a record."""
        return len(self.records) == self.spec.n_trials

    @property
    def trials_per_s(self) -> float:
        """Throughput of this call (0 when nothing ran)."""
        return self.ran / self.elapsed_s if self.elapsed_s > 0 else 0.0


def run_sweep(
    spec: SweepSpec,
    out_dir: str | Path,
    runner: Runner,
    *,
    resume: bool = False,
    show_progress: bool = True,
    progress_stream: TextIO | None = None,
) -> SweepOutcome:
    """Run every trial of ``spec`` not yet recorded in ``out_dir``, streaming records to disk.

    A folder that already holds a sweep is refused unless ``resume`` is set; with ``resume``
    its manifest must match ``spec`` and the trials already recorded (finished or failed) are
    not run again. A trial that raises is recorded with its error and the sweep goes on.
    ``summary.csv`` is written at the end, then the trial's report (if it has one:
    :func:`~hil.evaluation.registry.trial_reporter`) once every trial has a record. The
    runner's lifetime is the caller's (use it as a context manager to reuse its workers
    across sweeps).
    """
    store = SweepStore(out_dir)
    if store.has_sweep():
        if not resume:
            raise ConfigError(
                "--out",
                str(store.out_dir),
                "a folder without a sweep in it",
                "pass --resume to continue that sweep, or choose another --out folder",
            )
        manifest = store.check_manifest(spec)
        records = store.read_records()
        _check_records(spec, store, records)
        store.add_run(manifest, runner.describe())
    else:
        store.new_manifest(spec, runner.describe())
        records = []
    done = set(latest_records(records))
    progress = (
        Progress(spec.n_trials, already_done=len(done), label=spec.name, stream=progress_stream)
        if show_progress
        else None
    )
    ran = 0
    start = time.perf_counter()
    try:
        with store.appender() as writer:
            for record in runner.run(spec.target, spec.tasks(skip=done)):
                writer.write(record)
                records.append(record)
                ran += 1
                if progress is not None:
                    progress.update(record["status"] == "ok")
    except KeyboardInterrupt as exc:
        # Every finished trial is already a line of results.jsonl; the summary of those
        # is written too, so the folder says where the sweep stands and --resume goes on.
        with stops_deferred():
            outcome = _finish(spec, store, records, ran, len(done), start)
        raise SweepInterrupted(outcome, interruption(exc)) from None
    finally:
        if progress is not None:
            progress.close()
    outcome = _finish(spec, store, records, ran, len(done), start)
    reporter = trial_reporter(load_trial(spec.target))
    if reporter is None or not outcome.complete:
        return outcome
    try:
        reports = tuple(reporter(spec, outcome.records, store.out_dir))
    except KeyboardInterrupt as exc:
        # Every trial is saved; the report's files may be half written. A resume runs no
        # trial and writes the report again from the saved records.
        raise SweepInterrupted(outcome, interruption(exc), in_report=True) from None
    return replace(outcome, reports=reports)


class SweepInterrupted(RunInterrupted):
    """Ctrl-C or a stop signal ended :func:`run_sweep` early; ``outcome`` is what is saved
    (the finished trials and their summary), ``signal_name`` what stopped it; ``in_report``:
    it came while the trial's report was being written (every trial saved, the report's
    files possibly partial)."""

    def __init__(self, outcome: SweepOutcome, signal_name: str, *, in_report: bool = False) -> None:
        super().__init__(signal_name)
        self.outcome = outcome
        self.in_report = in_report


def _finish(
    spec: SweepSpec,
    store: SweepStore,
    records: list[dict[str, Any]],
    ran: int,
    skipped: int,
    start: float,
) -> SweepOutcome:
    """Write ``summary.csv`` of the latest record of every trial and return the outcome."""
    elapsed = time.perf_counter() - start
    latest = sorted(latest_records(records).values(), key=lambda r: int(r["trial_id"]))
    rows = summarise(spec, latest)
    write_summary_csv(store.summary_path, spec, rows)
    return SweepOutcome(spec, store, latest, rows, ran, skipped, elapsed)


def _check_records(spec: SweepSpec, store: SweepStore, records: list[dict[str, Any]]) -> None:
    for rec in records:
        trial_id = rec.get("trial_id")
        if not isinstance(trial_id, int) or not 0 <= trial_id < spec.n_trials:
            raise ConfigError(
                str(store.results_path),
                trial_id,
                f"trial ids in 0..{spec.n_trials - 1} (this sweep's grid)",
                "the results belong to another sweep: use a new --out folder",
            )
