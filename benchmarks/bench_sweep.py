"""Sweep throughput against the number of workers, on the process pool and on local Dask.

A sweep of real trials runs through the full engine (results streamed to disk, summary
written) on the local process pool and on a local Dask cluster, each with 1 worker, 2 workers
and one worker per core (``os.cpu_count()``; the counts are deduplicated). Two trial sizes:

- ``small``: ``waveform_af_sidelobe`` with L = 17, W = 3, 5 candidate codes (about 0.03 s of
  CPU each): the hand-out cost per trial shows here, and batching is what hides it;
- ``ch6``: ``ch6_receiver``, GCAS on 0.8 s of the ``att`` preset at −10 dB (the chapter-6
  trial, about 0.35 s of CPU each).

Workers start (one pool or cluster per runner and count, serving both kinds in turn), and
every worker runs a short warm-up sweep of the same trial, before the clock starts (imports,
compiled kernels loaded): a long sweep's steady state is what is timed. Per runner and count
the bench prints trials/s, the parallel efficiency ``rate(n) / (n · rate(1))`` of that runner,
CPU s per trial, and the Dask/pool ratio of trials/s at the same count. Target: Dask at least
0.8 × the pool at every count (within 20 %).

    python benchmarks/bench_sweep.py            # the full run (a few minutes on 2 cores)
    python benchmarks/bench_sweep.py --quick    # smoke run, a minute

The machine's load average is printed beside each figure: with other work on the cores,
efficiency measures the sharing, not the engine. The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from hil.evaluation.engine import run_sweep
from hil.evaluation.runners import DaskRunner, LocalPoolRunner, Runner
from hil.evaluation.sweep_file import sweep_from_dict

#: Dask's trials/s over the pool's at the same worker count, at least.
TARGET_DASK_OVER_POOL = 0.8

#: Trial kinds: the sweep file's trial and fixed parameters, and trials per worker count.
KINDS: dict[str, dict[str, Any]] = {
    "small": {
        "trial": "waveform_af_sidelobe",
        "grid": {"n_tones": [4, 5]},
        "fixed": {"code_length": 17, "window": 3, "candidates": 5, "doppler_bins": 2},
        "trials": 400,
        "quick_trials": 20,
    },
    "ch6": {
        "trial": "ch6_receiver",
        "grid": {"snr_db": [-10.0]},
        "fixed": {"receiver": "gcas", "m_hops": 10},
        "trials": 40,
        "quick_trials": 2,
    },
}


def sweep_doc(kind: str, trials: int, name: str) -> dict[str, Any]:
    """The benchmark sweep of ``kind`` with about ``trials`` trials over its grid."""
    setup = KINDS[kind]
    n_points = 1
    for values in setup["grid"].values():
        n_points *= len(values)
    return {
        "sweep": {
            "name": name,
            "trial": setup["trial"],
            "trials_per_point": max(1, trials // n_points),
            "seed": 20240601,
        },
        "grid": setup["grid"],
        "fixed": setup["fixed"],
    }


def make(runner: str, workers: int) -> Runner:
    """A pool or local Dask runner of ``workers`` processes."""
    return LocalPoolRunner(workers) if runner == "pool" else DaskRunner(n_workers=workers)


def measure(
    r: Runner, workers: int, kind: str, trials: int, out: Path, warm_per_worker: int = 2
) -> dict[str, float]:
    """Trials/s of ``trials`` trials of ``kind`` on the started runner ``r`` of ``workers``
    (one warm-up sweep of ``warm_per_worker`` trials per worker of the same kind first, not
    timed)."""
    warm = sweep_from_dict(sweep_doc(kind, warm_per_worker * workers, "warm"))
    spec = sweep_from_dict(sweep_doc(kind, trials, "bench"))
    run_sweep(warm, out / "warm", r, show_progress=False)
    load = os.getloadavg()[0]
    cpu_before = time.process_time()
    start = time.perf_counter()
    outcome = run_sweep(spec, out / "bench", r, show_progress=False)
    seconds = time.perf_counter() - start
    if outcome.n_failed or not outcome.complete:
        raise SystemExit(f"benchmark sweep incomplete: {outcome.n_failed} failed")
    n = len(outcome.records)
    return {
        "seconds": seconds,
        "trials": n,
        "trials_per_s": n / seconds,
        "trial_cpu_s": sum(rec["cpu_s"] for rec in outcome.records) / n,
        "load_before": load,
        # This process drives the sweep (futures, records to disk): its share of a core.
        "parent_cpu_s": time.process_time() - cpu_before,
    }


def worker_counts() -> list[int]:
    """1, 2 and one per core, each once, ascending."""
    return sorted({1, 2, os.cpu_count() or 1})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--quick", action="store_true", help="a few trials, 1 and 2 workers")
    parser.add_argument(
        "--kinds", default="small,ch6", help="comma-separated trial kinds (small, ch6)"
    )
    args = parser.parse_args()
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        raise SystemExit(f"--kinds: unknown {unknown}; choose among {', '.join(KINDS)}")
    counts = [1, 2] if args.quick else worker_counts()
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        # One runner per (runner, count) serves every kind: its start-up is not timed, and
        # each kind's own warm-up sweep comes before its timed one.
        for runner in ("pool", "dask"):
            for n in counts:
                with make(runner, n) as r:
                    for kind in kinds:
                        trials = KINDS[kind]["quick_trials" if args.quick else "trials"]
                        out = Path(tmp) / f"{kind}-{runner}-{n}"
                        # --quick: one warm-up trial per worker (the smoke run's rows,
                        # not its rates, are what it checks).
                        warm = 1 if args.quick else 2
                        rows.append({"kind": kind, "runner": runner, "workers": n,
                                     **measure(r, n, kind, trials, out, warm)})  # fmt: skip
    rows.sort(key=lambda row: kinds.index(row["kind"]))  # stable: per kind, runner, count
    _derive(rows)
    _print_table(rows)
    worst = min((r["dask_over_pool"] for r in rows if r["runner"] == "dask"), default=0.0)
    print(
        f"Dask/pool trials/s, worst over kinds and counts: {worst:.2f} "
        f"(target >= {TARGET_DASK_OVER_POOL})"
    )
    print(
        json.dumps(
            {
                "benchmark": "sweep",
                "quick": args.quick,
                "cpu_count": os.cpu_count(),
                "rows": [
                    {k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()}
                    for r in rows
                ],
                "worst_dask_over_pool": round(worst, 3),
                "target_dask_over_pool": TARGET_DASK_OVER_POOL,
                "ratio_to_target": round(worst / TARGET_DASK_OVER_POOL, 3),
            }
        )
    )


def _derive(rows: list[dict[str, Any]]) -> None:
    """Efficiency against the same runner's 1-worker rate; Dask over the pool per count."""
    rate = {(r["kind"], r["runner"], r["workers"]): r["trials_per_s"] for r in rows}
    for r in rows:
        one = rate.get((r["kind"], r["runner"], 1))
        r["efficiency"] = r["trials_per_s"] / (r["workers"] * one) if one else float("nan")
        pool = rate.get((r["kind"], "pool", r["workers"]))
        r["dask_over_pool"] = r["trials_per_s"] / pool if pool else float("nan")


def _print_table(rows: list[dict[str, Any]]) -> None:
    head = ("kind", "runner", "workers", "trials", "seconds", "trials/s", "efficiency",
            "cpu s/trial", "dask/pool", "load before")  # fmt: skip
    print("  ".join(f"{h:>11}" for h in head))
    for r in rows:
        cells = (
            r["kind"], r["runner"], r["workers"], r["trials"], f"{r['seconds']:.2f}",
            f"{r['trials_per_s']:.2f}", f"{r['efficiency']:.2f}", f"{r['trial_cpu_s']:.4f}",
            f"{r['dask_over_pool']:.2f}" if r["runner"] == "dask" else "-",
            f"{r['load_before']:.2f}",
        )  # fmt: skip
        print("  ".join(f"{c!s:>11}" for c in cells))


if __name__ == "__main__":
    main()
