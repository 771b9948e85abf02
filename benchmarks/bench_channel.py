"""Channel benchmark: one moving target plus 10^5 volume scatterers around a moving sonar.

att preset (random-cyclic HFC-CW, fs = 100 kHz), sonar at 3 m/s with a piston beam
(radius 0.1 m, ka ≈ 12.6, scatterers down to a two-way response of -40 dB: a 28° cone),
scatterers 2-60 m, density set so the beam volume holds 10^5, a 10 m/s target closing from
50 m, sea-state-3 noise. Measures the real-time factor on one core over ``--seconds`` of
signal (target >= 10x) and the memory over a long stream (tracemalloc peak per block and RSS
at the start and end). Prints a table; the last line is one JSON object.

    python benchmarks/bench_channel.py --seconds 10
"""

from __future__ import annotations

import argparse
import json
import resource
import time
import tracemalloc

import numpy as np

from sim_devices.acoustics.scenario import build_channel, parse_scenario

TARGET_XRT = 10.0
SCATTERERS = 100_000


def scenario(density: float) -> dict:
    return {
        "preset": "att", "duration_s": 3600.0, "seed": 1,
        "sonar": {"position_m": [0.0, 0.0, -50.0], "velocity_mps": [3.0, 0.0, 0.0],
                  "beam": {"type": "piston", "radius_m": 0.1}},
        "targets": [{"trajectory": "radial", "range_m": 50.0, "speed_mps": 10.0}],
        "noise": {"sea_state": 3},
        "reverberation": {"scattering_strength_db": -70.0, "density_per_m3": density,
                          "min_range_m": 2.0, "max_range_m": 60.0},
    }  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0, help="signal seconds to time")
    ap.add_argument("--block", type=float, default=0.1, help="block length, s")
    ap.add_argument("--quick", action="store_true", help="smoke run: 0.2 s of signal")
    args = ap.parse_args()
    if args.quick:
        args.seconds = 0.2
    probe = build_channel(parse_scenario(scenario(1.0)))
    assert probe.reverberation is not None
    k1 = probe.reverberation.scatterers_at(0.0)[0].size
    density = SCATTERERS / k1
    ch = build_channel(parse_scenario(scenario(density)))
    rev = ch.reverberation
    assert rev is not None
    k = rev.scatterers_at(0.0)[0].size
    fs = ch.fs_hz
    block = int(args.block * fs)
    n_blocks = int(args.seconds / args.block)
    ch.read(block)  # warm-up: cube generation and caches
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    tracemalloc.start()
    peaks = []
    t0 = time.perf_counter()
    for _ in range(n_blocks):
        tracemalloc.reset_peak()
        ch.read(block)
        peaks.append(tracemalloc.get_traced_memory()[1])
    elapsed = time.perf_counter() - t0
    tracemalloc.stop()
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    xrt = n_blocks * args.block / elapsed
    q = max(1, len(peaks) // 4)
    first, last = float(np.mean(peaks[:q])) / 1e6, float(np.mean(peaks[-q:])) / 1e6
    bins = rev.bins_used / max(1, rev.frames_done)
    print(f"{'quantity':<38} {'value':>12}")
    for name, val in [
        ("scatterers in beam volume", k), ("signal seconds", n_blocks * args.block),
        ("wall seconds (tracemalloc on)", round(elapsed, 2)), ("x real time", round(xrt, 2)),
        ("ratio to 10x target", round(xrt / TARGET_XRT, 3)),
        ("Doppler bins per frame", round(bins, 1)), ("frame samples", rev.frame),
        ("block peak MB, first quarter", round(first, 1)),
        ("block peak MB, last quarter", round(last, 1)),
        ("max RSS MB start / end", f"{rss0 / 1024:.0f} / {rss1 / 1024:.0f}"),
    ]:  # fmt: skip
        print(f"{name:<38} {val!s:>12}")
    print(json.dumps({
        "benchmark": "channel", "fs_hz": fs, "scatterers": int(k), "sonar_speed_mps": 3.0,
        "seconds": n_blocks * args.block, "xrt": round(xrt, 3), "target_xrt": TARGET_XRT,
        "ratio": round(xrt / TARGET_XRT, 3), "bins_per_frame": round(bins, 2),
        "peak_mb_first": round(first, 2), "peak_mb_last": round(last, 2),
        "rss_mb_start": round(rss0 / 1024, 1), "rss_mb_end": round(rss1 / 1024, 1),
    }))  # fmt: skip


if __name__ == "__main__":
    main()
