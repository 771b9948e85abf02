"""Channel benchmark: two rows, each against a real-time target.

Row ``att-reverb``: one moving target plus 10^5 volume scatterers around a moving sonar. att
preset (random-cyclic HFC-CW, fs = 100 kHz), sonar at 3 m/s with a piston beam (radius 0.1 m,
ka ≈ 12.6, scatterers down to a two-way response of -40 dB: a 28° cone), scatterers 2-60 m,
density set so the beam volume holds 10^5, a 10 m/s target closing from 50 m, sea-state-3
noise. Speed: real-time factor on one core over ``--seconds`` of signal (target >= 10x),
measured without tracemalloc. Memory: a separate pass over ``--memory-seconds`` of signal
(>= 60 s by default) with tracemalloc on: the peak traced memory per block, averaged over the
first and the last quarter of the blocks, and the process RSS after the first and the last
quarter (a flat stream keeps them level).

Row ``tank-board``: ``scenarios/tank-board.toml`` (1 MS/s, 19 echo paths of the first-order
tank images of a towed target, noise at a requested SNR), read in board-sized blocks of
``--board-block`` samples. The simulated board streams two such channels live, so the target
is 2x real time per channel (1x for the pair); the aim is twice that.

Real-time factors are signal seconds over this process's CPU seconds (``time.process_time``,
all numeric work runs on one thread), so other load on the machine does not count against
them; wall-clock factors are printed beside them.

    python benchmarks/bench_channel.py                # full run (about a minute)
    python benchmarks/bench_channel.py --quick        # smoke run, a few seconds

Prints a table; the last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np

from hil.data import scenario_path
from sim_devices.acoustics.channel import Channel
from sim_devices.acoustics.scenario import build_channel, load_scenario, parse_scenario

TARGET_XRT = 10.0
TANK_TARGET_XRT = 2.0  # per channel: two live channels at 1x
TANK_AIM_XRT = 4.0  # per channel: two live channels at 2x
SCATTERERS = 100_000


def scenario(density: float) -> dict[str, Any]:
    return {
        "preset": "att", "duration_s": 3600.0, "seed": 1,
        "sonar": {"position_m": [0.0, 0.0, -50.0], "velocity_mps": [3.0, 0.0, 0.0],
                  "beam": {"type": "piston", "radius_m": 0.1}},
        "targets": [{"trajectory": "radial", "range_m": 50.0, "speed_mps": 10.0}],
        "noise": {"sea_state": 3},
        "reverberation": {"scattering_strength_db": -70.0, "density_per_m3": density,
                          "min_range_m": 2.0, "max_range_m": 60.0},
    }  # fmt: skip


def att_channel() -> tuple[Channel, int]:
    """The att-reverb channel with 10^5 scatterers in the beam volume, and that count."""
    probe = build_channel(parse_scenario(scenario(1.0)))
    assert probe.reverberation is not None
    k1 = probe.reverberation.scatterers_at(0.0)[0].size
    ch = build_channel(parse_scenario(scenario(SCATTERERS / k1)))
    assert ch.reverberation is not None
    return ch, int(ch.reverberation.scatterers_at(0.0)[0].size)


def stream_speed(ch: Channel, block: int, n_blocks: int) -> tuple[float, float]:
    """CPU and wall seconds to read ``n_blocks`` blocks of ``block`` samples."""
    c0, w0 = time.process_time(), time.perf_counter()
    for _ in range(n_blocks):
        ch.read(block)
    return time.process_time() - c0, time.perf_counter() - w0


def rss_mb() -> float:
    """Current resident set size of this process, MB."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * 4096 / 1e6


