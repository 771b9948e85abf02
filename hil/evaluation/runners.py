"""Where trials run: in this process, on a local process pool, or on a Dask cluster.

All runners share one interface (:class:`Runner`): used as a context manager (workers start
on entry and stop on exit, so one runner can serve several sweeps), ``run(target, tasks)``
yields each trial's record as soon as its batch finishes, in completion order.

The pool and Dask runners hand trials out in *batches* (:class:`BatchSizer`): one trial per
task until a trial's time is known, then as many as fill :data:`BATCH_TARGET_S` of work, so a
hand-out (a pickle each way; on Dask also a scheduler round trip) is a small share of what it
carries, whatever the trial costs. At most
:data:`IN_FLIGHT_PER_WORKER` tasks per worker are out at a time, so a sweep of a million
trials holds a few futures, not a million. Before a trial's first task every worker imports it
(:func:`~hil.evaluation.worker.warm_trial`), side by side. Every worker has its BLAS thread
pools pinned to one thread (:data:`~hil.evaluation.worker.BLAS_THREAD_VARS`).

Dask is imported only by :class:`DaskRunner`; everything else needs no extra package.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import multiprocessing
import os
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, InvalidStateError, ProcessPoolExecutor, wait
from types import TracebackType
from typing import Any

from hil.errors import ConfigError
from hil.evaluation.worker import (
    BLAS_THREAD_VARS,
    TrialTask,
    execute_trial,
    execute_trials,
    init_pool_worker,
    pin_blas_threads,
    pinned_blas_env,
    probe_pool_worker,
    warm_pool_worker,
    warm_trial,
    worker_blas_env,
)

Record = dict[str, Any]

#: Tasks in flight per worker: enough to keep every worker busy between hand-outs.
IN_FLIGHT_PER_WORKER = 4

#: Work one task aims to carry, s of a worker's wall time: each hand-out wakes the client, the
#: scheduler and the worker (on a loaded machine, each wake-up waits for a core), so at 0.25 s
#: Dask ran small trials at 0.5-0.8x the pool's rate and at 1 s at 0.8-1.0x; the last tasks
#: of a sweep leave workers idle for at most about this.
BATCH_TARGET_S = 1.0

#: Most trials in one task.
MAX_BATCH = 256

#: Bound on the wait for one killed pool worker to be reaped, s.
_ABORT_JOIN_S = 10.0
#: Local worker processes per core at most: each is a whole Python with numpy (and numba's
#: kernels) loaded, started before the first trial; more than the cores only share them.
WORKERS_PER_CORE_MAX = 4


def check_local_workers(option: str, n: Any) -> int:
    """``n`` local worker processes, or a ConfigError naming ``option``: an integer from 1 to
    :data:`WORKERS_PER_CORE_MAX` per core of this machine."""
    cores = os.cpu_count() or 1
    most = WORKERS_PER_CORE_MAX * cores
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= most:
        raise ConfigError(
            option, n, f"an integer in 1..{most} ({WORKERS_PER_CORE_MAX} per core, {cores} cores)",
            "one per core is the default; for more, run on a Dask cluster (--scheduler)",
        )  # fmt: skip
    return n


class Runner:
    """Base class: a context manager that runs trials and yields their records."""

    name = "runner"

    def __init__(self) -> None:
        #: Messages for the user about the set-up (e.g. workers whose BLAS is not pinned).
        self.notes: list[str] = []

    @property
    def workers(self) -> int:
        """Number of trials that can run at once."""
        return 1

    def __enter__(self) -> Runner:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is not None and issubclass(exc_type, KeyboardInterrupt):
            self.abort()
        else:
            self.close()

    def close(self) -> None:
        """Stop the workers (idempotent)."""

    def abort(self) -> None:
        """Stop the workers now, dropping the trials they run (on Ctrl-C: a finished trial is
        already on disk, an unfinished one runs again on resume). Idempotent."""
        self.close()

    def describe(self) -> dict[str, Any]:
        """What ran the trials, for the manifest."""
        return {"runner": self.name, "workers": self.workers}

    def run(self, target: str, tasks: Iterable[TrialTask]) -> Iterator[Record]:
        """Run the trial ``target`` for every task; yield records as trials finish."""
        raise NotImplementedError


class BatchSizer:
    """How many trials the next task carries: 1 until trials have finished, then
    ``BATCH_TARGET_S`` over the mean wall time per trial seen so far (rounded), within
    1..``MAX_BATCH``.

    >>> sizer = BatchSizer()
    >>> sizer.size
    1
    >>> sizer.observe([{"elapsed_s": 0.01}, {"elapsed_s": 0.04}])
    >>> sizer.size
    40
    >>> sizer.observe([{"elapsed_s": 2.0}])
    >>> sizer.size
    1
    """

    def __init__(self, target_s: float = BATCH_TARGET_S, most: int = MAX_BATCH) -> None:
        self.target_s = target_s
        self.most = most
        self._seconds = 0.0
        self._trials = 0

    def observe(self, records: list[Record]) -> None:
        """Count the wall time of finished trials."""
        self._seconds += sum(float(r.get("elapsed_s") or 0.0) for r in records)
        self._trials += len(records)

    @property
    def size(self) -> int:
        """Trials for the next task."""
        if self._trials == 0:
            return 1
        mean = self._seconds / self._trials
        if mean <= 0.0:
            return self.most
        return max(1, min(self.most, round(self.target_s / mean)))


def _take(todo: Iterator[TrialTask], n: int) -> list[TrialTask]:
    return list(itertools.islice(todo, n))


class SerialRunner(Runner):
    """Runs every trial in this process, in order: for debugging (breakpoints work)."""

    name = "serial"

    def run(self, target: str, tasks: Iterable[TrialTask]) -> Iterator[Record]:
        for task in tasks:
            yield execute_trial(target, task)


class LocalPoolRunner(Runner):
    """A pool of ``workers`` processes on this machine (default ``os.cpu_count()``).

    Workers are *spawned* (not forked) with the BLAS variables set to 1 in the environment they
    start with, so numpy in the workers is single-threaded whatever the parent imported; they
    all start on entry and are reused for every sweep run through this runner.
    """

    name = "process-pool"

    def __init__(self, workers: int | None = None) -> None:
        super().__init__()
        n = (os.cpu_count() or 1) if workers is None else workers
        self._workers = check_local_workers("--workers", n)
        self._pool: ProcessPoolExecutor | None = None
        self._barrier: Any = None
        self._warm: set[str] = set()

    @property
    def workers(self) -> int:
        return self._workers

    def __enter__(self) -> LocalPoolRunner:
        self._start()
        return self

    def _start(self) -> None:
        if self._pool is not None:
            return
        context = multiprocessing.get_context("spawn")
        barrier = context.Barrier(self._workers)
        self._barrier = barrier
        with pinned_blas_env():
            pool = ProcessPoolExecutor(
                self._workers,
                mp_context=context,
                initializer=init_pool_worker,
                initargs=(barrier,),
            )
            # The pool spawns processes on demand while none is idle; the probes wait for one
            # another, so every process starts now, inside the pinned environment.
            probes = [pool.submit(probe_pool_worker) for _ in range(self._workers)]
            reports = [f.result() for f in probes]
        self._pool = pool
        self._warm = set()
        self.notes.extend(_unpinned_notes(reports))

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def abort(self) -> None:
        pool, self._pool = self._pool, None
        if pool is None:
            return
        # Python 3.14 has ProcessPoolExecutor.terminate_workers(); before it, the processes
        # are only reachable through the executor's process table.
        procs = list((getattr(pool, "_processes", None) or {}).values())
        with _quiet_broken_pool():
            for proc in procs:
                proc.kill()
            pool.shutdown(wait=True, cancel_futures=True)
        for proc in procs:
            proc.join(_ABORT_JOIN_S)

    def _warm_up(self, target: str) -> None:
        """Every worker imports ``target`` once (one call each, met at the barrier)."""
        pool = self._pool
        if pool is None or target in self._warm:
            return
        calls = [pool.submit(warm_pool_worker, target) for _ in range(self._workers)]
        for call in calls:
            call.exception()  # a worker that cannot load it records why with every trial
        self._warm.add(target)

    def run(self, target: str, tasks: Iterable[TrialTask]) -> Iterator[Record]:
        self._start()
        pool = self._pool
        assert pool is not None
        self._warm_up(target)
        pending: set[Future[list[Record]]] = set()
        todo = iter(tasks)
        sizer = BatchSizer()
        window = IN_FLIGHT_PER_WORKER * self._workers

        def submit(batch: list[TrialTask]) -> Future[list[Record]]:
            return pool.submit(execute_trials, target, batch)

        try:
            _refill(pending, todo, window, sizer, submit)
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    pending.discard(future)
                    records = future.result()
                    sizer.observe(records)
                    yield from records
                _refill(pending, todo, window, sizer, submit)
        finally:
            for future in pending:
                future.cancel()


@contextlib.contextmanager
def _quiet_broken_pool() -> Iterator[None]:
    """Workers killed on purpose: the executor's manager thread marks every pending future
    broken, and before Python 3.12 it raises ``InvalidStateError`` on one already cancelled
    (a trial the interrupted sweep gave up), printing that thread's traceback on stderr. That
    one error is swallowed while the pool is torn down; any other reaches the usual hook."""
    previous = threading.excepthook

    def hook(args: threading.ExceptHookArgs) -> None:
        if args.exc_type is InvalidStateError:
            return
        previous(args)

    threading.excepthook = hook
    try:
        yield
    finally:
        threading.excepthook = previous


def _refill(
    pending: set[Any],
    todo: Iterator[TrialTask],
    window: int,
    sizer: BatchSizer,
    submit: Callable[[list[TrialTask]], Any],
) -> None:
    while len(pending) < window:
        batch = _take(todo, sizer.size)
        if not batch:
            return
        pending.add(submit(batch))


def _unpinned_notes(reports: list[dict[str, str | None]]) -> list[str]:
    bad = {f"{k}={v}" for r in reports for k, v in r.items() if v != "1"}
    if not bad:
        return []
    return [
        f"{len(reports)} worker(s) report BLAS threads not pinned to 1 ({', '.join(sorted(bad))}); "
        f"start the workers with {', '.join(v + '=1' for v in BLAS_THREAD_VARS)}"
    ]


def _import_distributed() -> Any:
    try:
        import distributed
    except ModuleNotFoundError as exc:
        if exc.name not in ("distributed", "dask"):
            raise  # installed, but broken: show the real cause
        raise ConfigError(
            "runner",
            "dask",
            "available only with the dask extra installed",
            "pip install 'cas-hil[dask]'",
        ) from None
    return distributed


class DaskRunner(Runner):
    """Trials on a Dask cluster: an existing scheduler, or a local cluster of processes.

    Give exactly one of ``scheduler`` (``"tcp://HOST:PORT"``: connect to a running
    ``dask scheduler`` whose workers have this package installed), ``n_workers`` (start a
    ``LocalCluster`` of that many single-threaded worker processes) or ``client`` (an existing
    ``distributed.Client``, left open on close). Local workers are spawned with the BLAS
    variables at 1 (Dask's ``pre-spawn-environ``, with this process's own variables pinned while
    they start, since Dask lets those win) and Dask's settings of :data:`LOCAL_WORKER_CONFIG`;
    on a remote cluster the variables are set on connection and workers that started unpinned
    are reported in :attr:`notes`.
    """

    name = "dask"

    def __init__(
        self,
        scheduler: str | None = None,
        n_workers: int | None = None,
        *,
        client: Any = None,
        connect_timeout_s: float = 10.0,
    ) -> None:
        super().__init__()
        given = [x is not None for x in (scheduler, n_workers, client)]
        if sum(given) != 1:
            raise ConfigError(
                "--scheduler/--dask-workers",
                (scheduler, n_workers),
                "exactly one of a scheduler address or a number of local Dask workers",
            )
        if scheduler is not None and not _looks_like_address(scheduler):
            raise ConfigError(
                "--scheduler", scheduler, "an address tcp://HOST:PORT (or tls://HOST:PORT)"
            )
        if n_workers is not None:
            check_local_workers("--dask-workers", n_workers)
        self.scheduler = scheduler
        self.n_workers = n_workers
        self.connect_timeout_s = connect_timeout_s
        self._client: Any = client
        self._owns_client = client is None
        self._cluster: Any = None
        self._warm: set[str] = set()

    @property
    def client(self) -> Any:
        """The ``distributed.Client`` (started on first use)."""
        self._start()
        return self._client

    @property
    def workers(self) -> int:
        if self._client is None:
            return self.n_workers or 0
        return len(self._client.scheduler_info().get("workers", {}))

    def describe(self) -> dict[str, Any]:
        where = self.scheduler or ("local-cluster" if self.n_workers else "client")
        return {"runner": self.name, "workers": self.workers, "scheduler": where}

    def __enter__(self) -> DaskRunner:
        self._start()
        return self

    def _start(self) -> None:
        if self._client is not None:
            return
        distributed = _import_distributed()
        import dask

        if self.scheduler is not None:
            try:
                self._client = distributed.Client(
                    self.scheduler, timeout=self.connect_timeout_s, set_as_default=False
                )
            except (OSError, TimeoutError) as exc:
                raise ConfigError(
                    "--scheduler",
                    self.scheduler,
                    "the address of a running dask scheduler",
                    f"cannot connect ({exc}); start one with `dask scheduler` and workers "
                    "with `dask worker ADDRESS --nthreads 1`",
                ) from None
            self._client.run(pin_blas_threads)
            self.notes.extend(_unpinned_notes(list(self._client.run(worker_blas_env).values())))
            return
        # Dask's pre-spawn-environ gives way to variables already set in this process, so they
        # are pinned here too while the nannies are made and spawn their workers.
        with dask.config.set(LOCAL_WORKER_CONFIG), pinned_blas_env():
            self._cluster = distributed.LocalCluster(
                n_workers=self.n_workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                # The scheduler serves HTTP routes even without a dashboard, by default on
                # :8787; any free port avoids clashing with another cluster on this machine.
                scheduler_kwargs={"dashboard_address": ":0"},
                silence_logs=logging.ERROR,
            )
            self._client = distributed.Client(self._cluster, set_as_default=False)

    def close(self) -> None:
        if self._client is not None and self._owns_client:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None

    def run(self, target: str, tasks: Iterable[TrialTask]) -> Iterator[Record]:
        distributed = _import_distributed()
        client = self.client
        if target not in self._warm:
            client.run(warm_trial, target)
            self._warm.add(target)
        window = IN_FLIGHT_PER_WORKER * max(self.workers, 1)
        completed = distributed.as_completed(loop=client.loop)
        todo = iter(tasks)
        sizer = BatchSizer()

        def submit(batch: list[TrialTask]) -> Any:
            future = client.submit(execute_trials, target, batch, pure=False)
            completed.add(future)
            return future

        pending: set[Any] = set()
        try:
            _refill(pending, todo, window, sizer, submit)
            for future in completed:
                pending.discard(future)
                records: list[Record] = future.result()
                future.release()
                sizer.observe(records)
                yield from records
                _refill(pending, todo, window, sizer, submit)
        finally:
            for future in pending:
                future.cancel()


#: Dask settings of the local cluster's workers, so that a trial costs there what it costs in
#: a pool process:
#:
#: - the BLAS variables at 1, and not Dask's ``MALLOC_TRIM_THRESHOLD_=65536`` (None unsets
#:   it): that value also fixes glibc's mmap threshold, so every numpy array over 128 KiB is
#:   mapped and unmapped afresh, page faults included (a ch6_receiver trial: 10x the page
#:   faults, 1.45-1.7x the CPU time);
#: - no statistical profiler (it samples the task thread every 10 ms, GIL held: about 10 %
#:   more CPU per trial);
#: - the scheduler's, nannies' and workers' housekeeping once a second instead of every 20 ms
#:   (event-loop health tick) and 100 ms (memory monitor): on a loaded 2-core machine the
#:   cluster's own processes took 3 s of CPU over a 30 s sweep of small trials, 0.4-1.2 s so.
LOCAL_WORKER_CONFIG: dict[str, Any] = {
    **{f"distributed.nanny.pre-spawn-environ.{v}": "1" for v in BLAS_THREAD_VARS},
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1000ms",
    "distributed.worker.memory.monitor-interval": "1000ms",
    "distributed.admin.system-monitor.interval": "2000ms",
}


def _looks_like_address(address: str) -> bool:
    scheme, sep, rest = address.partition("://")
    host, _, port = rest.rpartition(":")
    return bool(sep) and scheme in ("tcp", "tls") and bool(host) and port.isdigit()


def make_runner(
    workers: int | None = None,
    dask_workers: int | None = None,
    scheduler: str | None = None,
    serial: bool = False,
) -> Runner:
    """The runner the command-line options ask for (process pool by default)."""
    if dask_workers is not None and scheduler is not None:
        raise ConfigError(
            "--dask-workers", dask_workers, "not given together with --scheduler", "pick one"
        )
    chosen = [serial, workers is not None, dask_workers is not None or scheduler is not None]
    if sum(chosen) > 1:
        raise ConfigError(
            "--workers/--serial/--dask-workers/--scheduler",
            "several",
            "one way to run: the local pool (--workers), --serial, or Dask",
        )
    if serial:
        return SerialRunner()
    if dask_workers is not None or scheduler is not None:
        return DaskRunner(scheduler=scheduler, n_workers=dask_workers)
    return LocalPoolRunner(workers)
