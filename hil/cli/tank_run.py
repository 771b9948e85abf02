"""``hil tank-run [EXPERIMENT.toml]``: the towed-target tank run.

Without a file it runs the built-in simulated tank (simulated board and GRBL stage over
ptys, the acoustic world with tank walls, surface, noise, reverberation and the towed target
following the simulated carriage); ``--virtual-time`` runs that tank in this process on
virtual time instead (deterministic, faster than real time). Writes the run folder
(recording ``run.h5``, estimates, ``summary.json``, figures) and prints the summary. Ctrl-C
stops safely.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import logging
import sys
from pathlib import Path
from typing import Any

# The experiment (and through it numpy, scipy and the simulated devices) is imported where
# the command runs, so that building the parser for --help stays cheap.

_LOG = logging.getLogger(__name__)


def register(sub: Any) -> None:
    """Add the ``tank-run`` sub-command."""
    p: argparse.ArgumentParser = sub.add_parser(
        "tank-run",
        help="run a towed-target tank experiment (built-in simulated tank without a file)",
        description="Transmit continuously, tow the target on the stage, estimate live, "
        "record everything. Without EXPERIMENT the built-in simulated tank runs. Writes the "
        'run folder (--out, else run.output_dir/NAME-YYYYmmdd-HHMMSS; output_dir "runs" '
        "means $HIL_RUNS_DIR when set): run.h5 (the recording), run.log, summary.json, "
        "estimates.csv and the report figures; prints the summary. Format: hil docs tank-run.",
    )
    p.add_argument("experiment", nargs="?", type=Path, help="experiment TOML file")
    p.add_argument("--out", type=Path, help="run folder (default: output_dir/name-timestamp)")
    p.add_argument("--no-live", action="store_true", help="no live status line")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument(
        "--virtual-time",
        action="store_true",
        help="run the built-in simulated tank in this process on virtual time: deterministic "
        "(the same seed gives the same estimates and recording), as fast as the CPU allows "
        "(sim:// devices only)",
    )
    p.add_argument(
        "--print-default", action="store_true", help="print the built-in experiment file and exit"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``hil tank-run``; 0 on success, 130 if Ctrl-C or a stop signal stopped the
    run (safely: its recording, summary and report cover it up to the stop), 1 if an error
    did."""
    from hil.experiments.experiment import DEFAULT_EXPERIMENT, load_experiment, parse_experiment

    if args.print_default:
        print(DEFAULT_EXPERIMENT, end="")
        return 0
    from hil.experiments.live.plan import new_run_folder
    from hil.outputs import release_output_folder

    exp = (
        parse_experiment(DEFAULT_EXPERIMENT)
        if args.experiment is None
        else load_experiment(args.experiment)
    )
    # The folder first (refused when it holds a run), then its log around the whole run.
    folder = new_run_folder(exp.output_dir, exp.name, args.out, dt.datetime.now())
    try:
        summary, outcome = _run_and_report(exp, folder, args)
    finally:
        release_output_folder(folder)
    print_summary(summary, outcome.folder, as_json=args.json)
    if outcome.interrupted:
        # The same exit status as an interruption before the run (hil.cli.main), and the
        # output said to be partial: the run stopped early, safely.
        print(
            f"hil tank-run: {outcome.error}: the run stopped early and safely; {outcome.folder}"
            ' holds it up to the stop (summary.json: "interrupted": true)',
            file=sys.stderr,
        )
        from hil.cli.main import EXIT_INTERRUPTED

        return EXIT_INTERRUPTED
    return 1 if outcome.error else 0


def _run_and_report(exp: Any, folder: Path, args: argparse.Namespace) -> tuple[dict[str, Any], Any]:
    """The run in its claimed ``folder`` with its log, then its summary and figures."""
    from hil.experiments.live.stops import StopSignals
    from hil.experiments.run_log import log_outcome
    from hil.experiments.run_report import write_report
    from hil.experiments.run_scoring import summarize, write_summary
    from hil.experiments.tank_run import LiveView, run_experiment
    from hil.logs import run_log

    with run_log(folder):
        _LOG.info("tank run %r into %s", exp.name, folder)
        outcome = run_experiment(
            exp,
            folder=folder,
            view=LiveView(enabled=not args.no_live),
            virtual_time=args.virtual_time,
        )
        with StopSignals() as signals:
            signals.stopping()  # the run is over: SIGTERM/SIGHUP wait for its summary
            summary = summarize(outcome)
            write_summary(outcome, summary)
            figures = write_report(outcome)
            summary["figures"] = [str(p) for p in figures]
            (outcome.folder / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
            log_outcome(outcome, summary)
    return summary, outcome


def print_summary(summary: dict[str, Any], folder: Path, *, as_json: bool) -> None:
    """Print a run's summary: one JSON line, or one ``key  value`` line per entry."""
    from hil.estimation.track_summary import track_lines

    if as_json:
        print(json.dumps(summary))
        return
    width = max(len(k) for k in summary)
    for key, value in summary.items():
        if key == "figures":
            continue
        if key == "tracks":
            print("\n".join(f"{key:<{width}}  {line}" for line in track_lines(value)))
            continue
        if isinstance(value, float):
            shown = f"{value:.4g}"
        elif isinstance(value, list):
            shown = ", ".join(str(v) for v in value) or "none"
        else:
            shown = value
        print(f"{key:<{width}}  {shown}")
    print(f"run folder: {folder}")
