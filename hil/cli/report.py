"""``hil report RUN.h5``: the summary and figures of a tank run, rebuilt from its recording.

For a run that could not write them (``kill -9``, a crash, power loss: its recording still
reads up to its last flush) or to write them again. Writes ``summary.json``,
``estimates.csv`` and the figures next to the recording (or into ``--out``) and prints the
summary as ``hil tank-run`` does. What a recording cannot give back is listed in
:mod:`hil.experiments.run_from_recording`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hil.errors import ConfigError

if TYPE_CHECKING:
    import numpy as np

    from hil.experiments.tank_run import RunOutcome

OPTION_NAMES = {"recording": "RUN"}


def register(sub: Any) -> None:
    """Add the ``report`` sub-command."""
    p: argparse.ArgumentParser = sub.add_parser(
        "report",
        help="rebuild a tank run's summary and figures from its recording",
        description="Rebuild summary.json, estimates.csv and the figures of a tank run from "
        "its recording run.h5 (also one left by a killed run). Without --out they go next "
        "to the recording, or into its folder's rebuilt/ when the run wrote its own "
        "summary.json (the live summary is never replaced).",
    )
    p.add_argument("run", type=Path, metavar="RUN", help="run recording (run.h5)")
    p.add_argument(
        "--out",
        type=Path,
        help="folder for the files (default: the recording's, or its rebuilt/ beside a live "
        "summary.json)",
    )
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument(
        "--exact-truth",
        type=Path,
        metavar="CSV",
        help="score the run against this exact truth too (truth-run-N.csv, written by hil "
        "sim-serve tank --jack beside its experiment file): range_rmse_vs_exact_m, "
        "speed_rmse_vs_exact_mps, telemetry_truth_error_max_m",
    )
    p.add_argument(
        "--no-map",
        action="store_true",
        help="skip the GCAS time-codeword map (it replays the receiver over the recording)",
    )
    p.set_defaults(func=run)


#: The folder ``hil report`` writes into, inside the run's folder, when that folder holds the
#: live run's ``summary.json`` already (never replaced: it has the wall time, the backlog and
#: the exact truth a recording cannot give back).
REBUILT = "rebuilt"


def report_folder(recording: Path, out: Path | None) -> Path:
    """Where ``hil report`` writes: ``out`` when given; else the recording's folder for a
    run that left no summary (killed), or ``<that folder>/rebuilt`` beside a live one.

    >>> report_folder(Path("runs/a/run.h5"), Path("elsewhere")).as_posix()
    'elsewhere'
    """
    if out is not None:
        return out
    folder = recording.parent
    return folder / REBUILT if (folder / "summary.json").exists() else folder


def with_exact_truth(outcome: RunOutcome, table: np.ndarray, path: Path) -> RunOutcome:
    """``outcome`` with its exact truth read from ``table`` (:mod:`hil.experiments.exact_truth`)
    at each estimate's bounce instant. Refused when the table does not cover the run's
    estimates (the truth of another run, or of a run cut short)."""
    import numpy

    from hil.experiments.exact_truth import truth_at
    from hil.experiments.run_scoring import bounce_times

    t_b = bounce_times(outcome)
    exact = truth_at(table, t_b)
    outside = int(numpy.count_nonzero(numpy.isnan(exact["range_m"])))
    if outside:
        raise ConfigError(
            "--exact-truth", str(path),
            f"a table covering the run's estimates ({t_b.min():.3f}-{t_b.max():.3f} s)",
            f"it covers {table[0, 0]:.3f}-{table[-1, 0]:.3f} s and misses {outside} of "
            f"{t_b.size} estimates: give the truth-run-N.csv of this run",
        )  # fmt: skip
    return dataclasses.replace(outcome, exact_truth=exact)


def run(args: argparse.Namespace) -> int:
    """Execute ``hil report``; 0, or 1 when the recorded run stopped on an error."""
    from hil.cli.tank_run import print_summary
    from hil.experiments.run_from_recording import outcome_from_recording
    from hil.experiments.run_report import write_report
    from hil.experiments.run_scoring import summarize, write_summary
    from hil.outputs import writable_folder

    out = writable_folder(report_folder(args.run, args.out), "--out")
    from hil.recording.reader import probe_structure

    probe_structure(args.run)
    table = None
    if args.exact_truth is not None:
        from hil.experiments.exact_truth import read_truth

        table = read_truth(args.exact_truth)
    outcome = outcome_from_recording(args.run, out, codeword_map=not args.no_map)
    if table is not None:
        outcome = with_exact_truth(outcome, table, args.exact_truth)
    summary = summarize(outcome)
    summary["rebuilt_from"] = str(args.run)
    write_summary(outcome, summary)
    figures = write_report(outcome)
    summary["figures"] = [str(p) for p in figures]
    (outcome.folder / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    print_summary(summary, outcome.folder, as_json=args.json)
    return 1 if outcome.error else 0