def memory_pass(block: int, n_blocks: int) -> dict[str, float]:
    """Peak traced memory per block and RSS over a long att-reverb stream.

    Tracing starts before the channel is built, so every array it holds is counted.
    """
    tracemalloc.start()
    ch, _ = att_channel()
    ch.read(block)
    peaks, rss = [], []
    for _ in range(n_blocks):
        tracemalloc.reset_peak()
        ch.read(block)
        peaks.append(tracemalloc.get_traced_memory()[1])
        rss.append(rss_mb())
    tracemalloc.stop()
    q = max(1, n_blocks // 4)
    return {
        "peak_mb_first": float(np.mean(peaks[:q])) / 1e6,
        "peak_mb_last": float(np.mean(peaks[-q:])) / 1e6,
        "rss_mb_first": rss[q - 1],
        "rss_mb_last": rss[-1],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0, help="att signal seconds timed")
    ap.add_argument("--memory-seconds", type=float, default=60.0, help="att memory pass, s")
    ap.add_argument("--block", type=float, default=0.1, help="att block length, s")
    ap.add_argument("--tank-seconds", type=float, default=4.0, help="tank-board seconds timed")
    ap.add_argument("--board-block", type=int, default=4096, help="tank-board block, samples")
    ap.add_argument("--quick", action="store_true", help="smoke run of a few seconds")
    args = ap.parse_args()
    if args.quick:
        args.seconds, args.memory_seconds, args.tank_seconds = 0.3, 0.5, 0.05

    ch, k = att_channel()
    rev = ch.reverberation
    assert rev is not None
    block = int(args.block * ch.fs_hz)
    n_blocks = max(1, int(round(args.seconds / args.block)))
    ch.read(block)  # warm-up: cube generation and caches
    cpu, wall = stream_speed(ch, block, n_blocks)
    sig = n_blocks * args.block
    xrt, xrt_wall = sig / cpu, sig / wall
    bins = rev.bins_used / max(1, rev.frames_done)
    mem = memory_pass(block, max(4, int(round(args.memory_seconds / args.block))))

    tank = build_channel(load_scenario(scenario_path("tank-board")))
    tb = args.board_block
    t_blocks = max(1, int(round(args.tank_seconds * tank.fs_hz / tb)))
    tank.read(tb)
    t_cpu, t_wall = stream_speed(tank, tb, t_blocks)
    t_sig = t_blocks * tb / tank.fs_hz
    t_xrt, t_xrt_wall = t_sig / t_cpu, t_sig / t_wall
    exact = sum(e.exact_intervals for e in tank._echoes)

    print(f"{'quantity':<46} {'value':>14}")
    for name, val in [
        ("att-reverb: scatterers in beam volume", k),
        ("att-reverb: signal seconds timed", round(sig, 2)),
        ("att-reverb: CPU / wall seconds", f"{cpu:.2f} / {wall:.2f}"),
        ("att-reverb: x real time (CPU / wall)", f"{xrt:.2f} / {xrt_wall:.2f}"),
        ("att-reverb: ratio to 10x target", round(xrt / TARGET_XRT, 3)),
        ("att-reverb: Doppler bins per frame", round(bins, 1)),
        ("att-reverb: frame samples", rev.frame),
        ("memory: signal seconds (tracemalloc on)", round(args.memory_seconds, 1)),
        ("memory: block peak MB, first / last quarter",
         f"{mem['peak_mb_first']:.1f} / {mem['peak_mb_last']:.1f}"),
        ("memory: RSS MB, first / last quarter",
         f"{mem['rss_mb_first']:.0f} / {mem['rss_mb_last']:.0f}"),
        ("tank-board: echo paths", len(tank._echoes)),
        ("tank-board: signal seconds timed", round(t_sig, 3)),
        ("tank-board: x real time per channel (CPU/wall)", f"{t_xrt:.2f} / {t_xrt_wall:.2f}"),
        ("tank-board: x real time, two channels", round(t_xrt / 2, 2)),
        ("tank-board: ratio to 2x-per-channel target", round(t_xrt / TANK_TARGET_XRT, 3)),
        ("tank-board: intervals solved exactly", exact),
    ]:  # fmt: skip
        print(f"{name:<46} {val!s:>14}")
    print(json.dumps({
        "benchmark": "channel",
        "att_reverb": {
            "fs_hz": ch.fs_hz, "scatterers": k, "sonar_speed_mps": 3.0, "seconds": sig,
            "xrt": round(xrt, 3), "xrt_wall": round(xrt_wall, 3), "target_xrt": TARGET_XRT,
            "ratio": round(xrt / TARGET_XRT, 3), "bins_per_frame": round(bins, 2),
            "memory_seconds": args.memory_seconds,
            **{key: round(v, 2) for key, v in mem.items()},
        },
        "tank_board": {
            "fs_hz": tank.fs_hz, "paths": len(tank._echoes), "seconds": round(t_sig, 4),
            "block_samples": tb, "xrt_per_channel": round(t_xrt, 3),
            "xrt_per_channel_wall": round(t_xrt_wall, 3), "xrt_two_channels": round(t_xrt / 2, 3),
            "target_xrt_per_channel": TANK_TARGET_XRT, "aim_xrt_per_channel": TANK_AIM_XRT,
            "ratio": round(t_xrt / TANK_TARGET_XRT, 3),
        },
        "xrt": round(xrt, 3), "target_xrt": TARGET_XRT, "ratio": round(xrt / TARGET_XRT, 3),
    }))  # fmt: skip


if __name__ == "__main__":
    main()
