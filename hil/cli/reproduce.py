"""``hil reproduce``: the seed's chapter-6 evaluation, figures and report in one command.

Example::

    hil reproduce --quick --out runs/ch6-quick              # smoke run, a few minutes
    hil reproduce --out runs/ch6 --workers 2                 # the full set
    hil reproduce --out runs/ch6 --items fig6_3_gcas_vs_stft,sim05_range_rmse_vs_m
    hil reproduce --out runs/ch6 --scheduler tcp://10.0.0.5:8786

Runs every item of SPEC §5 (one sweep file each in the repository's ``evaluation/``) and writes
``DIR/<item>/`` (the sweep engine's files), ``DIR/figures/*.png``, ``DIR/tables/*.csv`` and
``DIR/report.md``. Exit status 0 when every trial succeeded, 1 when some failed (errors in
the items' results.jsonl), 2 for a bad option or sweep file, 130 when interrupted.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

from hil.cli.sweep import add_runner_options, runner_of
from hil.errors import ConfigError
from hil.evaluation.reproduce import ITEM_IDS, reproduce


def register(sub: Any) -> None:
    """Add the ``reproduce`` sub-command."""
    p: argparse.ArgumentParser = sub.add_parser(
        "reproduce",
        help="run the seed's chapter-6 evaluation and write figures, tables and report.md",
        description="Run every chapter-6 item (the shipped sweep files in hil/data/sweeps/, see "
        "hil docs results), then write PNG figures, CSV tables and DIR/report.md. Items: "
        + ", ".join(ITEM_IDS),
    )
    p.add_argument(
        "--out",
        type=Path,
        required=True,
        metavar="DIR",
        help="output folder (required: it is the work --resume continues)",
    )
    p.add_argument(
        "--quick", action="store_true", help="reduced grids and trial counts (a few minutes)"
    )
    p.add_argument(
        "--items", metavar="A,B", help="comma-separated subset of the items (default: all)"
    )
    p.add_argument(
        "--trials-per-point", type=int, metavar="N", help="override every item's trial count"
    )
    p.add_argument(
        "--sweeps",
        type=Path,
        metavar="DIR",
        help="folder of the sweep files (default: the shipped ones, hil/data/sweeps/)",
    )
    add_runner_options(p)
    p.add_argument("--resume", action="store_true", help="continue the sweeps already in DIR")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def _items(text: str | None) -> list[str] | None:
    if text is None:
        return None
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise ConfigError("--items", text, f"comma-separated items among {', '.join(ITEM_IDS)}")
    return names


def run(args: argparse.Namespace) -> int:
    """Execute ``hil reproduce``; return the exit status."""
    if args.trials_per_point is not None and args.trials_per_point < 1:
        raise ConfigError("--trials-per-point", args.trials_per_point, "an integer >= 1")
    items = _items(args.items)
    from hil.outputs import writable_folder

    writable_folder(args.out, "--out")
    runner = runner_of(args)
    command = "hil " + shlex.join(sys.argv[1:]) if sys.argv[1:] else "hil reproduce"
    with runner:
        for note in runner.notes:
            print(f"hil reproduce: note: {note}", file=sys.stderr)
        outcome = reproduce(
            args.out,
            runner,
            quick=args.quick,
            items=items,
            trials_per_point=args.trials_per_point,
            sweeps_dir=args.sweeps,
            resume=args.resume,
            show_progress=not args.quiet,
            command=command,
        )
    print(
        f"reproduce: {len(outcome.results)} item(s), {outcome.n_trials} trials "
        f"({outcome.n_failed} failed) in {outcome.elapsed_s:.1f} s; report {outcome.report}"
    )
    return 0 if outcome.n_failed == 0 else 1
