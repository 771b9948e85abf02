"""Tracker cost per estimate (hil.estimation.tracking) against the number of targets.

Scripted constant-velocity targets at the ``att`` hop rate (10 ms hops: 100 estimates per
target per second), each with one clutter estimate per target every other hop, fed to one
:class:`~hil.estimation.tracking.Tracker` in receive-time order. Reports the CPU time per
estimate and the real-time factor (signal seconds per CPU second) for 1, 4, 16 and 64
targets. Target: at least 20× real time with 16 targets (the tracker must stay a small
part of a receiver's budget).

Run: ``python benchmarks/bench_tracking.py [--seconds 10] [--quick]``. The last line is one
JSON object with the figures.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from hil.estimation.base import Estimate
from hil.estimation.tracking import Tracker

C = 1500.0
HOP_S = 0.01
TARGET_XRT = 20.0


def scene(n_targets: int, seconds: float, seed: int = 0) -> list[Estimate]:
    """Estimates of ``n_targets`` targets (ranges 5–95 m, speeds ±20 m/s) and as many
    clutter estimates every other hop, in receive-time order."""
    rng = np.random.default_rng(seed)
    n_hops = int(seconds / HOP_S)
    r0 = rng.uniform(20.0, 80.0, n_targets)
    v = rng.uniform(-20.0, 20.0, n_targets) * (r0 > 0)
    k = np.arange(n_hops)
    t_tx = (k[:, None] + 1) * HOP_S
    r = (r0[None, :] - v[None, :] * t_tx) / (1.0 + v[None, :] / C)  # range at the bounce
    rows = []
    for j in range(n_targets):
        for i in range(n_hops):
            rows.append((t_tx[i, 0] + 2 * r[i, j] / C, r[i, j] + rng.normal(0, 0.005),
                         v[j] + rng.normal(0, 0.01), i, t_tx[i, 0]))  # fmt: skip
        for i in range(0, n_hops, 2):
            rc = float(rng.uniform(5.0, 95.0))
            rows.append((t_tx[i, 0] + 2 * rc / C, rc, float(rng.uniform(-30, 30)), i, t_tx[i, 0]))
    rows.sort()
    return [
        Estimate(t, rr, vv, int(h), 10.0, 20.0, 1.0, ttx, int(h) % 17, "bench", 0.003, 0.008)
        for t, rr, vv, h, ttx in rows
    ]


def measure(n_targets: int, seconds: float) -> dict[str, float]:
    """CPU µs per estimate and real-time factor of tracking ``seconds`` of the scene."""
    est = scene(n_targets, seconds)
    tracker = Tracker(HOP_S)
    t0 = time.process_time()
    out = tracker.update(est)
    cpu = time.process_time() - t0
    return {
        "estimates": len(est),
        "confirmed_tracks": tracker.next_id,
        "tracked_fraction": round(sum(e.track_id >= 0 for e in out) / len(out), 4),
        "us_per_estimate": round(1e6 * cpu / len(est), 2),
        "real_time_factor": round(seconds / cpu, 1) if cpu > 0 else float("inf"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="signal seconds per scene")
    parser.add_argument("--quick", action="store_true", help="smoke run (0.2 s): checks it runs")
    args = parser.parse_args()
    seconds = 0.2 if args.quick else args.seconds
    figures: dict[str, object] = {"seconds": seconds, "target_xrt_16": TARGET_XRT}
    measure(1, 0.05)  # the compiled loop loaded (or compiled) before anything is timed
    for n in (1, 4, 16, 64):
        figures[f"targets_{n}"] = m = measure(n, seconds)
        print(f"{n:3d} targets: {m}")
    figures["meets_target"] = bool(figures["targets_16"]["real_time_factor"] >= TARGET_XRT)  # type: ignore[index]
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
