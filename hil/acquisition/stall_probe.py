"""How long this machine keeps a ready thread off its CPU: one probe process per CPU.

A live run has a deadline per hop (an estimate at most one hop after its boundary). Whether a
machine can meet it is not only a question of the pipeline's work: a virtual machine's
hypervisor may take a virtual CPU away for milliseconds (steal time), and a loaded host may
leave a woken thread waiting for a core. A *stall probe* measures that directly. It is a
small process pinned to one CPU that sleeps ``period_s`` again and again; when a wake-up
comes more than ``threshold_s`` late, the interval it was kept away is a *stall* on that
CPU. With real-time priority (``SCHED_FIFO``, when the process may use it) a woken probe
preempts every ordinary thread at once, so what it still sees is the machine itself:
hypervisor, interrupts, kernel sections that cannot be preempted. Without it the stalls
also count ordinary load, including the run being measured.

:class:`StallProbes` starts one probe per CPU this process may run on and returns
:class:`MachineStalls`, whose :meth:`~MachineStalls.overlapping` tells which time windows
(say, from a boundary's arrival to its estimate) a stall fell into. All times are
:func:`time.monotonic` seconds, which every process on the machine shares (Linux
``CLOCK_MONOTONIC``).

Run one probe by hand: ``python -m hil.acquisition.stall_probe --cpu 0 --seconds 10``.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt

from hil.errors import ConfigError

#: Default sleep between two probe wake-ups, s.
PERIOD_S = 0.002
#: Default lateness of a wake-up that counts as a stall, s.
THRESHOLD_S = 0.001
#: Real-time priority a probe asks for (SCHED_FIFO, 1–99): above ordinary threads, below
#: the kernel's own real-time threads (50 is where threaded interrupts run).
RT_PRIORITY = 40


@dataclass(frozen=True)
class MachineStalls:
    """Stalls the probes saw: ``start`` and ``end`` (s, monotonic, shape ``(n,)``) and the
    ``cpu`` of each; ``cpus`` probed, whether every probe ran with real-time priority
    (``realtime``), probe ``wakeups`` in all, the probed interval ``t0``–``t1`` (s) and the
    machine's steal time meanwhile (:func:`steal_s`, all CPUs; NaN if unknown)."""

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

    def summary(self) -> dict[str, Any]:
        """The figures as plain numbers: count, longest (ms), count over 5 ms, stalled time
        and the machine's steal time per CPU and second of probing (ms/s), and how the probes
        ran."""
        d = self.durations_s
        span = max(self.t1 - self.t0, 1e-9)
        return {
            "probe_cpus": list(self.cpus),
            "probe_realtime": self.realtime,
            "probe_wakeups": self.wakeups,
            "stalls": int(d.size),
            "stall_max_ms": round(float(d.max()) * 1e3, 3) if d.size else 0.0,
            "stalls_over_5ms": int(np.count_nonzero(d > 0.005)),
            "stalled_ms_per_s": round(float(d.sum()) * 1e3 / span / max(len(self.cpus), 1), 3),
            "steal_ms_per_s": (
                round(self.steal_s * 1e3 / span / max(len(self.cpus), 1), 3)
                if np.isfinite(self.steal_s)
                else None
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


def steal_s() -> float:
    """CPU time the hypervisor gave to others while this machine's CPUs wanted to run
    (``steal`` in /proc/stat, all CPUs), s; NaN where there is no /proc/stat."""
    try:
        with open("/proc/stat") as fh:
            fields = fh.readline().split()
    except OSError:
        return float("nan")
    if fields[0] != "cpu" or len(fields) < 9:
        return float("nan")
    return int(fields[8]) / os.sysconf("SC_CLK_TCK")


def probe(
    stop_after_s: float | None,
    *,
    cpu: int | None = None,
    period_s: float = PERIOD_S,
    threshold_s: float = THRESHOLD_S,
    realtime: bool = True,
    on_ready: Callable[[], None] | None = None,
) -> dict[str, Any]:
    """Probe in this process until ``stop_after_s`` (s) or SIGTERM; the record as a dict.

    Pins the process to ``cpu`` (None: leave it), asks for SCHED_FIFO when ``realtime`` (an
    ordinary process keeps normal scheduling, and the record says so), calls ``on_ready``,
    then sleeps
    ``period_s`` at a time; a wake-up more than ``threshold_s`` late is a stall from the
    moment the sleep should have ended to the wake-up.
    """
    _check_probe_settings(period_s, threshold_s, cpu)
    if cpu is not None:
        os.sched_setaffinity(0, {cpu})
    rt = False
    if realtime:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY))
            rt = True
        except (PermissionError, OSError, AttributeError):
            rt = False  # no CAP_SYS_NICE / RLIMIT_RTPRIO: measure with normal scheduling
    stop = False

    def on_term(*_: object) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGTERM, on_term)
    if on_ready is not None:
        on_ready()
    now = time.monotonic
    t0 = now()
    deadline = float("inf") if stop_after_s is None else t0 + stop_after_s
    starts: list[float] = []
    ends: list[float] = []
    wakeups = 0
    t = t0
    while not stop and t < deadline:
        due = t + period_s
        time.sleep(period_s)
        t = now()
        wakeups += 1
        if t - due > threshold_s:
            starts.append(due)
            ends.append(t)
    return {
        "cpu": cpu,
        "realtime": rt,
        "wakeups": wakeups,
        "t0": t0,
        "t1": t,
        "period_s": period_s,
        "threshold_s": threshold_s,
        "start": starts,
        "end": ends,
    }


