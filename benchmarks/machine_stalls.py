"""How long this machine keeps a ready thread off its CPU: one stall probe per CPU.

A live run has a deadline per hop (an estimate at most one hop after its boundary). Whether a
machine can meet it is not only a question of the pipeline's work: a virtual machine's
hypervisor may take a virtual CPU away for milliseconds (steal time), and a loaded host may
leave a woken thread waiting for a core. A *stall probe* (``benchmarks/stall_probe.py``) measures
that directly: a small process pinned to one CPU that sleeps ``period_s`` again and again;
when a wake-up comes more than ``threshold_s`` late, the interval it was kept away is a
*stall* on that CPU. With real-time priority (``SCHED_FIFO``, when the process may use it)
a woken probe preempts every ordinary thread at once, so what it still sees is the machine
itself: hypervisor, interrupts, kernel sections that cannot be preempted. Without it the
stalls also count ordinary load, including the run being measured.

:class:`StallProbes` starts one probe per CPU this process may use (at most
:data:`MAX_DEFAULT_CPUS` unless told which) and returns :class:`MachineStalls`, whose
:meth:`~MachineStalls.overlapping` tells which time windows (say, from a boundary's arrival
to its estimate) a stall fell into. All times are :func:`time.monotonic` seconds, which
every process on the machine shares (Linux ``CLOCK_MONOTONIC``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import select
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt
from stall_probe import PERIOD_S, THRESHOLD_S, check_settings

from hil.errors import ConfigError

#: The probe process's script (beside this module: both are benchmark tools, imported with
#: ``benchmarks/`` on ``sys.path`` as a script there has it).
PROBE_SCRIPT = Path(__file__).with_name("stall_probe.py")

#: Most probes started when the CPUs are not named (one process per CPU).
MAX_DEFAULT_CPUS = 8
#: Longest wait for a probe process to start probing, s.
START_TIMEOUT_S = 30.0


@dataclass(frozen=True)
class MachineStalls:
    """Stalls the probes saw: ``start`` and ``end`` (s, monotonic, shape ``(n,)``) and the
    ``cpu`` of each; ``cpus`` probed, whether every probe ran with real-time priority
    (``realtime``), probe ``wakeups`` in all, the probed interval ``t0``–``t1`` (s) and the
    probed CPUs' steal time meanwhile (:func:`steal_s`, s; NaN if unknown)."""

    start: npt.NDArray[np.float64]
    end: npt.NDArray[np.float64]
    cpu: npt.NDArray[np.int64]
    cpus: tuple[int, ...]
    realtime: bool
    wakeups: int
    t0: float
    t1: float
    threshold_s: float = THRESHOLD_S
    steal_s: float = float("nan")

    @property
    def durations_s(self) -> npt.NDArray[np.float64]:
        """Length of each stall, s."""
        return self.end - self.start

    def overlapping(
        self, start: npt.ArrayLike, end: npt.ArrayLike, *, min_stall_s: float = 0.0
    ) -> npt.NDArray[np.bool_]:
        """For each window ``[start[i], end[i]]`` (s, monotonic), whether a stall of at least
        ``min_stall_s`` on any probed CPU overlaps it. NaN windows overlap nothing.

        >>> s = MachineStalls(np.array([1.0, 5.0]), np.array([1.2, 5.01]), np.array([0, 1]),
        ...                   (0, 1), True, 100, 0.0, 10.0)
        >>> s.overlapping([0.0, 1.1, 1.3, 4.0], [1.0, 1.15, 4.0, 6.0]).tolist()
        [True, True, False, True]
        >>> s.overlapping([4.0], [6.0], min_stall_s=0.05).tolist()
        [False]
        """
        keep = self.durations_s >= min_stall_s
        return overlapping(self.start[keep], self.end[keep], start, end)

    def between(self, t0: float, t1: float, steal: float = float("nan")) -> MachineStalls:
        """The stalls within ``t0``–``t1`` (s, monotonic; stalls cut at both ends), that
        interval as the probed one, and ``steal`` (s) as its steal time; the wake-ups are
        counted in proportion.

        >>> s = MachineStalls(np.array([1.0, 5.0]), np.array([1.2, 5.01]), np.array([0, 1]),
        ...                   (0, 1), True, 1000, 0.0, 10.0)
        >>> w = s.between(1.1, 6.0)
        >>> w.start.tolist(), w.end.tolist(), w.wakeups, (w.t0, w.t1)
        ([1.1, 5.0], [1.2, 5.01], 490, (1.1, 6.0))
        """
        if not t1 >= t0:
            raise ConfigError("t1", t1, f">= t0 = {t0}", "give the interval start first")
        keep = (self.end > t0) & (self.start < t1)
        span = max(self.t1 - self.t0, 1e-12)
        share = max(0.0, min(t1, self.t1) - max(t0, self.t0)) / span
        return dataclasses.replace(
            self,
            start=np.maximum(self.start[keep], t0),
            end=np.minimum(self.end[keep], t1),
            cpu=self.cpu[keep],
            wakeups=int(round(self.wakeups * share)),
            t0=float(t0),
            t1=float(t1),
            steal_s=float(steal),
        )

    def summary(self) -> dict[str, Any]:
        """The figures as plain numbers: count, longest (ms), count over 5 ms, stalled time
        and steal time per probed CPU and second (ms/s), and how the probes ran."""
        d = self.durations_s
        span = max(self.t1 - self.t0, 1e-9)
        per_cpu_s = span * max(len(self.cpus), 1)
        return {
            "probe_cpus": list(self.cpus),
            "probe_realtime": self.realtime,
            "probe_wakeups": self.wakeups,
            "stalls": int(d.size),
            "stall_max_ms": round(float(d.max()) * 1e3, 3) if d.size else 0.0,
            "stalls_over_5ms": int(np.count_nonzero(d > 0.005)),
            "stalled_ms_per_s": round(float(d.sum()) * 1e3 / per_cpu_s, 3),
            "steal_ms_per_s": (
                round(self.steal_s * 1e3 / per_cpu_s, 3) if np.isfinite(self.steal_s) else None
            ),
        }


