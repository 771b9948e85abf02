"""The default tank run on virtual time against its signal duration, and where its CPU goes.

Target (issue 30): the built-in experiment run in process on virtual time
(``hil tank-run --virtual-time``) at 10x real time or faster: ``wall_over_signal`` <= 0.1.
The run's wall time is :attr:`~hil.experiments.tank_run.RunOutcome.wall_s` (from the devices'
opening to the recording closed; the receiver's kernels are loaded before it). Also printed:
the run's process CPU time over the signal (what a loaded machine cannot inflate), the load
average beside it, and the run's range figures (the same seed gives the same ones on any
machine). The best of ``--repeat`` runs is kept.

Then one more run with its CPU charged to its parts (``benchmarks/run_parts.py``: the world's
target echoes, own echoes, reverberation and noise, the simulated stage and board, the board
driver's service, the virtual clock, the first-arrival readout, the rest of the receiver, the
recording, and the rest: setup, preflight, report), each in CPU seconds and per second of
signal. That run is not timed (its wrappers cost a little).

The same run bit for bit: ``--check DIR`` also runs the built-in run (and, with
``--board``, its ``tank-board`` form: the same file with ``preset = "tank-board"``) once more,
writes its summary and estimates, and compares the folder with the one saved under ``DIR``
by an earlier call (``benchmarks/run_identity.py``: every ``run.h5`` dataset but the
wall-clock ones, ``background.npy``, ``summary.json`` but its wall-clock keys,
``estimates.csv``); the first call saves it. So: ``--check DIR`` on the code before, then on
the code after; a difference ends the script with status 1.

Run: ``python benchmarks/bench_virtual_run.py [--repeat 3] [--quick] [--check DIR [--board]]``.
The last line is one JSON object with the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from run_identity import check_or_save, write_outputs  # benchmarks/, beside this script
from run_parts import measure_parts

from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from hil.experiments.run_scoring import summarize
from hil.experiments.tank_run import LiveView, RunOutcome, run_experiment

#: wall / signal to reach: 10x real time.
TARGET_RATIO = 0.1
# --quick: a 0.5 m pass instead of 3 m (the smoke test of the script, not the figure).
QUICK = DEFAULT_EXPERIMENT.replace("end_m = -5.0", "end_m = -2.5")
# The tank-board form of a run: the same file at the board's rate (1 MS/s).
BOARD = ('preset = "tank-audio"', 'preset = "tank-board"')


def _run(text: str, folder: Path) -> RunOutcome:
    outcome = run_experiment(
        parse_experiment(text), folder=folder, view=LiveView(enabled=False), virtual_time=True
    )
    if outcome.error:
        raise SystemExit(f"the run failed: {outcome.error}")
    return outcome


def one_run(text: str, folder: Path) -> dict[str, float]:
    """Run ``text`` on virtual time into ``folder``; its figures."""
    cpu0 = time.process_time()
    outcome = _run(text, folder)
    cpu = time.process_time() - cpu0
    summary = summarize(outcome)
    return {
        "wall_s": outcome.wall_s,
        "signal_s": outcome.signal_s,
        "cpu_s": cpu,
        "load_1min": os.getloadavg()[0],
        "range_bias_m": summary["range_bias_m"],
        "range_rmse_m": summary["range_rmse_m"],
        "estimates": float(summary["estimates"]),
    }


def parts_run(text: str, folder: Path) -> tuple[dict[str, float], float]:
    """CPU seconds per part of one run of ``text``, and its signal duration (s)."""
    with measure_parts() as parts:
        outcome = _run(text, folder)
    return parts, outcome.signal_s


def check_runs(text: str, folder: Path, reference: Path, board: bool) -> dict[str, str]:
    """Run ``text`` (and its tank-board form with ``board``) into ``folder`` and compare
    each with the run saved under ``reference`` (:func:`run_identity.check_or_save`): per
    form, "saved", "identical" or what differs."""
    forms = {"built-in": text}
    if board:
        forms["tank-board"] = text.replace(*BOARD)
    verdicts = {}
    for name, form in forms.items():
        outcome = _run(form, folder / name)
        write_outputs(outcome)
        found = check_or_save(outcome.folder, reference / name)
        verdicts[name] = "saved" if found is None else "; ".join(found) or "identical"
    return verdicts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs (the fastest is kept)")
    parser.add_argument("--quick", action="store_true", help="one short run")
    parser.add_argument(
        "--check", type=Path, metavar="DIR", help="compare the run with DIR's (saved there first)"
    )
    parser.add_argument("--board", action="store_true", help="--check the tank-board form too")
    args = parser.parse_args()
    text, repeat = (QUICK, 1) if args.quick else (DEFAULT_EXPERIMENT, args.repeat)
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(repeat):
            runs.append(one_run(text, Path(tmp) / f"run{k}"))
        parts, signal_s = parts_run(text, Path(tmp) / "parts")
        verdicts = {} if args.check is None else check_runs(text, Path(tmp), args.check, args.board)
    best = min(runs, key=lambda r: r["wall_s"])
    ratio = best["wall_s"] / best["signal_s"]
    cpu_ratio = best["cpu_s"] / best["signal_s"]
    print(
        f"virtual-time tank run: {best['wall_s']:.2f} s wall for {best['signal_s']:.2f} s of"
        f" signal: ratio {ratio:.2f} ({1 / ratio:.1f}x real time; target <= {TARGET_RATIO},"
        f" {1 / TARGET_RATIO:.0f}x), load {best['load_1min']:.1f}; process CPU"
        f" {best['cpu_s']:.2f} s ({cpu_ratio:.2f} of the signal, {1 / cpu_ratio:.1f}x);"
        f" {best['estimates']:.0f} estimates, range bias {best['range_bias_m']:+.4f} m,"
        f" RMSE {best['range_rmse_m']:.4f} m"
    )
    print(f"CPU per part (one more run, {signal_s:.2f} s of signal):")
    for name, seconds in parts.items():
        print(f"  {name:38s} {seconds:7.3f} s  {seconds / signal_s:6.3f} s per signal s")
    for name, verdict in verdicts.items():
        print(f"the {name} run against {args.check / name}: {verdict}")
    print(
        json.dumps(
            {
                **best,
                "wall_over_signal": ratio,
                "cpu_over_signal": cpu_ratio,
                "target_ratio": TARGET_RATIO,
                "runs": len(runs),
                "parts_cpu_s": parts,
                "same_run": verdicts,
            }
        )
    )
    if any(v not in ("saved", "identical") for v in verdicts.values()):
        raise SystemExit(1)


if __name__ == "__main__":
    main()
