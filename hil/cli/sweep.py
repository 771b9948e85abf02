"""``hil sweep``: run a Monte Carlo sweep file on a process pool or a Dask cluster.

Example::

    hil sweep sweeps/psl.toml --out runs/psl --workers 2
    hil sweep sweeps/psl.toml --out runs/psl --resume          # after an interruption
    hil sweep sweeps/psl.toml --out runs/psl --scheduler tcp://10.0.0.5:8786
    hil sweep tank-mc --out runs/tank --quick                  # a shipped sweep, reduced
    hil sweep scenes --out runs/scenes                         # the receiver's scenes

SWEEP is a sweep file or the name of a shipped one (``hil/data/sweeps/``: ``tank-mc``,
``scenes`` and the chapter-6 items). Writes ``manifest.json``, ``results.jsonl`` and
``summary.csv`` in ``--out`` (docs/sweeps.md), and the trial's report when it has one
(``tank_run``: ``report.md``, ``tank_points.csv``, ``figures/``; ``scene``: ``report.md``,
``scene_points.csv``, ``figures/``), and prints a summary. Exit status 0 when every trial
succeeded, 1 when some failed (their errors are in results.jsonl), 2 for a bad sweep file or
option, 130 when interrupted (Ctrl-C, SIGTERM or SIGHUP: the finished trials are saved and
``--resume`` continues from them, or rebuilds the report that the interruption left partial;
the pool's workers end with the command, even when it is killed with ``kill -9``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from hil.evaluation.aggregate import STATS
from hil.evaluation.engine import SweepInterrupted, SweepOutcome, run_sweep
from hil.evaluation.runners import Runner, make_runner
from hil.evaluation.sweep_file import load_sweep_file, shipped_sweeps

#: Exit status after Ctrl-C or a stop signal (as for every hil command).
EXIT_INTERRUPTED = 130

# Numeric fields shown in the printed table (all of them are in summary.csv).
_SHOWN_FIELDS = 4


def register(sub: Any) -> None:
    """Add the ``sweep`` sub-command."""
    p: argparse.ArgumentParser = sub.add_parser(
        "sweep",
        help="run a Monte Carlo sweep (grid x repetitions) and summarise it",
        description="Run every trial of a sweep file (format: hil docs sweeps), streaming one "
        "JSON line per trial to DIR/results.jsonl, then write DIR/summary.csv (and the trial's "
        "report, if it has one). By default on a local process pool with one worker per core.",
    )
    p.add_argument(
        "sweep_file",
        metavar="SWEEP",
        help="a sweep file (.toml) or a shipped sweep's name: " + ", ".join(shipped_sweeps()),
    )
    p.add_argument(
        "--out",
        type=Path,
        required=True,
        metavar="DIR",
        help="output folder (required: it is the work --resume continues)",
    )
    p.add_argument(
        "--quick", action="store_true", help="the file's [quick] grid and trial count (a smoke run)"
    )
    add_runner_options(p)
    p.add_argument(
        "--resume", action="store_true", help="continue the sweep in DIR, skipping finished trials"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the summary rows as JSON")
    p.set_defaults(func=run)


def add_runner_options(p: argparse.ArgumentParser) -> None:
    """Where the trials run: ``--workers``, ``--serial``, ``--dask-workers``, ``--scheduler``
    (one of them; :func:`runner_of` makes the runner)."""
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--workers", type=int, metavar="N", help="local pool processes (default: one per core)"
    )
    where.add_argument(
        "--serial", action="store_true", help="run trials one by one in this process (debug)"
    )
    where.add_argument(
        "--dask-workers", type=int, metavar="N", help="start a local Dask cluster of N workers"
    )
    where.add_argument(
        "--scheduler", metavar="tcp://HOST:PORT", help="run on the Dask scheduler at this address"
    )


def runner_of(args: argparse.Namespace) -> Runner:
    """The runner the options of :func:`add_runner_options` ask for."""
    return make_runner(
        workers=args.workers,
        dask_workers=args.dask_workers,
        scheduler=args.scheduler,
        serial=args.serial,
    )


def run(args: argparse.Namespace) -> int:
    """Execute ``hil sweep``; return the exit status."""
    from hil.outputs import writable_folder

    spec = load_sweep_file(args.sweep_file, quick=args.quick)
    writable_folder(args.out, "--out")
    runner = runner_of(args)
    try:
        with runner:
            for note in runner.notes:
                print(f"hil sweep: note: {note}", file=sys.stderr)
            outcome = run_sweep(
                spec, args.out, runner, resume=args.resume, show_progress=not args.quiet
            )
            where = f"{runner.name} ({runner.workers} worker{'s' * (runner.workers != 1)})"
    except SweepInterrupted as stop:
        # The runner has ended its workers by now (Runner.abort); the finished trials are saved.
        saved = stop.outcome
        resume = f"hil sweep {args.sweep_file} --out {args.out}{' --quick' * args.quick} --resume"
        if stop.in_report:
            print(
                f"hil sweep: interrupted ({stop.signal_name}) while writing the report: all "
                f"{spec.n_trials} trials are saved in {saved.store.results_path}, but the "
                f"report in {args.out} may be partial; rebuild it with: {resume}",
                file=sys.stderr,
            )
            return EXIT_INTERRUPTED
        print(
            f"hil sweep: interrupted ({stop.signal_name}): {len(saved.records)} of "
            f"{spec.n_trials} trials saved in {saved.store.results_path}; continue with: "
            f"{resume}",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    if args.json:
        print(json.dumps(outcome.rows))
    else:
        print(_report(outcome, where))
    return 0 if outcome.n_failed == 0 else 1


def _report(outcome: SweepOutcome, where: str) -> str:
    spec = outcome.spec
    store = outcome.store
    lines = [
        f"sweep {spec.name}: trial {spec.trial}, {spec.n_points} point(s) x "
        f"{spec.trials_per_point} = {spec.n_trials} trials, seed {spec.seed}",
        f"ran {outcome.ran} ({outcome.skipped} already done) in {outcome.elapsed_s:.1f} s on "
        f"{where}: {outcome.trials_per_s:.2f} trials/s; "
        f"{outcome.n_ok} ok, {outcome.n_failed} failed",
    ]
    lines += _table(outcome)
    failed = [r for r in outcome.records if r["status"] != "ok"]
    if failed:
        first = failed[0]
        err = first["error"]
        lines.append(
            f"first failure: trial {first['trial_id']} (point {first['point']}, rep "
            f"{first['rep']}): {err['type']}: {err['message']} (details in {store.results_path})"
        )
    lines.append(f"wrote {store.manifest_path}, {store.results_path}, {store.summary_path}")
    if outcome.reports:
        lines.append("report: " + ", ".join(str(p) for p in outcome.reports))
    return "\n".join(lines)


def _table(outcome: SweepOutcome) -> list[str]:
    rows = outcome.rows
    if not rows:
        return []
    stat_cols = [c for c in rows[0] if c.endswith(("_mean", "_rmse"))]
    fields = list(dict.fromkeys(c.rsplit("_", 1)[0] for c in stat_cols))[:_SHOWN_FIELDS]
    shown = [f"{f}_{s}" for f in fields for s in STATS[:2]]
    cols = ["point", *outcome.spec.grid, "n_ok", "n_failed", *shown]
    cells = [[_fmt(row.get(c)) for c in cols] for row in rows]
    widths = [max(len(c), *(len(r[i]) for r in cells)) for i, c in enumerate(cols)]
    out = ["  ".join(c.rjust(w) for c, w in zip(cols, widths, strict=True))]
    out += ["  ".join(v.rjust(w) for v, w in zip(r, widths, strict=True)) for r in cells]
    return out


def _fmt(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return str(value)