def overlapping(
    interval_start: npt.ArrayLike,
    interval_end: npt.ArrayLike,
    start: npt.ArrayLike,
    end: npt.ArrayLike,
) -> npt.NDArray[np.bool_]:
    """For each window ``[start[i], end[i]]``, whether any interval
    ``[interval_start[k], interval_end[k]]`` overlaps it (ends included; NaN windows overlap
    nothing). O((n + k) log k).

    >>> overlapping([1.0, 5.0], [2.0, 6.0], [0.0, 2.5, 5.5], [0.5, 4.9, 9.0]).tolist()
    [False, False, True]
    """
    a = np.asarray(start, dtype=np.float64)
    b = np.asarray(end, dtype=np.float64)
    s0 = np.asarray(interval_start, dtype=np.float64)
    s1 = np.asarray(interval_end, dtype=np.float64)
    if s0.size == 0:
        return np.zeros(a.shape, dtype=bool)
    order = np.argsort(s0)
    s0, s1 = s0[order], s1[order]
    # An interval overlaps [a, b] when it starts at or before b and ends at or after a:
    # among the intervals starting by b, the latest end decides.
    latest_end = np.maximum.accumulate(s1)
    k = np.searchsorted(s0, b, side="right") - 1
    out = np.zeros(a.shape, dtype=bool)
    ok = (k >= 0) & np.isfinite(a) & np.isfinite(b)
    out[ok] = latest_end[k[ok]] >= a[ok]
    return out


def steal_s(cpus: Iterable[int] | None = None, path: str | Path = "/proc/stat") -> float:
    """Time the hypervisor ran others while ``cpus`` (None: all) wanted to run (``steal``
    in ``/proc/stat``), s, summed over those CPUs; NaN where the file or a CPU is missing.

    >>> import tempfile
    >>> with tempfile.NamedTemporaryFile("w", suffix=".stat", delete=False) as f:
    ...     _ = f.write("cpu  9 0 9 9 0 0 0 700 0 0\\ncpu0 1 0 1 1 0 0 0 300 0 0\\n"
    ...                 "cpu1 1 0 1 1 0 0 0 400 0 0\\nintr 5\\n")
    >>> hz = os.sysconf("SC_CLK_TCK")
    >>> round(steal_s([1], f.name) * hz), round(steal_s(None, f.name) * hz)
    (400, 700)
    >>> import math; math.isnan(steal_s([7], f.name))
    True
    >>> os.unlink(f.name)
    """
    try:
        with open(path) as fh:
            lines = [line.split() for line in fh if line.startswith("cpu")]
    except OSError:
        return float("nan")
    wanted = {"cpu"} if cpus is None else {f"cpu{c}" for c in cpus}
    ticks = {f[0]: int(f[8]) for f in lines if f[0] in wanted and len(f) > 8}
    if set(ticks) != wanted:
        return float("nan")
    return sum(ticks.values()) / os.sysconf("SC_CLK_TCK")