def _check_probe_settings(period_s: float, threshold_s: float, cpu: int | None) -> None:
    if not period_s > 0:
        raise ConfigError("period_s", period_s, "> 0 s", "a probe sleeps this long per wake-up")
    if not threshold_s > 0:
        raise ConfigError("threshold_s", threshold_s, "> 0 s", "e.g. 0.001 (1 ms)")
    allowed = sorted(os.sched_getaffinity(0))
    if cpu is not None and cpu not in allowed:
        raise ConfigError(
            "cpu", cpu, f"one of the CPUs this process may use: {allowed}", "pick one of those"
        )


@dataclass
class StallProbes:
    """One probe process per CPU (default: every CPU this process may use), from
    :meth:`start` to :meth:`stop` (also a context manager); :attr:`result` then holds the
    :class:`MachineStalls`.

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
    _procs: list[tuple[subprocess.Popen[bytes], Path]] = field(default_factory=list, init=False)
    _dir: tempfile.TemporaryDirectory[str] | None = field(default=None, init=False)
    _steal0: float = field(default=float("nan"), init=False)

    def __post_init__(self) -> None:
        cpus = self.cpus if self.cpus is not None else tuple(sorted(os.sched_getaffinity(0)))
        if not cpus:
            raise ConfigError("cpus", cpus, "at least one CPU", "leave it None for all")
        for cpu in cpus:
            _check_probe_settings(self.period_s, self.threshold_s, cpu)
        self.cpus = tuple(cpus)

    def start(self) -> StallProbes:
        """Start the probe processes and wait until each is probing (returns self)."""
        assert self.cpus is not None
        self._steal0 = steal_s()
        self._dir = tempfile.TemporaryDirectory(prefix="stall-probe-")
        for cpu in self.cpus:
            out = Path(self._dir.name) / f"cpu{cpu}.json"
            cmd = [sys.executable, "-m", "hil.acquisition.stall_probe", "--cpu", str(cpu)]
            cmd += ["--period", repr(self.period_s), "--threshold", repr(self.threshold_s)]
            cmd += ["--out", str(out), "--ready"]
            if not self.realtime:
                cmd.append("--no-realtime")
            proc = subprocess.Popen(cmd, stdout=subprocess.PIPE)
            self._procs.append((proc, out))
        for proc, _ in self._procs:
            assert proc.stdout is not None
            if proc.stdout.readline().strip() != b"ready":
                self._kill()
                raise RuntimeError(f"stall probe failed to start (exit {proc.wait()})")
        return self

    def stop(self) -> MachineStalls:
        """Stop the probes and collect what they saw."""
        records = []
        try:
            for proc, _ in self._procs:
                proc.send_signal(signal.SIGTERM)
            for proc, out in self._procs:
                code = proc.wait(timeout=10)
                if code != 0:
                    raise RuntimeError(f"stall probe exited with {code}")
                records.append(json.loads(out.read_text()))
        finally:
            self._kill()
        self.result = _merge(records, steal_s() - self._steal0)
        return self.result

    def _kill(self) -> None:
        for proc, _ in self._procs:
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
            self._kill()


def _merge(records: list[dict[str, Any]], steal: float = float("nan")) -> MachineStalls:
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


def main(argv: list[str] | None = None) -> None:
    """Command line: probe one CPU; the record as JSON to ``--out`` or stdout."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--cpu", type=int, default=None, help="CPU to pin to (default: any)")
    parser.add_argument(
        "--seconds", type=float, default=None, help="probe time (default: to SIGTERM)"
    )
    parser.add_argument("--period", type=float, default=PERIOD_S, help="sleep per wake-up, s")
    parser.add_argument("--threshold", type=float, default=THRESHOLD_S, help="stall, s late")
    parser.add_argument("--no-realtime", action="store_true", help="do not ask for SCHED_FIFO")
    parser.add_argument("--out", type=Path, default=None, help="JSON file (default stdout)")
    parser.add_argument("--ready", action="store_true", help="print 'ready' once probing")
    args = parser.parse_args(argv)
    try:
        record = probe(
            args.seconds,
            cpu=args.cpu,
            period_s=args.period,
            threshold_s=args.threshold,
            realtime=not args.no_realtime,
            on_ready=(lambda: print("ready", flush=True)) if args.ready else None,
        )
    except ConfigError as error:
        parser.error(str(error))
    text = json.dumps(record)
    if args.out is None:
        print(text)
    else:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
