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

Both board implementations are measured side by side: the Python simulated board and the C
reference firmware (``firmware_protocol/c``, built with ``make host``): over the pty as above
(``hil sim-serve board`` vs ``hil sim-serve board --impl c``; the board process's own CPU is
read from ``/proc``), and sans-IO on an injected clock (how many seconds of 1 MS/s x 2
streaming, with DAC data in and ADC data out, one board simulates per second of CPU).
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


def _process_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) used so far by process ``pid`` (Linux /proc)."""
    import os

    with open(f"/proc/{pid}/stat", encoding="ascii") as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _board_server(impl: str) -> subprocess.Popen[str]:
    """The board behind a pty in its own process: first stdout line is the pty path."""
    if impl == "c":
        from sim_devices.board.c_firmware import PTY_SERVER, build

        build()
        command = [str(PTY_SERVER), "--delay", str(LOOPBACK_DELAY)]
    else:
        command = [sys.executable, "-m", "hil.cli.main", "sim-serve", "board"]
        command += ["--delay", str(LOOPBACK_DELAY)]
    return subprocess.Popen(command, stdout=subprocess.PIPE, text=True)


def bench_pty_streaming(
    seconds: float, impl: str = "python"
) -> dict[str, float | int | bool | str]:
    """Stream ``seconds`` over a pty to a board (``impl`` python or c) in another process."""
    from hil.devices.board import Board
    from hil.devices.board_settings import BoardSettings, to_wire_samples
    from hil.signals.presets import get_preset
    from hil.signals.synthesis import BlockSynthesizer
    from hil.signals.waveforms import build_schedule

    server = _board_server(impl)
    try:
        assert server.stdout is not None
        port = server.stdout.readline().strip()
        spec = get_preset("tank-board").spec()
        schedule = build_schedule(spec)
        synth = BlockSynthesizer(schedule, spec.fs_hz, amplitude=0.5)
        n_total = int(seconds * RATE_HZ)
        wall0, cpu0 = time.perf_counter(), _host_cpu_s()
        board_cpu0 = _process_cpu_s(server.pid)
        with Board(port, settings=BoardSettings(sample_rate_hz=RATE_HZ)) as board:
            board.configure()
            first = board.start(synth.blocks(4096))
            complete = board.wait_for_samples(first + n_total, timeout_s=seconds + 30.0)
            wall, cpu = time.perf_counter() - wall0, _host_cpu_s() - cpu0
            board_cpu = _process_cpu_s(server.pid) - board_cpu0
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
        "board": impl,
        "seconds": seconds,
        "complete": bool(complete),
        "lost_samples": int(lost),
        "annotations": annotations,
        "dac_underruns": int(underruns),
        "loopback_equal": loopback_ok,
        "host_cpu_cores": round(cpu / wall, 3),
        "board_cpu_cores": round(board_cpu / wall, 3),
        "target_cpu_cores": PTY_TARGET_CPU_CORES,
        "cpu_ratio": round(PTY_TARGET_CPU_CORES / max(cpu / wall, 1e-9), 2),
    }


def bench_board_step(impl: str, board_seconds: float) -> dict[str, float | str]:
    """Sans-IO: a board (python or c) on an injected clock streaming 1 MS/s x 2 int16.

    Each 1 ms step delivers one DAC_DATA frame of 1000 sample frames and runs one service
    pass (1000 ADC sample frames out). Returns board seconds simulated per CPU second.
    """
    from firmware_protocol.conversations import BOARD, Host
    from firmware_protocol.messages import Configure, DacData, Hello, Start
    from firmware_protocol.schema import SCHEMA_HASH
    from sim_devices.board.c_firmware import CBoardStepper
    from sim_devices.board.stepper import PythonBoardStepper, conversation_spec

    board = dict(BOARD, dac_buffer_samples=1 << 18, formats=["INT16"])
    device = CBoardStepper(board) if impl == "c" else PythonBoardStepper(conversation_spec(board))
    h = Host()
    ms = 1_000_000
    device.step(0, h.frame(Hello(2, 0, SCHEMA_HASH)))
    fmt = SampleFormat.INT16
    device.step(ms, h.frame(Configure(RATE_HZ, 0b11, 0b11, fmt, fmt)))
    start = 1000 + 5000  # 5 ms after CONFIGURE
    rng = np.random.default_rng(3)
    block = rng.integers(-20000, 20000, (1000, 2)).astype(np.int16)
    frames = [
        h.frame(DacData.from_array(start + 1000 * k, 0b11, fmt, block))
        for k in range(int(board_seconds * 1000) + 10)
    ]
    device.step(2 * ms, b"".join(frames[:8]) + h.frame(Start(start)))
    out_bytes = 0
    cpu0 = time.process_time()
    for k in range(int(board_seconds * 1000)):
        out_bytes += len(device.step((3 + k) * ms, frames[8 + k]))
    cpu = time.process_time() - cpu0
    return {
        "board": impl,
        "board_seconds": board_seconds,
        "x_realtime": round(board_seconds / cpu, 2),
        "output_MB": round(out_bytes / 1e6, 2),
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
    steps = {impl: bench_board_step(impl, 0.2 if quick else 2.0) for impl in ("python", "c")}
    for impl, step in steps.items():
        print(
            f"{impl:>6} board sans-IO at 1 MS/s x 2 ch: {step['x_realtime']:.2f} x realtime"
            f" ({step['output_MB']} MB of ADC frames out)"
        )
    ptys = {}
    for impl in ("python", "c"):
        pty = bench_pty_streaming(2.0 if quick else 60.0, impl)
        ptys[impl] = pty
        print(
            f"{impl:>6} board pty {pty['seconds']:.0f} s at 1 MS/s x 2 ch int16: lost"
            f" {pty['lost_samples']} samples, loopback equal {pty['loopback_equal']}, host CPU"
            f" {pty['host_cpu_cores']:.3f} cores vs target < {PTY_TARGET_CPU_CORES} (ratio"
            f" {pty['cpu_ratio']:.2f}), board CPU {pty['board_cpu_cores']:.3f} cores"
        )
    summary = {
        "benchmark": "bench_protocol",
        "decode_MB_s": headline,
        "target_MB_s": TARGET_MB_S,
        "ratio": round(ratio, 2),
        "pty_streaming": ptys["python"],
        "pty_streaming_c": ptys["c"],
        "board_step": steps,
        **results,
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
