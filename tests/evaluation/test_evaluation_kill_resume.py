"""A sweep killed with SIGKILL part-way resumes without redoing a finished trial, and ends with
the numbers of an uninterrupted run."""

from __future__ import annotations

import collections
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from hil.cli.main import main
from hil.evaluation.engine import run_sweep
from hil.evaluation.runners import SerialRunner
from hil.evaluation.sweep_file import load_sweep_file

HELPERS = Path(__file__).with_name("evaluation_trials_for_tests.py")
N_TRIALS = 24


def _write_sweep(path: Path, marker: Path) -> None:
    path.write_text(
        f"""
[sweep]
name = "killme"
trial = "{HELPERS}:marker_trial"
trials_per_point = 12
seed = 424242

[grid]
k = [0, 1]

[fixed]
marker = "{marker}"
sleep_s = 0.05
"""
    )


def _record_lines(path: Path) -> list[str]:
    if not path.exists():
        return []
    return [line for line in path.read_text().splitlines(keepends=True) if line.endswith("\n")]


def test_sigkill_then_resume_redoes_nothing(tmp_path: Path) -> None:
    marker = tmp_path / "markers.txt"
    sweep = tmp_path / "sweep.toml"
    _write_sweep(sweep, marker)
    out = tmp_path / "out"
    command = [sys.executable, "-m", "hil.cli.main", "sweep", str(sweep), "--out", str(out)]
    proc = subprocess.Popen(
        [*command, "--workers", "2", "--quiet"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,  # its own process group: the kill takes the workers too
    )
    try:
        deadline = time.monotonic() + 60
        while len(_record_lines(out / "results.jsonl")) < 6:
            assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
            assert time.monotonic() < deadline, "no trials on disk after 60 s"
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        if proc.stderr:
            proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL

    before = {json.loads(line)["trial_id"] for line in _record_lines(out / "results.jsonl")}
    assert 6 <= len(before) < N_TRIALS

    assert main(["sweep", str(sweep), "--out", str(out), "--resume", "--serial", "--quiet"]) == 0

    records = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    ids = [r["trial_id"] for r in records]
    assert sorted(ids) == list(range(N_TRIALS))  # every trial once, none recorded twice
    runs = collections.Counter(marker.read_text().split())
    for rec in records:
        if rec["trial_id"] in before:
            # Finished before the kill: ran exactly once (never again on resume).
            assert runs[",".join(map(str, rec["seed"]["spawn_key"]))] == 1, rec["trial_id"]
    # Only trials in flight at the kill (at most 4 per worker are handed out) ran twice.
    assert sum(runs.values()) - N_TRIALS <= 4 * 2

    # Same numbers as one uninterrupted run.
    spec = load_sweep_file(sweep)
    clean = run_sweep(spec, tmp_path / "clean", SerialRunner(), show_progress=False)
    by_id = {r["trial_id"]: r["result"] for r in records}
    assert by_id == {r["trial_id"]: r["result"] for r in clean.records}
    assert (out / "summary.csv").read_text() == (tmp_path / "clean" / "summary.csv").read_text()