@dataclass
class StallProbes:
    """One probe process per CPU, from :meth:`start` to :meth:`stop` (also a context
    manager); :attr:`result` then holds the :class:`MachineStalls`.

    ``cpus`` default: the CPUs this process may use, the first :data:`MAX_DEFAULT_CPUS`.
    The probes run in their own session (a Ctrl-C at the terminal reaches the caller, which
    stops them) and stop by themselves when the caller's process is gone. :meth:`close`
    kills them without reading anything (error paths; idempotent).

    >>> import time
    >>> with StallProbes(period_s=0.002) as probes:
    ...     time.sleep(0.2)
    >>> probes.result.wakeups > 0
    True
    """

    cpus: tuple[int, ...] | None = None
    period_s: float = PERIOD_S
    threshold_s: float = THRESHOLD_S
    realtime: bool = True
    result: MachineStalls | None = field(default=None, init=False)
    _procs: list[tuple[int, subprocess.Popen[bytes], Path]] = field(
        default_factory=list, init=False
    )
    _dir: tempfile.TemporaryDirectory[str] | None = field(default=None, init=False)
    _steal0: float = field(default=float("nan"), init=False)

    def __post_init__(self) -> None:
        if self.cpus is None:
            cpus = tuple(sorted(os.sched_getaffinity(0)))[:MAX_DEFAULT_CPUS]
        else:
            cpus = tuple(self.cpus)
        if not cpus:
            raise ConfigError("cpus", cpus, "at least one CPU", "leave it None for all")
        if len(set(cpus)) != len(cpus):
            raise ConfigError("cpus", cpus, "each CPU once", "drop the repeated CPUs")
        for cpu in cpus:
            check_settings(self.period_s, self.threshold_s, cpu)
        self.cpus = cpus

    def _command(self, cpu: int, out: Path) -> list[str]:
        """The probe process for ``cpu`` writing its record to ``out``."""
        cmd = [sys.executable, str(PROBE_SCRIPT), "--cpu", str(cpu), "--ready"]
        cmd += ["--period", repr(self.period_s), "--threshold", repr(self.threshold_s)]
        cmd += ["--out", str(out)]
        if not self.realtime:
            cmd.append("--no-realtime")
        return cmd

    def start(self) -> StallProbes:
        """Start the probe processes and wait until each is probing (returns self)."""
        assert self.cpus is not None
        if self._procs or self.result is not None:
            raise RuntimeError("these stall probes were started already: make new ones")
        try:
            self._steal0 = steal_s(self.cpus)
            self._dir = tempfile.TemporaryDirectory(prefix="stall-probe-")
            for cpu in self.cpus:
                out = Path(self._dir.name) / f"cpu{cpu}.json"
                proc = subprocess.Popen(
                    self._command(cpu, out), stdout=subprocess.PIPE, start_new_session=True
                )
                self._procs.append((cpu, proc, out))
            for cpu, proc, _ in self._procs:
                assert proc.stdout is not None
                ready, _, _ = select.select([proc.stdout], [], [], START_TIMEOUT_S)
                line = proc.stdout.readline().strip() if ready else b""
                if line != b"ready":
                    code = proc.poll()
                    why = f"exit status {code}" if code is not None else "no answer"
                    raise RuntimeError(
                        f"the stall probe for CPU {cpu} did not start ({why}); its error, if"
                        " any, is above"
                    )
        except BaseException:
            self.close()
            raise
        return self

    def stop(self) -> MachineStalls:
        """Stop the probes and collect what they saw (again: the same result)."""
        if self.result is not None:
            return self.result
        if not self._procs:
            raise RuntimeError("the stall probes are not running: call start() first")
        records = []
        try:
            for _, proc, _ in self._procs:
                proc.send_signal(signal.SIGTERM)
            for cpu, proc, out in self._procs:
                code = proc.wait(timeout=10)
                if code != 0 or not out.exists():
                    raise RuntimeError(
                        f"the stall probe for CPU {cpu} exited with status {code} and no record"
                    )
                records.append(json.loads(out.read_text()))
            steal = steal_s(self.cpus) - self._steal0
        finally:
            self.close()
        self.result = _merge(records, steal)
        return self.result

    def close(self) -> None:
        """Kill the probe processes that still run and remove their files (idempotent)."""
        for _, proc, _ in self._procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            if proc.stdout is not None:
                proc.stdout.close()
        self._procs.clear()
        if self._dir is not None:
            self._dir.cleanup()
            self._dir = None

    def __enter__(self) -> StallProbes:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.stop()
        else:
            self.close()


def _merge(records: list[dict[str, Any]], steal: float = float("nan")) -> MachineStalls:
    if not records:
        raise ValueError("no probe records to merge")
    start = np.array([s for r in records for s in r["start"]], dtype=np.float64)
    end = np.array([e for r in records for e in r["end"]], dtype=np.float64)
    cpu = np.array([r["cpu"] for r in records for _ in r["start"]], dtype=np.int64)
    return MachineStalls(
        start=start,
        end=end,
        cpu=cpu,
        cpus=tuple(int(r["cpu"]) for r in records),
        realtime=all(r["realtime"] for r in records),
        wakeups=sum(int(r["wakeups"]) for r in records),
        t0=max(float(r["t0"]) for r in records),
        t1=min(float(r["t1"]) for r in records),
        threshold_s=float(records[0]["threshold_s"]),
        steal_s=steal,
    )
