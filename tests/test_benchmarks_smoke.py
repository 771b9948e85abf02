"""Every benchmark script runs (``--quick``) and ends with one JSON object, as the project's
benchmark convention requires. The figures themselves are checked by running the scripts in
full, never by timed unit tests."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "benchmarks").glob("bench_*.py"))


def test_there_are_benchmarks() -> None:
    assert SCRIPTS, "benchmarks/ holds no bench_*.py"


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_benchmark_quick_run_ends_with_json(script: Path) -> None:
    proc = subprocess.run(
        [sys.executable, str(script), "--quick"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    last = proc.stdout.strip().splitlines()[-1]
    figures = json.loads(last)
    assert isinstance(figures, dict) and figures, last
    if script.name == "bench_sweep.py":
        _check_sweep_scaling(figures)


def _check_sweep_scaling(figures: dict[str, object]) -> None:
    """bench_sweep's quick form: both runners at 1 and 2 workers for both trial sizes, each
    row's efficiency and Dask/pool ratio derived from its own rates."""
    rows = figures["rows"]
    assert isinstance(rows, list)
    assert {(r["kind"], r["runner"], r["workers"]) for r in rows} == {
        (k, runner, n) for k in ("small", "ch6") for runner in ("pool", "dask") for n in (1, 2)
    }
    rate = {(r["kind"], r["runner"], r["workers"]): r["trials_per_s"] for r in rows}
    for r in rows:
        one = rate[(r["kind"], r["runner"], 1)]
        assert r["efficiency"] == pytest.approx(r["trials_per_s"] / (r["workers"] * one), rel=1e-2)
        pool = rate[(r["kind"], "pool", r["workers"])]
        assert r["dask_over_pool"] == pytest.approx(r["trials_per_s"] / pool, rel=1e-2)
    worst = min(r["dask_over_pool"] for r in rows if r["runner"] == "dask")
    assert figures["worst_dask_over_pool"] == pytest.approx(worst, abs=1e-3)
