"""Decode throughput of the firmware protocol on one core.

Realistic load: ADC data at 1 MS/s x 2 channels int16 (4 MB/s of samples) in frames of
1000 sample frames (4000 bytes of samples, 4 KB frames). The signal is what a continuous
active sonar receiver sees: the direct blast of the own transmitter (a CW at -12 dBFS) plus
noise. Also measured: low-level noise (zero-dense bytes) and digital silence, the worst case
for COBS, and the full path through ``Connection.next_event`` with numpy unpacking.

Target: >= 50 MB/s of wire bytes decoded by ``FrameDecoder`` (realistic load).
Run: ``python benchmarks/bench_protocol.py``. The last line is one JSON object.

Also measured: 60 s of streaming over a real pseudo-terminal at the ``tank-board`` rate
(1 MS/s x 2 channels int16, both directions, real-time paced) between the ``Board`` driver
and the simulated board firmware, which runs in a separate process (``hil sim-serve
board``) so that only the host's CPU is counted (``resource.getrusage`` of this process).
Targets: zero lost samples, loopback content equal to the DAC content delayed, host CPU
under half a core. Run ``--quick`` for a smoke run (2 s of streaming).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from collections.abc import Callable

import numpy as np

from firmware_protocol import (
    NEED_DATA,
    AdcData,
    Configure,
    Connection,
    FrameDecoder,
    Role,
    SampleFormat,
    State,
    encode_frame,
)

TARGET_MB_S = 50.0
FRAMES_PER_MESSAGE = 1000
CHANNELS = 2
RATE_HZ = 1_000_000
SECONDS = 2.0  # of signal per load: 2000 frames, ~8 MB of wire bytes
CHUNK = 65536  # bytes per receive_data call, like a USB bulk read


def _signal(kind: str, rng: np.random.Generator) -> np.ndarray:
    n = int(RATE_HZ * SECONDS)
    if kind == "silence":
        return np.zeros((n, CHANNELS), dtype=np.int16)
    t = np.arange(n) / RATE_HZ
    if kind == "cas":
        blast = 0.25 * 32767 * np.sin(2 * np.pi * 150e3 * t)
        x = blast[:, None] + rng.normal(0, 30, (n, CHANNELS))
    else:  # low-level noise only: most high bytes are 0x00 or 0xff
        x = rng.normal(0, 20, (n, CHANNELS))
    return np.clip(np.round(x), -32768, 32767).astype(np.int16)


def _wire(samples: np.ndarray) -> bytes:
    parts = []
    for k, first in enumerate(range(0, samples.shape[0], FRAMES_PER_MESSAGE)):
        block = samples[first : first + FRAMES_PER_MESSAGE]
        msg = AdcData.from_array(first, 0b11, SampleFormat.INT16, block)
        parts.append(encode_frame(AdcData.TYPE_ID, msg.encode_payload(), k & 0xFFFF))
    return b"".join(parts)


def _best_of(run: Callable[[], int], repeats: int = 3) -> tuple[float, int]:
    best, count = float("inf"), 0
    for _ in range(repeats):
        start = time.perf_counter()
        count = run()
        best = min(best, time.perf_counter() - start)
    return best, count


def bench_frame_decoder(wire: bytes) -> tuple[float, int]:
    """Seconds to split, COBS-decode and CRC-check every frame; and the frame count."""

    def run() -> int:
        decoder = FrameDecoder()
        frames = 0
        for i in range(0, len(wire), CHUNK):
            decoder.feed(wire[i : i + CHUNK])
            while decoder.next_frame() is not None:
                frames += 1
        assert decoder.stats.frame_errors == 0
        return frames

    return _best_of(run)


def bench_connection(wire: bytes) -> tuple[float, int]:
    """Seconds for the full HOST path: frames -> AdcData events -> (frames, 2) int16 arrays."""

    def run() -> int:
        host = Connection(Role.HOST)
        host.state = State.STREAMING  # measure the streaming path only
        host.configuration = Configure(RATE_HZ, 1, 0b11, SampleFormat.INT16, SampleFormat.INT16)
        samples = 0
        for i in range(0, len(wire), CHUNK):
            host.receive_data(wire[i : i + CHUNK])
            while (event := host.next_event()) is not NEED_DATA:
                assert isinstance(event, AdcData)
                samples += event.samples().shape[0]
        return samples

    return _best_of(run)


PTY_TARGET_CPU_CORES = 0.5
LOOPBACK_DELAY = 100  # samples


def _host_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def bench_pty_streaming(seconds: float) -> dict[str, float | int | bool]:
    """Stream ``seconds`` over a pty to a simulated board in another process."""
    from hil.devices.board import Board
    from hil.devices.board_settings import BoardSettings, to_wire_samples
    from hil.signals.presets import get_preset
    from hil.signals.synthesis import BlockSynthesizer
    from hil.signals.waveforms import build_schedule

    server = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hil.cli.main",
            "sim-serve",
            "board",
            "--delay",
            str(LOOPBACK_DELAY),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert server.stdout is not None
        port = server.stdout.readline().strip()
        spec = get_preset("tank-board").spec()
        schedule = build_schedule(spec)
        synth = BlockSynthesizer(schedule, spec.fs_hz, amplitude=0.5)
        n_total = int(seconds * RATE_HZ)
        wall0, cpu0 = time.perf_counter(), _host_cpu_s()
        with Board(port, settings=BoardSettings(sample_rate_hz=RATE_HZ)) as board:
            board.configure()
            first = board.start(synth.blocks(4096))
            complete = board.wait_for_samples(first + n_total, timeout_s=seconds + 30.0)
            wall, cpu = time.perf_counter() - wall0, _host_cpu_s() - cpu0
            # Loopback check on the last second held in the ring: ADC(i) = DAC(i - delay).
            end = first + n_total
            n_check = min(n_total - LOOPBACK_DELAY, RATE_HZ)
            got = board.read(end - n_check, n_check)
            sent = synth.render(end - n_check - LOOPBACK_DELAY - first, n_check)
            expected = to_wire_samples(sent, SampleFormat.INT16, CHANNELS)
            loopback_ok = bool(np.array_equal(got, expected))
            gaps = board.gaps.gap_samples
            received = board.samples_received
            annotations = len(board.annotations.all())
            underruns = board.last_status.dac_underruns if board.last_status else -1
    finally:
        server.terminate()
        server.wait(timeout=10)
    lost = n_total - min(received, n_total) + gaps
    return {
        "seconds": seconds,
        "complete": bool(complete),
        "lost_samples": int(lost),
        "annotations": annotations,
        "dac_underruns": int(underruns),
        "loopback_equal": loopback_ok,
        "host_cpu_cores": round(cpu / wall, 3),
        "target_cpu_cores": PTY_TARGET_CPU_CORES,
        "cpu_ratio": round(PTY_TARGET_CPU_CORES / max(cpu / wall, 1e-9), 2),
    }


def main() -> None:
    global SECONDS
    parser = argparse.ArgumentParser(description="firmware protocol decode throughput")
    parser.add_argument("--quick", action="store_true", help="smoke run on 0.05 s of signal")
    quick = parser.parse_args().quick
    if quick:
        SECONDS = 0.05
    rng = np.random.default_rng(1)
    results: dict[str, float] = {}
    print(
        f"{'load':<12} {'path':<14} {'wire MB':>8} {'MB/s':>8} {'frames/s':>10} {'x realtime':>10}"
    )
    for kind in ("cas", "low_noise", "silence"):
        wire = _wire(_signal(kind, rng))
        realtime_mb_s = len(wire) / SECONDS / 1e6
        for path, bench in (
            ("FrameDecoder", bench_frame_decoder),
            ("Connection", bench_connection),
        ):
            seconds, _count = bench(wire)
            mb_s = len(wire) / seconds / 1e6
            frames_s = len(wire) / (4000 + 30) / seconds
            results[f"{kind}_{path}_MB_s"] = round(mb_s, 1)
            print(
                f"{kind:<12} {path:<14} {len(wire) / 1e6:>8.2f} {mb_s:>8.1f} {frames_s:>10.0f}"
                f" {mb_s / realtime_mb_s:>10.1f}"
            )
    headline = results["cas_FrameDecoder_MB_s"]
    ratio = headline / TARGET_MB_S
    print(
        f"realistic decode {headline:.1f} MB/s vs target {TARGET_MB_S:.0f} MB/s: ratio {ratio:.2f}"
    )
    pty = bench_pty_streaming(2.0 if quick else 60.0)
    print(
        f"pty streaming {pty['seconds']:.0f} s at 1 MS/s x 2 ch int16: lost {pty['lost_samples']}"
        f" samples, loopback equal {pty['loopback_equal']}, host CPU {pty['host_cpu_cores']:.3f}"
        f" cores vs target < {PTY_TARGET_CPU_CORES} (ratio {pty['cpu_ratio']:.2f})"
    )
    summary = {
        "benchmark": "bench_protocol",
        "decode_MB_s": headline,
        "target_MB_s": TARGET_MB_S,
        "ratio": round(ratio, 2),
        "pty_streaming": pty,
        **results,
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
