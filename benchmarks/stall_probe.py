"""One stall probe: a process that sleeps again and again and notes each late wake-up.

Standard library only, so a probe process starts in tens of milliseconds and holds a few MB
(one runs per CPU; ``machine_stalls.StallProbes`` (benchmarks) starts them and reads
their records). A wake-up more than ``threshold_s`` after it was due is a *stall*: the
interval from the due time to the wake-up, on :func:`time.monotonic` (``CLOCK_MONOTONIC``,
shared by every process on the machine). With real-time priority (``SCHED_FIFO``, when the
process may have it) a woken probe preempts every ordinary thread, so what it still sees is
the machine itself: hypervisor, interrupts, kernel sections.

By hand: ``python benchmarks/stall_probe.py --cpu 0 --seconds 10`` prints the record as JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hil.errors import ConfigError

#: Default sleep between two probe wake-ups, s.
PERIOD_S = 0.002
#: Default lateness of a wake-up that counts as a stall, s.
THRESHOLD_S = 0.001
#: Real-time priority a probe asks for (SCHED_FIFO, 1–99): above ordinary threads, below
#: the kernel's own real-time threads (50 is where threaded interrupts run).
RT_PRIORITY = 40


def check_settings(period_s: float, threshold_s: float, cpu: int | None) -> None:
    """Raise :class:`~hil.errors.ConfigError` unless the probe settings are usable."""
    if not (math.isfinite(period_s) and period_s > 0):
        raise ConfigError("period_s", period_s, "a finite time > 0 s", "e.g. 0.002 (2 ms)")
    if not (math.isfinite(threshold_s) and threshold_s > 0):
        raise ConfigError("threshold_s", threshold_s, "a finite time > 0 s", "e.g. 0.001 (1 ms)")
    if cpu is not None and hasattr(os, "sched_getaffinity"):
        allowed = sorted(os.sched_getaffinity(0))
        if cpu not in allowed:
            raise ConfigError(
                "cpu", cpu, f"one of the CPUs this process may use: {allowed}", "pick one of those"
            )


def run_probe(
    stop_after_s: float | None,
    *,
    cpu: int | None = None,
    period_s: float = PERIOD_S,
    threshold_s: float = THRESHOLD_S,
    realtime: bool = True,
    should_stop: Callable[[], bool] | None = None,
    on_ready: Callable[[], None] | None = None,
    now: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> dict[str, Any]:
    """Probe until ``stop_after_s`` (s; None: no limit) or ``should_stop()``; the record.

    Pins the calling process to ``cpu`` (None: leave it) and asks for SCHED_FIFO when
    ``realtime`` (without the right to it, scheduling stays normal and the record says so),
    calls ``on_ready``, then sleeps ``period_s`` at a time. ``now`` and ``sleep`` are the
    clock (tests inject one). The record: ``cpu``, ``realtime``, ``wakeups``, the probed
    interval ``t0``–``t1`` (s), ``period_s``, ``threshold_s`` and the stalls as lists
    ``start``, ``end`` (s).

    >>> clock = [0.0]
    >>> def sleep(s):  # the third wake-up comes 4 ms late
    ...     clock[0] += s + (0.004 if abs(clock[0] - 0.004) < 1e-9 else 0.0)
    >>> r = run_probe(0.02, realtime=False, now=lambda: clock[0], sleep=sleep)
    >>> r["wakeups"], [round(x, 6) for x in r["start"] + r["end"]]
    (8, [0.006, 0.01])
    """
    check_settings(period_s, threshold_s, cpu)
    if stop_after_s is not None and not (math.isfinite(stop_after_s) and stop_after_s >= 0):
        raise ConfigError("seconds", stop_after_s, "a finite time >= 0 s, or none (no limit)")
    if cpu is not None:
        os.sched_setaffinity(0, {cpu})
    rt = False
    if realtime and hasattr(os, "sched_setscheduler"):
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY))
            rt = True
        except OSError:
            rt = False  # no CAP_SYS_NICE / RLIMIT_RTPRIO: measure with normal scheduling
    if on_ready is not None:
        on_ready()
    t0 = now()
    deadline = math.inf if stop_after_s is None else t0 + stop_after_s
    starts: list[float] = []
    ends: list[float] = []
    wakeups = 0
    t = t0
    while t < deadline and not (should_stop is not None and should_stop()):
        due = t + period_s
        sleep(period_s)
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


def main(argv: list[str] | None = None) -> None:
    """Command line: probe one CPU until ``--seconds`` pass, SIGTERM comes or the parent
    process is gone; the record as JSON to ``--out`` or stdout."""
    parser = argparse.ArgumentParser(prog="stall_probe.py", description=__doc__)
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
    stop = False

    def on_term(*_: object) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGTERM, on_term)
    parent = os.getppid()

    def should_stop() -> bool:
        # A parent that died without stopping us (killed) leaves us to its successor: stop.
        return stop or os.getppid() != parent

    try:
        record = run_probe(
            args.seconds,
            cpu=args.cpu,
            period_s=args.period,
            threshold_s=args.threshold,
            realtime=not args.no_realtime,
            should_stop=should_stop,
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
