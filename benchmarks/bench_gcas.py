"""Streaming GCAS speed, flatness in M, memory over a long stream, and the full-bank ratio.

Preset ``att``, random cyclic code (4 tones, L = 17, T_h = 10 ms), real input at
fs = 100 kHz, D = 64 Doppler hypotheses over ±30 m/s, one core (BLAS threads pinned to 1
before numpy is imported; the bank's FFTs on one worker). The input is an exact moving-target
echo (60 m, 12 m/s closing) in white noise at 0 dB per-sample SNR, fed in blocks of 0.1 s.
The echo is :data:`SIGNAL_S` seconds long (``--signal-seconds``) and cycled to make longer
inputs: at each cycle the echo starts again, and as 2 s is not a whole number of code periods
(17 hops, 0.17 s) the receiver reads each cycle's echo 30 m nearer than the last (over 20 s it
starts at 60, 30, 0, 97.5, 67.5, 37.5, 7.5, 105, 75 and 45 m and closes 24 m in each); a range
below 0 reads 127.5 m (one code period) further, and the detections beyond ``max_range_m`` =
100 m are fitted and then refused by range (1637 estimates of some 2000 boundaries at M = 10).
The ``M`` or so detections whose hops straddle a jump are fits of part of an echo (their hops'
coherence falls as an accelerating echo's does; the refinement does not try its accelerating
fit where the echo holds one side of the window only, :data:`hil.estimation.refine.PARTIAL_LEVEL`).

Timing is interleaved: every repeat runs each receiver once (GCAS at every M, then the bank at
every M), and each figure is the best of the repeats, so a slow spell of a shared machine hits
all M alike instead of one block of runs. One untimed warm-up run first loads the compiled
kernels. Wall and CPU (``time.process_time``) times are both reported; ratios use wall time.

Figures and targets:

- real-time factor of GCAS at M = 10 (signal seconds per wall-clock second), with its
  default coherent refinement: >= 100x; the detector alone (``refine=False``) beside it, and
  the refinement's cost per estimate: the difference over the estimates, and the CPU spent
  inside the refiner's own calls (one more untimed run, each call timed with
  ``time.process_time``), and of that the CPU inside each of the refinement's compiled
  kernels (the rest of it is the refiner's Python): the rest of the difference is the
  detector's own work for the refinement (every local maximum a candidate, the still
  candidates' second codewords);
- GCAS time for M = 5, 10, 15, 22, 29: max/min <= 1.3 (cost independent of M);
- memory over a 10-minute stream: tracemalloc peak per minute and RSS at the end of every
  minute; the last minute must not exceed the first (flat, no growth);
- the full matched-filter bank (:class:`~hil.estimation.mfbank.MatchedFilterBank`: baseband
  FFT overlap-save, complex64, same Doppler grid, ``refine=False`` so only the bank itself is
  timed) at M = 5, 10 and 29: GCAS >= 5x faster at M = 10 (the ratio at every M is listed).

Run: ``python benchmarks/bench_gcas.py [--seconds 20] [--bank-seconds 4] [--repeat 3]
[--stream-minutes 10] [--quick] [--search full|two-stage] [--signal-seconds 2]``
(``--search`` picks the GCAS correlator search; ``--signal-seconds`` the echo's length before
it is cycled, at most :data:`MAX_SIGNAL_S`). The last line is one JSON object with the
figures and the ratios to the targets.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from collections.abc import Iterator  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

import hil.estimation.refine as refine_module  # noqa: E402
import hil.estimation.refine_pair as pair_module  # noqa: E402
from hil.estimation.cost import gcas_mults_per_sample  # noqa: E402
from hil.estimation.gcas import GcasReceiver  # noqa: E402
from hil.estimation.mfbank import MatchedFilterBank  # noqa: E402
from hil.signals.presets import check_design, get_preset  # noqa: E402
from hil.signals.schedule import HopSchedule  # noqa: E402
from sim_devices.acoustics.delay import TwoWayPath  # noqa: E402
from sim_devices.acoustics.echo import AnalyticEcho  # noqa: E402
from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed  # noqa: E402

FS_HZ = 100_000.0
C = 1500.0
V_MAX = 30.0
R_MAX = 100.0
N_DOPPLER = 64
BLOCK = 10_000  # 0.1 s
M_LIST = (5, 10, 15, 22, 29)
BANK_M = (5, 10, 29)
TARGET_XRT = 100.0
TARGET_FLAT = 1.3
TARGET_BANK = 5.0
SIGNAL_S = 2.0  # distinct echo seconds, repeated to make longer inputs
#: The longest echo ``--signal-seconds`` gives, s: the target (60 m closing at 12 m/s) is then
#: 6 m from the transducer.
MAX_SIGNAL_S = 4.5


def schedule() -> HopSchedule:
    return check_design(get_preset("att").spec("random-cyclic"))


def test_signal(sch: HopSchedule, seconds: float, seed: int = 1) -> np.ndarray:
    """Echo of a target at 60 m closing at 12 m/s plus white noise (0 dB per sample)."""
    path = TwoWayPath.monostatic(
        Fixed((0.0, 0.0, 0.0)), ConstantVelocity((60.0, 0.0, 0.0), (-12.0, 0.0, 0.0)), C
    )
    x = AnalyticEcho(sch, path, FS_HZ).block(0, int(round(seconds * FS_HZ)))
    rng = np.random.default_rng(seed)
    return x + rng.normal(0.0, np.sqrt(0.5), x.shape)


def blocks(base: np.ndarray, seconds: float) -> Iterator[np.ndarray]:
    """``seconds`` of input in :data:`BLOCK`-sample blocks, cycling through ``base``."""
    n_total = int(round(seconds * FS_HZ))
    pos = 0
    while pos < n_total:
        count = min(BLOCK, n_total - pos)
        a = pos % base.shape[0]
        blk = base[a : a + count]
        if blk.shape[0] < count:
            blk = np.concatenate((blk, base[: count - blk.shape[0]]))
        yield blk
        pos += count


SEARCH = {"search": "two-stage"}  # set from --search in main()


def gcas(sch: HopSchedule, m_hops: int, refine: bool = True) -> GcasReceiver:
    return GcasReceiver.from_options(
        sch, FS_HZ, sound_speed_mps=C, max_speed_mps=V_MAX, max_range_m=R_MAX,
        m_hops=m_hops, n_doppler=N_DOPPLER, search=SEARCH["search"], refine=refine,
    )  # fmt: skip


def bank(sch: HopSchedule, m_hops: int) -> MatchedFilterBank:
    return MatchedFilterBank.from_options(
        sch, FS_HZ, sound_speed_mps=C, max_speed_mps=V_MAX, max_range_m=R_MAX,
        m_hops=m_hops, n_doppler=N_DOPPLER, refine=False, fft_workers=1,
    )  # fmt: skip


def run_once(make: Any, base: np.ndarray, seconds: float) -> tuple[float, float, int]:
    """Wall time (s), CPU time (s) and estimate count of one run of ``seconds`` of input
    (the receiver is built before the clock starts)."""
    rx = make()
    w0, c0 = time.perf_counter(), time.process_time()
    n = 0
    for blk in blocks(base, seconds):
        n += len(rx.process(blk))
    n += len(rx.flush())
    return time.perf_counter() - w0, time.process_time() - c0, n


def time_interleaved(
    runs: dict[tuple[str, int], tuple[Any, float]], base: np.ndarray, repeat: int
) -> dict[tuple[str, int], dict[str, float]]:
    """Best wall and CPU time over ``repeat`` rounds, each round running every entry of
    ``runs`` (key → (receiver factory, input seconds)) once in order."""
    best: dict[tuple[str, int], dict[str, float]] = {
        key: {"wall_s": float("inf"), "cpu_s": float("inf"), "estimates": 0} for key in runs
    }
    for _ in range(repeat):
        for key, (make, seconds) in runs.items():
            wall, cpu, n = run_once(make, base, seconds)
            row = best[key]
            row["wall_s"] = min(row["wall_s"], wall)
            row["cpu_s"] = min(row["cpu_s"], cpu)
            row["estimates"] = n
    return best


#: The refinement's compiled kernels, timed one by one in :func:`refiner_cpu`.
REFINE_KERNELS = ("candidate_sums", "assign_slots", "maximise", "grid_sums", "fit_quality")


def refiner_cpu(
    sch: HopSchedule, base: np.ndarray, seconds: float
) -> tuple[float, float, int, dict[str, float]]:
    """CPU seconds inside the refiner's calls (:class:`~hil.estimation.refine.
    CoherentRefiner`'s methods the receiver calls; nested calls counted once), CPU seconds
    of the whole run, the estimate count and the CPU seconds inside each of
    :data:`REFINE_KERNELS` (wherever the refinement's modules call them; each call timed on
    its own, about 1-2 us of timer a call), GCAS at M = 10 over ``seconds`` of input."""
    rx = gcas(sch, 10)
    refiner = rx._refiner
    spent = [0.0, 0]  # seconds, depth
    kernel_s = dict.fromkeys(REFINE_KERNELS, 0.0)
    saved = [
        (module, name, getattr(module, name))
        for module in (refine_module, pair_module)
        for name in REFINE_KERNELS
        if hasattr(module, name)
    ]

    def timed_kernel(name: str, kernel: Any) -> Any:
        def call(*args: Any) -> Any:
            t0 = time.process_time()
            try:
                return kernel(*args)
            finally:
                kernel_s[name] += time.process_time() - t0

        return call

    def timed(method: Any) -> Any:
        def call(*args: Any, **kwargs: Any) -> Any:
            spent[1] += 1
            t0 = time.process_time()
            try:
                return method(*args, **kwargs)
            finally:
                spent[1] -= 1
                if spent[1] == 0:
                    spent[0] += time.process_time() - t0

        return call

    for name in ("refine", "ghost_of_known", "beside_known", "correlation", "known_echoes", "push"):
        setattr(refiner, name, timed(getattr(refiner, name)))
    for module, name, kernel in saved:
        setattr(module, name, timed_kernel(name, kernel))
    try:
        c0 = time.process_time()
        n = 0
        for blk in blocks(base, seconds):
            n += len(rx.process(blk))
        n += len(rx.flush())
        total = time.process_time() - c0
    finally:
        for module, name, kernel in saved:
            setattr(module, name, kernel)
    return spent[0], total, n, kernel_s


def rss_mib() -> float:
    """Resident set size of this process, MiB (Linux /proc; NaN elsewhere)."""
    try:
        with open("/proc/self/statm") as fh:
            pages = int(fh.read().split()[1])
    except OSError:
        return float("nan")
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def stream_memory(sch: HopSchedule, base: np.ndarray, minutes: float) -> dict[str, Any]:
    """tracemalloc peak per minute (MiB) and RSS at each minute's end over a long stream."""
    rx = gcas(sch, 10)
    minute_s = min(60.0, minutes * 60.0)
    n_min = max(1, int(round(minutes * 60.0 / minute_s)))
    peaks, rss = [], []
    count = 0
    tracemalloc.start()
    t0 = time.perf_counter()
    for _ in range(n_min):
        tracemalloc.reset_peak()
        for blk in blocks(base, minute_s):
            count += len(rx.process(blk))
        peaks.append(tracemalloc.get_traced_memory()[1] / 2**20)
        rss.append(rss_mib())
    wall = time.perf_counter() - t0
    tracemalloc.stop()
    return {
        "minutes": n_min * minute_s / 60.0,
        "estimates": count,
        "wall_s": round(wall, 1),
        "tracemalloc_peak_mib_per_minute": [round(p, 2) for p in peaks],
        "rss_mib_per_minute": [round(r, 1) for r in rss],
        "first_minute_peak_mib": round(peaks[0], 2),
        "last_minute_peak_mib": round(peaks[-1], 2),
        "first_minute_rss_mib": round(rss[0], 1),
        "last_minute_rss_mib": round(rss[-1], 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="input seconds per GCAS run")
    parser.add_argument("--bank-seconds", type=float, default=4.0, help="input seconds, bank")
    parser.add_argument("--repeat", type=int, default=3, help="runs per figure (best kept)")
    parser.add_argument("--stream-minutes", type=float, default=10.0, help="memory stream")
    parser.add_argument("--quick", action="store_true", help="few-second smoke run")
    parser.add_argument(
        "--search", choices=("full", "two-stage"), default="two-stage", help="GCAS search"
    )
    parser.add_argument(
        "--signal-seconds", type=float, default=SIGNAL_S,
        help=f"echo seconds before the input cycles (0 < s <= {MAX_SIGNAL_S})",
    )  # fmt: skip
    args = parser.parse_args()
    if not 0.0 < args.signal_seconds <= MAX_SIGNAL_S:
        parser.error(
            f"--signal-seconds = {args.signal_seconds} is not allowed: must be > 0 and <= "
            f"{MAX_SIGNAL_S} s (the target reaches the transducer soon after); use a shorter echo"
        )
    SEARCH["search"] = args.search
    if args.quick:
        args.seconds, args.bank_seconds, args.repeat, args.stream_minutes = 0.5, 0.5, 1, 0.02
    sch = schedule()
    base = test_signal(sch, min(args.signal_seconds, max(args.seconds, args.bank_seconds)))
    base_s = base.shape[0] / FS_HZ

    runs: dict[tuple[str, int], tuple[Any, float]] = {}
    for m in M_LIST:
        runs["gcas", m] = (lambda m=m: gcas(sch, m), args.seconds)
    runs["detector", 10] = (lambda: gcas(sch, 10, refine=False), args.seconds)
    for m in BANK_M:
        runs["mfbank", m] = (lambda m=m: bank(sch, m), args.bank_seconds)
    for make, _ in (runs["gcas", 10], runs["mfbank", BANK_M[0]]):
        run_once(make, base, 0.2)  # warm-up: load the compiled kernels
    timed = time_interleaved(runs, base, args.repeat)

    print(
        f"{'receiver':<10} {'M':>3} {'seconds':>8} {'wall s':>8} {'cpu s':>8} "
        f"{'x real time':>12} {'est':>6}"
    )
    rows: dict[str, list[dict[str, Any]]] = {"gcas": [], "detector": [], "mfbank": []}
    for (name, m), (_, seconds) in runs.items():
        t = timed[name, m]
        xrt = seconds / t["wall_s"]
        rows[name].append(
            {
                "m_hops": m,
                "wall_s": round(t["wall_s"], 4),
                "cpu_s": round(t["cpu_s"], 4),
                "xrt": round(xrt, 2),
                "xrt_cpu": round(seconds / t["cpu_s"], 2),
            }
        )
        print(
            f"{name:<10} {m:>3} {seconds:>8.1f} {t['wall_s']:>8.3f} {t['cpu_s']:>8.3f} "
            f"{xrt:>12.2f} {int(t['estimates']):>6}"
        )
    gcas_rows, bank_rows = rows["gcas"], rows["mfbank"]
    xrt10 = next(r["xrt"] for r in gcas_rows if r["m_hops"] == 10)
    per_s = [r["wall_s"] / args.seconds for r in gcas_rows]
    flat = max(per_s) / min(per_s)
    cpu_per_s = [r["cpu_s"] / args.seconds for r in gcas_rows]
    flat_cpu = max(cpu_per_s) / min(cpu_per_s)
    gcas_xrt = {r["m_hops"]: r["xrt"] for r in gcas_rows}
    gcas_cpu = {r["m_hops"]: r["xrt_cpu"] for r in gcas_rows}
    for r in bank_rows:
        r["mults_per_sample"] = round(bank(sch, r["m_hops"]).mults_per_sample, 1)
        r["gcas_over_bank"] = round(gcas_xrt[r["m_hops"]] / r["xrt"], 2)
        r["gcas_over_bank_cpu"] = round(gcas_cpu[r["m_hops"]] / r["xrt_cpu"], 2)
    bank10 = next(r["xrt"] for r in bank_rows if r["m_hops"] == 10)
    bank_ratio = xrt10 / bank10
    # Refinement's own cost: GCAS at M = 10 with it, less the detector alone, per estimate.
    n_est = max(int(timed["gcas", 10]["estimates"]), 1)
    refine_cpu_us = (timed["gcas", 10]["cpu_s"] - timed["detector", 10]["cpu_s"]) / n_est * 1e6
    refine_wall_us = (timed["gcas", 10]["wall_s"] - timed["detector", 10]["wall_s"]) / n_est * 1e6
    detector_xrt = rows["detector"][0]["xrt"]
    own_s, own_total_s, own_n, kernel_s = refiner_cpu(sch, base, args.seconds)
    own_us = own_s / max(own_n, 1) * 1e6
    kernel_us = {name: s / max(own_n, 1) * 1e6 for name, s in kernel_s.items()}
    print(
        f"refinement: {refine_cpu_us:.0f} us CPU ({refine_wall_us:.0f} us wall) per estimate, "
        f"{n_est} estimates; of it {own_us:.0f} us CPU inside the refiner's calls "
        f"({100 * own_s / own_total_s:.0f}% of that run's CPU); detector alone "
        f"{detector_xrt:.1f}x real time"
    )
    print(
        f"  refinement's compiled kernels: {sum(kernel_us.values()):.0f} us CPU per estimate ("
        + ", ".join(f"{name} {us:.0f}" for name, us in kernel_us.items())
        + ")"
    )

    mem = stream_memory(sch, base, args.stream_minutes)
    print(
        f"memory over {mem['minutes']:.2f} min ({mem['wall_s']} s wall): tracemalloc peak "
        f"{mem['first_minute_peak_mib']} MiB first minute, {mem['last_minute_peak_mib']} MiB "
        f"last; RSS {mem['first_minute_rss_mib']} -> {mem['last_minute_rss_mib']} MiB"
    )
    growth = mem["last_minute_peak_mib"] / max(mem["first_minute_peak_mib"], 1e-9)
    print(
        f"GCAS M=10: {xrt10:.1f}x real time (target {TARGET_XRT:.0f}x); time max/min over M = "
        f"{flat:.2f} (CPU {flat_cpu:.2f}; target <= {TARGET_FLAT}); bank M=10 {bank10:.2f}x "
        f"real time, GCAS {bank_ratio:.1f}x faster (target >= {TARGET_BANK:.0f}x)"
    )
    print(
        json.dumps(
            {
                "benchmark": "gcas",
                "quick": bool(args.quick),
                "search": args.search,
                "preset": "att",
                "family": "random-cyclic",
                "fs_hz": FS_HZ,
                "n_doppler": N_DOPPLER,
                "block": BLOCK,
                "repeat": args.repeat,
                "timing": "interleaved, best of repeat",
                "seconds": args.seconds,
                "signal_seconds": round(base_s, 3),
                "echo_jumps_per_run": max(0, math.ceil(args.seconds / base_s - 1e-9) - 1),
                "gcas_xrt_m10": xrt10,
                "target_xrt": TARGET_XRT,
                "xrt_ratio": round(xrt10 / TARGET_XRT, 3),
                "gcas_by_m": gcas_rows,
                "m_flatness": round(flat, 3),
                "m_flatness_cpu": round(flat_cpu, 3),
                "target_m_flatness": TARGET_FLAT,
                "m_flatness_ratio": round(TARGET_FLAT / flat, 3),
                "bank_by_m": bank_rows,
                "gcas_mults_per_sample": gcas_mults_per_sample(len(sch.tones_hz), N_DOPPLER),
                "detector_xrt_m10": detector_xrt,
                "refine_cpu_us_per_estimate": round(refine_cpu_us, 1),
                "refine_wall_us_per_estimate": round(refine_wall_us, 1),
                "refiner_own_cpu_us_per_estimate": round(own_us, 1),
                "refiner_own_cpu_share": round(own_s / own_total_s, 3),
                "refine_kernel_cpu_us_per_estimate": {n: round(u, 1) for n, u in kernel_us.items()},
                "bank_xrt_m10": bank10,
                "gcas_over_bank_m10": round(bank_ratio, 2),
                "gcas_over_bank_by_m": {r["m_hops"]: r["gcas_over_bank"] for r in bank_rows},
                "target_gcas_over_bank": TARGET_BANK,
                "bank_ratio": round(bank_ratio / TARGET_BANK, 3),
                "memory": mem,
                "memory_last_over_first": round(growth, 3),
            }
        )
    )


if __name__ == "__main__":
    main()
