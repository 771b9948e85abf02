"""What a worker process does with one trial: load it, run it, turn the outcome into a record.

Everything here is importable by a fresh process (process pool or Dask worker) from the
installed package alone. :func:`execute_trial` never raises for a failing trial: the error,
with its type, message and traceback text, becomes the record, so the sweep goes on.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import os
import signal
import socket
import threading
import time
import traceback
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hil.environment import environment
from hil.evaluation.registry import load_trial
from hil.evaluation.seeds import seed_record, trial_seed

#: Thread-count variables of OpenMP, OpenBLAS and MKL: pinned to 1 in every worker so that N
#: workers use N cores and not N x cores (BLAS reads them when numpy is first imported).
BLAS_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@dataclass(frozen=True)
class TrialTask:
    """One trial to run: its id, place in the grid, full parameters and the root entropy.

    ``trial_id = point * trials_per_point + rep``; the seed is derived from ``(entropy, point,
    rep)`` by :func:`~hil.evaluation.seeds.trial_seed` on the worker.
    """

    trial_id: int
    point: int
    rep: int
    params: dict[str, Any]
    entropy: int


def execute_trial(target: str, task: TrialTask) -> dict[str, Any]:
    """Run the trial ``target`` for ``task`` and return its record (never raises on a failing
    trial).

    Record keys: ``trial_id``, ``point``, ``rep``, ``params``, ``seed`` (``entropy``,
    ``spawn_key``), ``status`` (``"ok"`` or ``"error"``), then ``result`` (the trial's dict) or
    ``error`` (``type``, ``message``, ``traceback``), ``elapsed_s`` (wall time of the trial, s),
    ``cpu_s`` (CPU time of the worker process during the trial, s) and ``worker``
    (``host:pid``).

    >>> rec = execute_trial("hil.evaluation.worker:_example_trial", TrialTask(3, 1, 1, {"x": 2}, 5))
    >>> rec["status"], rec["result"], rec["seed"]
    ('ok', {'y': 4}, {'entropy': 5, 'spawn_key': [1, 1]})
    """
    seed = trial_seed(task.entropy, task.point, task.rep)
    record: dict[str, Any] = {
        "trial_id": task.trial_id,
        "point": task.point,
        "rep": task.rep,
        "params": task.params,
        "seed": seed_record(seed),
    }
    start = time.perf_counter()
    cpu_start = time.process_time()
    try:
        trial = load_trial(target)
        # The trial gets its own copy: a trial that edits its params cannot touch the record.
        result = normalise_result(trial(dict(task.params), seed))
    except Exception as exc:
        record["status"] = "error"
        record["error"] = {
            "type": type(exc).__name__,
            "message": str(exc),
            "traceback": traceback.format_exc(),
        }
    else:
        record["status"] = "ok"
        record["result"] = result
    record["elapsed_s"] = time.perf_counter() - start
    record["cpu_s"] = time.process_time() - cpu_start
    record["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return record


def execute_trials(target: str, tasks: list[TrialTask]) -> list[dict[str, Any]]:
    """:func:`execute_trial` for each of ``tasks`` in turn: one hand-out to a worker for a
    batch of short trials (the runners size the batches).

    >>> recs = execute_trials("hil.evaluation.worker:_example_trial",
    ...                       [TrialTask(0, 0, 0, {"x": 2}, 5), TrialTask(1, 0, 1, {"x": 3}, 5)])
    >>> [r["result"]["y"] for r in recs]
    [4, 9]
    """
    return [execute_trial(target, task) for task in tasks]


def warm_trial(target: str) -> None:
    """Import the trial ``target`` in this worker ahead of its first task, so the workers
    load it side by side, not one task at a time; a trial that cannot load is left to
    :func:`execute_trial`, which records why."""
    try:
        load_trial(target)
    except Exception:  # every trial's own record says why
        return


def warm_pool_worker(target: str) -> None:
    """:func:`warm_trial`, then wait until every pool worker has done it (one call per
    worker then reaches each of them, as :func:`probe_pool_worker` does)."""
    warm_trial(target)
    if _start_barrier is not None:
        _start_barrier.wait(timeout=300)


def _example_trial(params: dict[str, Any], seed: np.random.SeedSequence) -> dict[str, Any]:
    """A trivial trial for the doctest above."""
    return {"y": params["x"] ** 2}


def normalise_result(result: Any) -> dict[str, Any]:
    """The trial's return value as JSON-ready data; ``TypeError`` naming the key otherwise.

    numpy scalars become Python numbers, arrays and tuples become lists.

    >>> normalise_result({"rmse": np.float64(0.5), "n": np.int64(3), "v": np.arange(2)})
    {'rmse': 0.5, 'n': 3, 'v': [0, 1]}
    """
    if not isinstance(result, Mapping):
        raise TypeError(f"a trial must return a dict of results, got {type(result).__name__}")
    out: dict[str, Any] = {}
    for key, value in result.items():
        if not isinstance(key, str):
            raise TypeError(f"result keys must be str, got {key!r}")
        out[key] = _json_value(value, key)
    return out


def _json_value(value: Any, key: str) -> Any:
    # numpy scalars first: np.float64 is also a float, but must not reach JSON as numpy.
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, (np.ndarray, list, tuple)):
        items = value.tolist() if isinstance(value, np.ndarray) else value
        return [_json_value(v, key) for v in items]
    raise TypeError(
        f"result {key!r} is a {type(value).__name__}: values must be float, int, bool, str, "
        "None or lists of them"
    )


def pin_blas_threads() -> None:
    """Set the BLAS thread variables to 1 in this process (worker initializer).

    Effective for libraries loaded afterwards; for numpy itself the variables must already be
    in the environment the process starts with, which :func:`pinned_blas_env` arranges.
    """
    for name in BLAS_THREAD_VARS:
        os.environ[name] = "1"


def worker_blas_env() -> dict[str, str | None]:
    """The BLAS thread variables this process *started* with (what numpy's BLAS read).

    Read from ``/proc/self/environ`` where it exists (Linux: the environment at exec, which
    later ``os.environ`` changes do not touch), else from ``os.environ``.
    """
    try:
        raw = Path("/proc/self/environ").read_bytes()
    except OSError:
        return {name: os.environ.get(name) for name in BLAS_THREAD_VARS}
    start = dict(
        item.decode(errors="replace").split("=", 1) for item in raw.split(b"\0") if b"=" in item
    )
    return {name: start.get(name) for name in BLAS_THREAD_VARS}


# Set in each pool worker by its initializer: all workers meet here once at pool start.
_start_barrier: Any = None


#: Exit status of a pool worker that ends because the process that started it is gone.
EXIT_PARENT_GONE = 70


def init_pool_worker(barrier: Any) -> None:
    """Process-pool initializer: pin BLAS threads, keep the start-up barrier, leave Ctrl-C to
    the parent and end with the parent (:func:`exit_with_parent`)."""
    global _start_barrier
    pin_blas_threads()
    _start_barrier = barrier
    # Ctrl-C in a terminal reaches the whole process group; the parent alone decides what
    # stops (it saves the finished trials, then ends the workers), so a worker never dies
    # half-way through handing back a record.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    exit_with_parent()


def exit_with_parent() -> None:
    """End this process (status :data:`EXIT_PARENT_GONE`) as soon as the process that
    spawned it ends, however it ends (``kill -9`` included).

    A daemon thread waits on multiprocessing's parent sentinel, a pipe whose other end only
    the parent holds: the kernel closes it when the parent dies, which wakes the thread. A
    process not started by multiprocessing has no parent sentinel and is left alone.
    """
    parent = multiprocessing.parent_process()
    if parent is None or parent.sentinel is None:
        return
    sentinel = parent.sentinel

    def watch() -> None:
        multiprocessing.connection.wait([sentinel])
        os._exit(EXIT_PARENT_GONE)  # no clean-up: whatever the trial held dies with it

    threading.Thread(target=watch, name="hil-parent-watch", daemon=True).start()


def probe_pool_worker() -> dict[str, str | None]:
    """Wait until every pool worker runs one of these, then report :func:`worker_blas_env`.

    No worker returns before all have started, so submitting one probe per worker makes the
    pool start every process at once (while the parent holds :func:`pinned_blas_env`).
    """
    if _start_barrier is not None:
        _start_barrier.wait(timeout=300)
    return worker_blas_env()


@contextmanager
def pinned_blas_env() -> Iterator[None]:
    """Within the block, this process's environment has the BLAS variables at 1, so the
    processes it spawns start pinned; the previous values come back afterwards."""
    with environment(**dict.fromkeys(BLAS_THREAD_VARS, "1")):
        yield
