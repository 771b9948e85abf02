"""Sweep throughput on a local Dask cluster: 1 worker against 2 workers.

A 200-trial sweep of the real ``waveform_af_sidelobe`` trial (best of 700 random cyclic codes
with L = 31, W = 4, then its periodic AF over 17 Doppler bins: about 0.25 s of CPU per trial, a
mix of the Python code search and numpy FFTs) runs through the full
engine (results streamed to disk, summary written) on a ``LocalCluster`` of 1 and then 2
single-threaded worker processes. Cluster start-up is not timed; each worker imports the trial
before the clock starts. Target: 2 workers give at least 1.7 x the trials/s of 1 worker.

    python benchmarks/bench_sweep.py            # the full run (~1.5 min on 2 cores)
    python benchmarks/bench_sweep.py --quick    # smoke run, a few seconds

The last line printed is one JSON object with the figures and the ratio to the target.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from hil.evaluation.engine import run_sweep
from hil.evaluation.runners import DaskRunner
from hil.evaluation.sweep_file import sweep_from_dict

TARGET_SPEEDUP = 1.7

FULL: dict[str, Any] = {
    "trials": 200,
    "fixed": {"code_length": 31, "window": 4, "candidates": 700, "doppler_bins": 8},
}
QUICK: dict[str, Any] = {"trials": 8, "fixed": {"code_length": 17, "window": 3, "doppler_bins": 2}}


def sweep_doc(trials: int, fixed: dict[str, Any]) -> dict[str, Any]:
    """A sweep of ``trials`` trials over two tone counts (one grid point per count)."""
    return {
        "sweep": {
            "name": "bench",
            "trial": "waveform_af_sidelobe",
            "trials_per_point": trials // 2,
            "seed": 20240601,
        },
        "grid": {"n_tones": [4, 5]},
        "fixed": fixed,
    }


def measure(n_workers: int, doc: dict[str, Any], out: Path) -> dict[str, float]:
    """Run the sweep on a fresh local cluster of ``n_workers``; return time and rate."""
    spec = sweep_from_dict(doc)
    load = os.getloadavg()[0]
    with DaskRunner(n_workers=n_workers) as runner:
        runner.client.run(importlib.import_module, "hil.evaluation.trials_waveform")
        start = time.perf_counter()
        outcome = run_sweep(spec, out, runner, show_progress=False)
        seconds = time.perf_counter() - start
    if outcome.n_failed or not outcome.complete:
        raise SystemExit(f"benchmark sweep incomplete: {outcome.n_failed} failed")
    n = len(outcome.records)
    return {
        "seconds": seconds,
        "trials_per_s": outcome.ran / seconds,
        "trial_s": sum(r["elapsed_s"] for r in outcome.records) / n,
        "trial_cpu_s": sum(r["cpu_s"] for r in outcome.records) / n,
        "load_before": load,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--quick", action="store_true", help="tiny smoke run (a few seconds)")
    args = parser.parse_args()
    setup = QUICK if args.quick else FULL
    doc = sweep_doc(setup["trials"], setup["fixed"])
    with tempfile.TemporaryDirectory() as tmp:
        one = measure(1, doc, Path(tmp) / "one")
        two = measure(2, doc, Path(tmp) / "two")
    speedup = two["trials_per_s"] / one["trials_per_s"]
    # Wall time per trial well above its CPU time, or a high load average before the run,
    # means other processes shared the cores: the speedup is then not the engine's.
    print(
        f"{'workers':>7}  {'trials':>6}  {'seconds':>8}  {'trials/s':>8}  {'wall s/trial':>12}  "
        f"{'cpu s/trial':>11}  {'load before':>11}"
    )
    for n, m in ((1, one), (2, two)):
        print(
            f"{n:>7}  {setup['trials']:>6}  {m['seconds']:>8.2f}  {m['trials_per_s']:>8.2f}  "
            f"{m['trial_s']:>12.3f}  {m['trial_cpu_s']:>11.3f}  {m['load_before']:>11.2f}"
        )
    print(f"speedup 2 vs 1 workers: {speedup:.2f} x (target >= {TARGET_SPEEDUP} x)")
    print(
        json.dumps(
            {
                "benchmark": "sweep",
                "quick": args.quick,
                "trials": setup["trials"],
                "trial_s": round(one["trial_s"], 4),
                "trial_cpu_s": round(one["trial_cpu_s"], 4),
                "load_before": [round(one["load_before"], 2), round(two["load_before"], 2)],
                "trials_per_s_1_worker": round(one["trials_per_s"], 3),
                "trials_per_s_2_workers": round(two["trials_per_s"], 3),
                "speedup": round(speedup, 3),
                "target_speedup": TARGET_SPEEDUP,
                "ratio_to_target": round(speedup / TARGET_SPEEDUP, 3),
            }
        )
    )


if __name__ == "__main__":
    main()
