"""``hil sweep`` interrupted (Ctrl-C to its process group) or killed (``kill -9`` of the command
alone): no pool worker outlives it, the finished trials are saved and ``--resume`` completes the
sweep with the numbers of an uninterrupted run.

The trials past the first ``FREE_REPS`` of each point block until a gate file exists. Trials
are handed out in id order, so the first ``FREE_REPS`` finish and then both workers block (and
stay blocked) when the signal arrives: a runner that waited for them would never end."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from hil.cli.main import main
from hil.evaluation.engine import run_sweep
from hil.evaluation.runners import SerialRunner
from hil.evaluation.sweep_file import load_sweep_file

HELPERS = Path(__file__).with_name("evaluation_trials_for_tests.py")
REPS = 6
FREE_REPS = 2
N_TRIALS = 2 * REPS
# Bound on every wait for the processes under test, s (generous: a busy shared machine).
BOUND_S = 60.0

pytestmark = pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc for children")


def _write_sweep(path: Path, gate: Path) -> None:
    path.write_text(
        f"""
[sweep]
name = "gated"
trial = "{HELPERS}:gated_trial"
trials_per_point = {REPS}
seed = 77

[grid]
k = [0, 1]

[fixed]
gate = "{gate}"
free_reps = {FREE_REPS}
"""
    )


def _children(pid: int) -> set[int]:
    """Live (non-zombie) processes whose parent is ``pid``."""
    found = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        state, ppid = stat.rsplit(")", 1)[1].split()[:2]
        if int(ppid) == pid and state != "Z":
            found.add(int(entry.name))
    return found


def _pool_workers(children: set[int]) -> set[int]:
    """The pool's processes among ``children`` (not multiprocessing's resource tracker, which
    ends by itself once the command is gone)."""
    return {
        pid
        for pid in children
        if b"resource_tracker" not in Path(f"/proc/{pid}/cmdline").read_bytes()
    }


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _wait_for(condition: Callable[[], bool], what: str, proc: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + BOUND_S
    while not condition():
        assert time.monotonic() < deadline, f"{what} not within {BOUND_S} s"
        time.sleep(0.02)


def _lines(path: Path) -> list[str]:
    if not path.exists():
        return []
    return [line for line in path.read_text().splitlines(keepends=True) if line.endswith("\n")]


def _default_sigint() -> None:
    """In the child before exec: SIGINT raises KeyboardInterrupt again, as in a terminal (a
    suite started as a background job hands its children SIGINT ignored, and Python keeps
    an inherited ignore)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(sweep: Path, out: Path) -> subprocess.Popen[bytes]:
    command = [sys.executable, "-m", "hil.cli.main", "sweep", str(sweep), "--out", str(out)]
    return subprocess.Popen(
        [*command, "--workers", "2", "--quiet"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,  # its own process group, as a shell job has
        preexec_fn=_default_sigint,
    )


def _started_and_blocked(
    sweep: Path, out: Path
) -> tuple[subprocess.Popen[bytes], set[int], set[int]]:
    """Start the sweep; return it once the free trials are on disk, with the pids of its pool
    workers and of all its children."""
    proc = _start(sweep, out)
    try:
        _wait_for(lambda: len(_lines(out / "results.jsonl")) >= FREE_REPS, "free trials", proc)
        assert proc.poll() is None
        records = _lines(out / "results.jsonl")
        workers = {int(json.loads(r)["worker"].rsplit(":", 1)[1]) for r in records}
        children = _children(proc.pid)
        pool = _pool_workers(children)
        assert workers <= pool  # the trials ran in the pool's processes
        assert len(pool) == 2
    except BaseException:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise
    return proc, pool, children


def _ended(pool: set[int], children: set[int], proc: subprocess.Popen[bytes]) -> None:
    """The command ended its pool workers before exiting; every other child ends too."""
    assert not [pid for pid in pool if _alive(pid)]
    _wait_for(lambda: not [pid for pid in children if _alive(pid)], "every child gone", proc)


def _resume_matches_a_clean_run(tmp_path: Path, sweep: Path, out: Path, gate: Path) -> None:
    gate.touch()
    assert main(["sweep", str(sweep), "--out", str(out), "--resume", "--serial", "--quiet"]) == 0
    records = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    assert sorted(r["trial_id"] for r in records) == list(range(N_TRIALS))
    clean = run_sweep(
        load_sweep_file(sweep), tmp_path / "clean", SerialRunner(), show_progress=False
    )
    assert {r["trial_id"]: r["result"] for r in records} == {
        r["trial_id"]: r["result"] for r in clean.records
    }
    assert (out / "summary.csv").read_text() == (tmp_path / "clean" / "summary.csv").read_text()


@pytest.mark.slow
def test_ctrl_c_saves_the_finished_trials_ends_the_workers_and_resume_completes(
    tmp_path: Path,
) -> None:
    gate, sweep, out = tmp_path / "gate", tmp_path / "sweep.toml", tmp_path / "out"
    _write_sweep(sweep, gate)
    proc, pool, children = _started_and_blocked(sweep, out)
    try:
        os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in the terminal does
        _, err = proc.communicate(timeout=BOUND_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()  # reaps it and closes its stderr pipe
    assert proc.returncode == 130
    saved = len(_lines(out / "results.jsonl"))
    assert saved == FREE_REPS  # the blocked trials never finished
    assert err.decode().splitlines()[-1] == (
        f"hil sweep: interrupted (Ctrl-C): {saved} of {N_TRIALS} trials saved in "
        f"{out / 'results.jsonl'}; continue with: hil sweep {sweep} --out {out} --resume"
    )
    assert "Traceback" not in err.decode()
    _ended(pool, children, proc)
    # The summary of what is saved is written: point 0 holds the FREE_REPS finished trials.
    summary = (out / "summary.csv").read_text().splitlines()
    header = summary[0].split(",")
    assert summary[1].split(",")[header.index("n_ok")] == str(FREE_REPS)
    _resume_matches_a_clean_run(tmp_path, sweep, out, gate)


@pytest.mark.slow
def test_sigterm_saves_like_ctrl_c(tmp_path: Path) -> None:
    gate, sweep, out = tmp_path / "gate", tmp_path / "sweep.toml", tmp_path / "out"
    _write_sweep(sweep, gate)
    proc, pool, children = _started_and_blocked(sweep, out)
    try:
        proc.send_signal(signal.SIGTERM)  # the command alone, not its group
        _, err = proc.communicate(timeout=BOUND_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()  # reaps it and closes its stderr pipe
    assert proc.returncode == 130
    assert (
        err.decode()
        .splitlines()[-1]
        .startswith(f"hil sweep: interrupted (SIGTERM): {FREE_REPS} of 12")
    )
    _ended(pool, children, proc)


@pytest.mark.slow
def test_kill_9_of_the_command_leaves_no_worker(tmp_path: Path) -> None:
    gate, sweep, out = tmp_path / "gate", tmp_path / "sweep.toml", tmp_path / "out"
    _write_sweep(sweep, gate)
    proc, _pool, children = _started_and_blocked(sweep, out)
    try:
        os.kill(proc.pid, signal.SIGKILL)  # the command alone: its workers are not signalled
        proc.wait(timeout=BOUND_S)
        _wait_for(lambda: not [pid for pid in children if _alive(pid)], "workers gone", proc)
    finally:
        for pid in children:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
        if proc.stderr:
            proc.stderr.close()
    _resume_matches_a_clean_run(tmp_path, sweep, out, gate)


def test_a_torn_down_pools_cancelled_future_error_is_the_only_one_swallowed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import threading
    from concurrent.futures import InvalidStateError

    from hil.evaluation.runners import _quiet_broken_pool

    seen: list[type[BaseException]] = []
    monkeypatch.setattr(threading, "excepthook", lambda args: seen.append(args.exc_type))

    def raising(error: BaseException) -> None:
        def run() -> None:
            raise error

        thread = threading.Thread(target=run)
        thread.start()
        thread.join()

    with _quiet_broken_pool():
        raising(InvalidStateError("CANCELLED"))
        raising(ValueError("another"))
    raising(InvalidStateError("after"))
    assert seen == [ValueError, InvalidStateError]
