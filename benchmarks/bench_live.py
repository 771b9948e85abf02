"""The live pipeline at the tank-board rate: capture plus GCAS, in real time, on one host.

Setup: the simulated board firmware runs in a separate process (this file with
``--serve-board``), real-time paced, on a pseudo-terminal, so only the host's CPU is counted.
Its world returns a real echo: ADC channel 0 is the DAC output delayed by
:data:`ECHO_DELAY_SAMPLES` (a stationary target at ``c·delay/(2 fs)`` ≈ 3 m) at
:data:`ECHO_GAIN`, plus seeded white noise; ADC channel 1 monitors the DAC drive. The DAC is
fed by :class:`~hil.signals.synthesis.BlockSynthesizer` from the ``tank-board`` preset
(random cyclic code, 1 MS/s, 2 ADC channels int16). The host process runs the
:class:`~hil.devices.board.Board` driver (reader and writer threads), the capture loop and
:class:`~hil.acquisition.feed.ReceiverFeed` with GCAS on channel 0. The loop is the one of
``hil tank-run`` (:class:`~hil.acquisition.capture.CaptureLoop`): it waits until
the ring holds the receiver's next decision index (no estimate can come out earlier) or one
block, then feeds everything the ring holds up to one block; with ``--every-block`` it feeds every
``--min-block-ms`` instead (more calls, the same estimates). The setup's objects are kept
out of the garbage collector's full passes (:class:`~hil.acquisition.HeapFreeze`), as in
``hil tank-run``.

Figures (over the ``--seconds`` of streaming, default 30):

- host CPU in cores: ``getrusage(RUSAGE_SELF)`` user+system over wall (all host threads);
  capture plus GCAS (the board's reader thread and the main thread), the main thread's
  share (capture loop + GCAS, ``time.thread_time``) and GCAS alone;
- keeping up: samples captured and processed against the board time elapsed, the ring's
  zero-filled (missing) samples, the gap detector's lost samples, the backlog (captured but
  not yet processed) at the end and its maximum during the run;
- the feed call (capture read + GCAS) per block: wall time (median, p99, max) and the main
  thread's CPU time (p99, max); a wall time far above the CPU time is time spent waiting
  for a core or the GIL (board threads, the simulated board's process), not computing;
- estimate latency, per estimate: wall time when ``feed`` returned it minus wall time when its
  boundary's sample (board index ``origin + t_s·fs``) was stored in the ring (stamped by the
  board's reader thread, so waiting and backlog in the capture loop count); median, 99th
  percentile and max, in hops, and how many estimates took longer than one hop;
- its two parts: waiting, from the boundary's arrival until the samples of the block that
  emitted the estimate were seen (the receiver's look-ahead past the boundary, about half a
  hop for GCAS, plus any stall of the stream meanwhile), and the feed call itself; both also
  for the estimates that took longer than one hop, and how many waited more than a hop
  before the feed call began (late whatever the receiver costs); finer, the wait as the
  stream delivering the look-ahead plus the loop waking up, and the feed call's time off the
  CPU (waiting for a core or the GIL);
- stream lateness: when each block was stored in the ring, against the board's clock on the
  host's time axis (the SYNC fit moved to its earliest pair): a stall anywhere upstream of
  the capture loop (simulated board, pty, reader thread) shows here;
- estimates per second and how many are at the echo's range;
- the host's resident-set growth while streaming (a page fault in the live path shows here);
- what else held the CPUs: the machine's stalls, seen by one real-time stall probe per CPU
  (``benchmarks/machine_stalls.py``; count, longest, steal time), and the
  stand-in board's stalls (gaps over :data:`STANDIN_STALL_S` between its 1 ms captures);
  how many estimates each touched (the stall overlaps the time from the boundary's arrival
  to the estimate), and the latency over the estimates that neither touched.

Targets: host CPU < 0.5 core, latency <= 1 hop (max over all estimates), keeps up (no
missing samples, no DAC underrun, backlog when the last block is done at most
:data:`KEEP_UP_BACKLOG_S`).
Run: ``python benchmarks/bench_live.py [--seconds 30] [--min-block-ms 1] [--every-block]
[--profile] [--no-stall-probes] [--quick] [--dump TIMES.npz]``; ``--machine-only`` runs the
stall probes alone for ``--seconds`` (what the machine takes away from any pipeline);
``--dump`` also saves the per-estimate and per-block times for analysis. The last stdout
line is one JSON object.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from hil.estimation.base import Receiver
    from hil.signals.schedule import HopSchedule
    from hil.signals.synthesis import BlockSynthesizer

FS_HZ = 1_000_000
ADC_CHANNELS = 2
ECHO_DELAY_SAMPLES = 4000  # 4 ms two-way: a stationary target at ~2.96 m
ECHO_GAIN = 0.1  # linear, of the DAC output
NOISE_RMS = 0.02  # full-scale units, white, on the echo channel
DAC_AMPLITUDE = 0.5  # full scale
INT16_SCALE = 1.0 / 32768.0
MAX_SPEED_MPS = 2.0  # the tank-board preset's Doppler span; includes the stationary echo
MAX_RANGE_M = 20.0
M_HOPS = 10
RING_SECONDS = 8.0
MAX_BLOCK_S = 0.005  # longest block per receiver call: one hop, so a catch-up emits early

TARGET_CPU_CORES = 0.5
TARGET_LATENCY_HOPS = 1.0
KEEP_UP_BACKLOG_S = 0.1
#: Gap between two captures of the simulated board (it captures every 1 ms) that counts as
#: a stall of the stand-in, s.
STANDIN_STALL_S = 0.003


# --------------------------------------------------------------------------- board process
class EchoWorld:
    """Board world: ADC 0 = delayed, attenuated DAC 0 plus white noise; ADC 1 = DAC 0.

    ``dac_block`` (n, dac_channels) full scale in; (n, 2) full scale out. The noise is seeded
    once; the delay line is :class:`sim_devices.board.LoopbackWorld`.

    It also times the stand-in board: the board calls its world whenever it captures, once
    per 1 ms tick, so a gap of more than :data:`STANDIN_STALL_S` between two calls is a
    stall of the simulated board's pump (``stalls``: (start, end) monotonic s).
    """

    def __init__(self, delay_samples: int, gain: float, noise_rms: float, seed: int = 7) -> None:
        from sim_devices.board import LoopbackWorld

        self._echo = LoopbackWorld(delay_samples, gain)
        self._noise_rms = noise_rms
        self._rng = np.random.default_rng(seed)
        self._last_call: float | None = None
        self.stalls: list[tuple[float, float]] = []

    def reset(self) -> None:
        """A new stream: empty delay line."""
        self._echo.reset()

    def __call__(self, dac_block: npt.NDArray[np.float64], first_sample: int, /) -> Any:
        now = time.monotonic()
        if self._last_call is not None and now - self._last_call > STANDIN_STALL_S:
            self.stalls.append((self._last_call, now))
        self._last_call = now
        dac = dac_block[:, :1]
        out = np.empty((dac.shape[0], 2))
        out[:, 0] = self._echo(dac, first_sample)[:, 0]
        out[:, 0] += self._rng.normal(0.0, self._noise_rms, dac.shape[0])
        out[:, 1] = dac[:, 0]
        return out


def serve_board(delay: int, gain: float, noise_rms: float, stalls_out: str) -> None:
    """Serve the simulated board on a pty until SIGTERM; the pty path on stdout's first line.
    At the end its pump's stalls (:class:`EchoWorld`) go to ``stalls_out`` as JSON pairs."""
    from sim_devices.board import SimulatedBoardOnPty

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    world = EchoWorld(delay, gain, noise_rms)
    with SimulatedBoardOnPty(world=world) as board:
        # A stand-in for hardware, which has no garbage collector: its setup's objects stay
        # out of the collector's full passes (20 ms each here), as the host's do.
        gc.collect()
        gc.freeze()
        print(board.port_name, flush=True)
        while not stop.wait(0.2):
            pass
    with open(stalls_out, "w") as fh:
        json.dump(world.stalls, fh)


# --------------------------------------------------------------------------- host side
def _host_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _rss_bytes() -> float:
    """This process's resident memory, bytes (Linux /proc; NaN elsewhere)."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return float("nan")


def _process_cpu_s(pid: int, stat: str = "/proc/{pid}/stat") -> float:
    """User+system CPU seconds of process ``pid`` (Linux /proc; NaN elsewhere)."""
    try:
        with open(stat.format(pid=pid)) as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    # Fields 14 and 15 of stat(5) (utime, stime), counted after the ")" that ends comm.
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _thread_cpu_s(native_id: int | None) -> float:
    """User+system CPU seconds of this process's thread ``native_id`` (Linux /proc; NaN
    elsewhere or when the thread is gone)."""
    if native_id is None:
        return float("nan")
    return _process_cpu_s(native_id, "/proc/self/task/{pid}/stat")


def _board_thread_ids(board: Any) -> dict[str, int | None]:
    """Native thread ids of the board driver's reader and writer threads."""
    return {
        name: getattr(getattr(board, attr, None), "native_id", None)
        for name, attr in (("reader", "_reader"), ("writer", "_writer"))
    }


def _ms(x: npt.NDArray[np.float64], percentile: float) -> float | None:
    """A percentile of ``x`` (s) in ms, rounded; None when ``x`` holds no finite value."""
    x = x[np.isfinite(x)]
    return round(float(np.percentile(x, percentile)) * 1e3, 3) if x.size else None


def _stream_lateness_s(board: Any, arrivals: Arrivals) -> npt.NDArray[np.float64]:
    """How late each block's newest sample was seen, against the board's clock (s).

    The board clock on the host's time axis is the SYNC fit moved down to its earliest pair
    (the fastest delivery seen), so 0 is "as early as the link ever delivered" and a stall
    anywhere upstream of the capture loop (simulated board, pty, reader thread) shows as
    lateness. Empty without SYNC pairs.
    """
    fit = board.clock_fit
    ends, times = arrivals.arrays()
    if fit is None or fit.pairs < 2 or ends.size == 0:
        return np.zeros(0)
    floor = float(np.min(fit.residuals_s()))
    on_time = np.array([fit.host_time(e - 1) for e in ends.tolist()]) + floor
    return times - on_time


@dataclass
class Arrivals:
    """When the ring reached each end index (monotonic s, stamped by the board's reader
    thread as it stores a block): a sample's arrival is the first stamp past it.

    One list of pairs, appended whole, so a reader in another thread never sees an end
    without its time."""

    stamps: list[tuple[int, float]] = field(default_factory=list)

    def add(self, end_index: int, t: float) -> None:
        self.stamps.append((end_index, t))

    def arrays(self) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
        """End indices and their times, as recorded so far."""
        stamps = list(self.stamps)
        ends = np.array([e for e, _ in stamps], dtype=np.int64)
        return ends, np.array([t for _, t in stamps], dtype=np.float64)

    def time_of(self, index: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
        """Arrival time of each board sample ``index`` (NaN if it never arrived)."""
        ends, times = self.arrays()
        k = np.searchsorted(ends, index, side="right")  # first block whose end is past index
        out = np.full(index.shape, np.nan)
        ok = k < ends.shape[0]
        out[ok] = times[k[ok]]
        return out


@dataclass(frozen=True)
class LiveDesign:
    """The signal and the receiver of the live run: the ``tank-board`` preset, random cyclic.

    ``schedule``: the hop schedule (``schedule.hop_s``, s); ``receiver``: GCAS on ADC channel
    0, fed int16 counts scaled by :data:`INT16_SCALE` to full scale; ``synth``: the DAC's
    blocks at :data:`DAC_AMPLITUDE` full scale; ``echo_range_m``: the range of the stand-in's
    echo (:data:`ECHO_DELAY_SAMPLES`), m.
    """

    schedule: HopSchedule
    receiver: Receiver
    synth: BlockSynthesizer
    echo_range_m: float


def tank_board_design() -> LiveDesign:
    """Build the run's signal and receiver as ``hil tank-run`` builds its own."""
    from hil.recording.records import ReceiverSetup
    from hil.recording.replay import build_receiver
    from hil.signals.presets import check_design, get_preset
    from hil.signals.synthesis import BlockSynthesizer

    spec = get_preset("tank-board").spec("random-cyclic")
    schedule = check_design(spec)
    assert spec.fs_hz == FS_HZ
    c = spec.sound_speed_mps
    setup = ReceiverSetup(
        "gcas",
        {
            "sound_speed_mps": c,
            "max_speed_mps": MAX_SPEED_MPS,
            "max_range_m": MAX_RANGE_M,
            "m_hops": M_HOPS,
        },
        channel=0,
        scale=INT16_SCALE,
    )
    return LiveDesign(
        schedule=schedule,
        receiver=build_receiver(setup, schedule, FS_HZ),
        synth=BlockSynthesizer(schedule, FS_HZ, amplitude=DAC_AMPLITUDE),
        echo_range_m=c * ECHO_DELAY_SAMPLES / FS_HZ / 2.0,
    )


class StandinBoard:
    """The simulated board in its own process (this file with ``--serve-board``), real-time
    paced on a pseudo-terminal, so the host's CPU figures hold the host alone.

    A context manager: inside it the process runs and :attr:`port` names its pty; on exit the
    process is stopped (SIGTERM; killed if it has not ended within 10 s) and :attr:`stalls`
    holds its pump's stalls (:class:`EchoWorld`), shape (n, 2), (start, end) monotonic s.
    """

    def __init__(self) -> None:
        self.port = ""
        self.stalls: npt.NDArray[np.float64] = np.zeros((0, 2))
        self._server: subprocess.Popen[str] | None = None
        self._stalls_path = ""

    def __enter__(self) -> StandinBoard:
        fd, self._stalls_path = tempfile.mkstemp(prefix="standin-stalls-", suffix=".json")
        os.close(fd)
        try:
            self._server = subprocess.Popen(
                [
                    sys.executable,
                    __file__,
                    "--serve-board",
                    str(ECHO_DELAY_SAMPLES),
                    str(ECHO_GAIN),
                    str(NOISE_RMS),
                    self._stalls_path,
                ],
                stdout=subprocess.PIPE,
                text=True,
            )
            assert self._server.stdout is not None
            self.port = self._server.stdout.readline().strip()
        except BaseException:
            self._stop()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop()

    def cpu_s(self) -> float:
        """The process's user+system CPU time so far, s (NaN once stopped or off Linux)."""
        return _process_cpu_s(self._server.pid) if self._server is not None else float("nan")

    def _stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.terminate()
            try:
                server.wait(timeout=10)
            except subprocess.TimeoutExpired:
                server.kill()
                server.wait()
            if server.stdout is not None:
                server.stdout.close()
        self.stalls = _standin_stalls(self._stalls_path)
        os.unlink(self._stalls_path)


def run_live(
    seconds: float,
    min_block_s: float,
    profile: bool = False,
    every_block: bool = False,
    stall_probes: bool = True,
    dump: str | None = None,
) -> dict[str, Any]:
    """Stream ``seconds`` through Board + capture loop + GCAS; the figures (module docstring)."""
    from machine_stalls import StallProbes, overlapping, steal_s

    from hil.acquisition import HeapFreeze
    from hil.acquisition.capture import CapturedBlock, CaptureLoop
    from hil.acquisition.feed import ReceiverFeed
    from hil.devices.board import Board
    from hil.devices.board_settings import BoardSettings

    design = tank_board_design()
    schedule, echo_range_m = design.schedule, design.echo_range_m
    probes = StallProbes() if stall_probes else None
    machine = None
    profiler: Any = None
    if profile:
        import cProfile

        profiler = cProfile.Profile()
    try:
        if probes is not None:
            probes.start()  # before the board: their start-up must not land in the stream
        with StandinBoard() as standin:
            settings = BoardSettings(
                sample_rate_hz=FS_HZ, dac_channels=1, adc_channels=ADC_CHANNELS
            )
            with Board(standin.port, settings=settings, ring_seconds=RING_SECONDS) as board:
                board.configure()
                ring = board.ring
                assert ring is not None
                arrivals = Arrivals()
                # Stamped by the board's reader thread as each block is stored.
                ring.on_write = lambda end: arrivals.add(end, time.monotonic())
                start = board.start(design.synth.blocks(1 << 15))
                # The DAC plays schedule sample 0 at board index `start`, so that is the
                # receiver's sample 0 (the echo delay is the target's range, not latency).
                feed = ReceiverFeed(design.receiver, origin=start, channel=0, scale=INT16_SCALE)
                n_total = int(round(seconds * FS_HZ))
                end_target = start + n_total
                min_block = max(1, int(round(min_block_s * FS_HZ)))
                max_block = int(round(MAX_BLOCK_S * FS_HZ))
                est_boundary: list[int] = []
                est_emit: list[float] = []
                est_seen: list[float] = []  # when the samples of the emitting block were seen
                est_wanted: list[int] = []  # the board index the loop waited for before it
                est_cpu: list[float] = []  # main-thread CPU time of the emitting feed call
                est_range: list[float] = []
                est_speed: list[float] = []
                feed_wall: list[float] = []
                feed_cpu: list[float] = []
                block_times: list[tuple[float, float]] = []  # (wait began, samples seen)

                def observe(block: CapturedBlock) -> None:
                    feed_cpu.append(block.feed_cpu_s)
                    feed_wall.append(block.fed_at - block.seen_at)
                    block_times.append((block.wait_began, block.seen_at))
                    for e in block.estimates:
                        est_boundary.append(start + round(e.t_s * FS_HZ))
                        est_emit.append(block.fed_at)
                        est_seen.append(block.seen_at)
                        est_wanted.append(block.wanted_index)
                        est_cpu.append(block.feed_cpu_s)
                        est_range.append(e.range_m)
                        est_speed.append(e.speed_mps)

                # The capture loop of hil tank-run: it waits, as the run does, for the receiver's
                # next decision (nothing can come out before it) or one block when no decision
                # comes within it; with --every-block for every min_block samples instead.
                capture = CaptureLoop(
                    board,
                    start,
                    max_block,
                    feed=feed,
                    on_fed=observe,
                    every=min_block if every_block else None,
                )
                heap = HeapFreeze()
                heap.start()  # as the tank run does: no 75 ms full collection mid-stream
                if profiler is not None:
                    profiler.enable()
                threads = _board_thread_ids(board)
                thread0 = {name: _thread_cpu_s(tid) for name, tid in threads.items()}
                rss0 = _rss_bytes()
                steal0 = steal_s(probes.cpus) if probes is not None else float("nan")
                wall0, cpu0, main0 = time.monotonic(), _host_cpu_s(), time.thread_time()
                server_cpu0 = standin.cpu_s()
                while capture.next_index < end_target:
                    if capture.step(2.0, limit=end_target) is None:
                        raise RuntimeError(
                            f"no samples past board index {capture.next_index} for 2 s: the board"
                            " stalled"
                        )
                next_index = capture.next_index
                blocks = len(block_times)
                gcas_cpu = float(sum(feed_cpu))
                max_backlog = capture.backlog_max
                # A long wait means the samples came late (board process or reader thread
                # starved), not that the receiver was slow.
                wait_max = max((seen - began for began, seen in block_times), default=0.0)
                wall = time.monotonic() - wall0
                steal = (steal_s(probes.cpus) if probes is not None else float("nan")) - steal0
                rss_growth = _rss_bytes() - rss0
                held_end = ring.end_index or start
                cpu = _host_cpu_s() - cpu0
                main_cpu = time.thread_time() - main0
                server_cpu = standin.cpu_s() - server_cpu0
                thread_cpu = {
                    name: _thread_cpu_s(tid) - thread0[name] for name, tid in threads.items()
                }
                heap.stop()
                if probes is not None:
                    # The machine while streaming (not while the board and probes started).
                    machine = probes.stop().between(wall0, wall0 + wall, steal)
                if profiler is not None:
                    profiler.disable()
                board_now = board.board_index_now()
                missing = ring.missing
                gap_samples = board.gaps.gap_samples
                underruns = board.last_status.dac_underruns if board.last_status else -1
                overruns = board.last_status.adc_overruns if board.last_status else -1
                annotations = len(board.annotations.all())
                stream_late_s = _stream_lateness_s(board, arrivals)
            flushed = len(feed.finish())
    finally:
        if probes is not None:
            probes.close()  # after stop() nothing is left; on an error, kill them
    standin_stalls = standin.stalls

    boundary = np.asarray(est_boundary, dtype=np.int64)
    emit = np.asarray(est_emit)
    boundary_seen = arrivals.time_of(boundary)
    lat_s = emit - boundary_seen
    # The two parts of each latency: waiting for the samples past the boundary that the
    # receiver needs (its look-ahead, plus any stall of the stream), then the feed call.
    wait_s = np.asarray(est_seen) - boundary_seen
    proc_s = emit - np.asarray(est_seen)
    # Finer: the wait is the stream delivering the look-ahead (the arrival of the last sample
    # the loop waited for) plus the loop waking up; the feed call is CPU plus time off the
    # CPU (waiting for a core or the GIL).
    wanted = np.asarray(est_wanted, dtype=np.int64)
    wanted_seen = arrivals.time_of(wanted - 1)
    stream_s = wanted_seen - boundary_seen
    wake_s = np.asarray(est_seen) - wanted_seen
    off_cpu_s = proc_s - np.asarray(est_cpu)
    over = lat_s > schedule.hop_s
    hop_s = schedule.hop_s
    # Estimates whose time from boundary to estimate overlapped a machine stall: the
    # machine (hypervisor, kernel) held a CPU away from every thread meanwhile.
    if machine is not None:
        in_stall = machine.overlapping(boundary_seen, emit)
    else:
        in_stall = np.zeros(lat_s.shape, dtype=bool)
    # ... and those during which the stand-in board's pump stalled (it shares the host's
    # CPUs; hardware would not).
    in_standin = overlapping(standin_stalls[:, 0], standin_stalls[:, 1], boundary_seen, emit)
    standin_run = standin_stalls[
        (standin_stalls[:, 1] >= wall0) & (standin_stalls[:, 0] <= wall0 + wall)
    ]
    standin_d = np.minimum(standin_run[:, 1], wall0 + wall) - np.maximum(standin_run[:, 0], wall0)
    clear = ~in_stall & ~in_standin
    if dump is not None:
        arr_index, arr_time = arrivals.arrays()
        np.savez(
            dump,
            boundary=boundary,
            boundary_seen=boundary_seen,
            wanted=wanted,
            wanted_seen=wanted_seen,
            feed_cpu_of_estimate=np.asarray(est_cpu),
            seen=np.asarray(est_seen),
            emit=emit,
            in_machine_stall=in_stall,
            in_standin_stall=in_standin,
            arrival_end_index=arr_index,
            arrival_time=arr_time,
            feed_wall=np.asarray(feed_wall),
            block_times=np.asarray(block_times),
            feed_cpu=np.asarray(feed_cpu),
            start=start,
            wall0=wall0,
        )

    def hops(x: npt.NDArray[np.float64], percentile: float) -> float:
        x = x[np.isfinite(x)]
        if x.size == 0:
            return float("nan")
        return round(float(np.percentile(x, percentile)) / hop_s, 3)

    ranges = np.asarray(est_range)
    on_target = int(np.count_nonzero(np.abs(ranges - echo_range_m) < 0.1))
    board_elapsed = board_now - start
    processed = next_index - start
    final_backlog = held_end - next_index
    # Kept up: nothing lost, and when the last block was done the receiver was behind the
    # capture by less than KEEP_UP_BACKLOG_S (a transient stall may leave a backlog, a
    # receiver slower than real time leaves one that grows with the run).
    keeps_up = bool(
        missing == 0
        and gap_samples == 0
        and overruns <= 0
        and underruns == 0  # the transmitter was fed in time too
        and processed == n_total
        and final_backlog <= KEEP_UP_BACKLOG_S * FS_HZ
    )
    cores = cpu / wall
    result: dict[str, Any] = {
        "seconds": seconds,
        "wall_s": round(wall, 3),
        "blocks": blocks,
        "mean_block_samples": round(processed / max(blocks, 1), 1),
        "host_cpu_cores": round(cores, 3),
        "main_thread_cores": round(main_cpu / wall, 3),
        "gcas_cores": round(gcas_cpu / wall, 3),
        "board_threads_cores": round((cpu - main_cpu) / wall, 3),
        "reader_thread_cores": round(thread_cpu["reader"] / wall, 3),
        # What the CPU target names, capture plus GCAS: the reader thread and the
        # main thread (capture loop + GCAS); the host figure, which the target is checked
        # on, also holds the DAC writer (transmission) and everything else in the process.
        "capture_gcas_cores": round((thread_cpu["reader"] + main_cpu) / wall, 3),
        "writer_thread_cores": round(thread_cpu["writer"] / wall, 3),
        "sim_board_process_cores": round(server_cpu / wall, 3),
        "host_rss_growth_mib": round(rss_growth / 2**20, 2),
        "feed_call_median_ms": round(float(np.median(feed_wall)) * 1e3, 3),
        "feed_call_p99_ms": round(float(np.percentile(feed_wall, 99)) * 1e3, 3),
        "feed_call_max_ms": round(float(np.max(feed_wall)) * 1e3, 3),
        "feed_call_cpu_p99_ms": round(float(np.percentile(feed_cpu, 99)) * 1e3, 3),
        "feed_call_cpu_max_ms": round(float(np.max(feed_cpu)) * 1e3, 3),
        "wait_for_samples_max_ms": round(wait_max * 1e3, 3),
        "board_samples_elapsed": int(board_elapsed),
        "samples_processed": int(processed),
        "samples_captured": int(held_end - start),
        "ring_missing_samples": int(missing),
        "gap_samples": int(gap_samples),
        "dac_underruns": int(underruns),
        "adc_overruns": int(overruns),
        "annotations": annotations,
        "final_backlog_samples": int(final_backlog),
        "max_backlog_samples": int(max_backlog),
        "keeps_up": keeps_up,
        "estimates": len(est_boundary),
        "estimates_flushed": flushed,
        "estimates_per_s": round(len(est_boundary) / wall, 1),
        "estimates_on_target": on_target,
        "echo_range_m": round(echo_range_m, 4),
        "median_range_m": round(float(np.median(ranges)), 4) if ranges.size else None,
        "median_speed_mps": round(float(np.median(est_speed)), 4) if est_speed else None,
        "hop_s": hop_s,
        "latency_median_hops": hops(lat_s, 50),
        "latency_p99_hops": hops(lat_s, 99),
        "latency_max_hops": hops(lat_s, 100),
        "estimates_over_1_hop": int(np.count_nonzero(over)),
        "latency_wait_median_ms": _ms(wait_s, 50),
        "latency_wait_max_ms": _ms(wait_s, 100),
        "latency_processing_median_ms": _ms(proc_s, 50),
        "latency_processing_max_ms": _ms(proc_s, 100),
        # Estimates already a hop late when the feed call began: the look-ahead and the
        # stream alone took longer, so GCAS could not have met the target however fast it ran.
        "wait_over_1_hop": int(np.count_nonzero(wait_s > hop_s)),
        "over_1_hop_wait_median_ms": _ms(wait_s[over], 50),
        "over_1_hop_processing_median_ms": _ms(proc_s[over], 50),
        "lookahead_median_ms": _ms((wanted - boundary) / FS_HZ, 50),
        "stream_median_ms": _ms(stream_s, 50),
        "over_1_hop_stream_median_ms": _ms(stream_s[over], 50),
        "wake_median_ms": _ms(wake_s, 50),
        "over_1_hop_wake_median_ms": _ms(wake_s[over], 50),
        "feed_off_cpu_median_ms": _ms(off_cpu_s, 50),
        "over_1_hop_feed_off_cpu_median_ms": _ms(off_cpu_s[over], 50),
        "stream_lateness_median_ms": _ms(stream_late_s, 50),
        "stream_lateness_p99_ms": _ms(stream_late_s, 99),
        "stream_lateness_max_ms": _ms(stream_late_s, 100),
        **machine_figures(machine),
        **(
            {
                "estimates_in_machine_stall": int(np.count_nonzero(in_stall)),
                "over_1_hop_in_machine_stall": int(np.count_nonzero(over & in_stall)),
            }
            if machine is not None
            else {}
        ),
        "standin_stalls": int(standin_d.size),
        "standin_stall_max_ms": round(float(standin_d.max()) * 1e3, 3) if standin_d.size else 0.0,
        "estimates_in_standin_stall": int(np.count_nonzero(in_standin)),
        "over_1_hop_in_standin_stall": int(np.count_nonzero(over & in_standin)),
        "over_1_hop_outside_stalls": int(np.count_nonzero(over & clear)),
        "latency_p99_outside_stalls_hops": hops(lat_s[clear], 99),
        "latency_max_outside_stalls_hops": hops(lat_s[clear], 100),
        "target_cpu_cores": TARGET_CPU_CORES,
        "cpu_ratio": round(TARGET_CPU_CORES / max(cores, 1e-9), 2),
        "target_latency_hops": TARGET_LATENCY_HOPS,
    }
    max_lat = result["latency_max_hops"]
    result["latency_ratio"] = round(TARGET_LATENCY_HOPS / max_lat, 2) if max_lat > 0 else None
    result["meets_targets"] = bool(
        keeps_up and cores < TARGET_CPU_CORES and max_lat <= TARGET_LATENCY_HOPS
    )
    if profiler is not None:
        import pstats

        pstats.Stats(profiler, stream=sys.stderr).sort_stats("cumulative").print_stats(30)
    return result


def _standin_stalls(path: str) -> npt.NDArray[np.float64]:
    """The stand-in board's stalls, shape (n, 2) (start, end monotonic s), from the file
    its process wrote at exit; none if it wrote nothing (it failed: its error is above)."""
    try:
        with open(path) as fh:
            return np.array(json.load(fh), dtype=np.float64).reshape(-1, 2)
    except (OSError, ValueError):
        return np.zeros((0, 2))


def machine_figures(machine: Any) -> dict[str, Any]:
    """The stall probes' summary, keys prefixed ``machine_`` (empty without probes)."""
    if machine is None:
        return {}
    return {f"machine_{k}": v for k, v in machine.summary().items()}


def machine_rows(r: dict[str, Any]) -> list[tuple[str, str]]:
    """Table rows for the stall probes' figures (none without probes)."""
    if "machine_stalls" not in r:
        return []
    kind = "real-time" if r["machine_probe_realtime"] else "ordinary (no real-time priority)"
    return [
        (
            "machine stalls",
            f"{r['machine_stalls']} over 1 ms on CPUs {r['machine_probe_cpus']}, longest"
            f" {r['machine_stall_max_ms']} ms, {r['machine_stalls_over_5ms']} over 5 ms;"
            f" {r['machine_stalled_ms_per_s']} ms/s stalled and"
            f" {r['machine_steal_ms_per_s']} ms/s stolen by the hypervisor per CPU ({kind}"
            " probes)",
        )
    ]


def print_table(r: dict[str, Any]) -> None:
    """The figures as a table on stdout."""
    hop_ms = r["hop_s"] * 1e3
    rows = [
        ("streamed", f"{r['seconds']:.1f} s at 1 MS/s x 2 ch int16 (wall {r['wall_s']:.2f} s)"),
        ("blocks", f"{r['blocks']} (mean {r['mean_block_samples']:.0f} samples)"),
        (
            "host CPU",
            f"{r['host_cpu_cores']:.3f} cores (target < {TARGET_CPU_CORES}; ratio"
            f" {r['cpu_ratio']:.2f})",
        ),
        (
            "  capture + GCAS",
            f"{r['capture_gcas_cores']:.3f} cores (reader thread + main thread; the host"
            " figure is the one checked)",
        ),
        ("  main thread", f"{r['main_thread_cores']:.3f} cores (capture loop + GCAS)"),
        ("  GCAS alone", f"{r['gcas_cores']:.3f} cores"),
        (
            "  board threads",
            f"{r['board_threads_cores']:.3f} cores (reader {r['reader_thread_cores']:.3f},"
            f" writer {r['writer_thread_cores']:.3f})",
        ),
        ("  (sim board)", f"{r['sim_board_process_cores']:.3f} cores, other process, not counted"),
        ("host memory", f"resident set grew {r['host_rss_growth_mib']} MiB while streaming"),
        (
            "feed call",
            f"median {r['feed_call_median_ms']:.2f} ms, p99 {r['feed_call_p99_ms']:.2f} ms,"
            f" max {r['feed_call_max_ms']:.2f} ms wall; CPU p99"
            f" {r['feed_call_cpu_p99_ms']:.2f} ms, max {r['feed_call_cpu_max_ms']:.2f} ms",
        ),
        ("longest wait", f"{r['wait_for_samples_max_ms']:.2f} ms for new samples"),
        (
            "kept up",
            f"{r['keeps_up']}: processed {r['samples_processed']} of"
            f" {r['samples_captured']} captured ({r['board_samples_elapsed']} board samples"
            " elapsed, from the SYNC fit)",
        ),
        ("missing/gaps", f"ring {r['ring_missing_samples']}, gaps {r['gap_samples']} samples"),
        (
            "backlog",
            f"final {r['final_backlog_samples']}, max {r['max_backlog_samples']} samples",
        ),
        ("dac underruns", f"{r['dac_underruns']}, adc overruns {r['adc_overruns']}"),
        (
            "estimates",
            f"{r['estimates']} ({r['estimates_per_s']:.1f}/s), {r['estimates_on_target']} at"
            f" the echo range {r['echo_range_m']:.3f} m (median {r['median_range_m']} m,"
            f" {r['median_speed_mps']} m/s)",
        ),
        (
            "latency",
            f"median {r['latency_median_hops']:.3f}, p99 {r['latency_p99_hops']:.3f},"
            f" max {r['latency_max_hops']:.3f} hops (hop {hop_ms:.1f} ms; target <="
            f" {TARGET_LATENCY_HOPS}); {r['estimates_over_1_hop']} estimates over 1 hop",
        ),
    ]
    rows += [
        (
            "  its parts",
            f"waiting for the look-ahead samples: median {r['latency_wait_median_ms']} ms, max"
            f" {r['latency_wait_max_ms']} ms; feed call: median"
            f" {r['latency_processing_median_ms']} ms, max {r['latency_processing_max_ms']} ms",
        ),
        (
            "  over 1 hop",
            f"median wait {r['over_1_hop_wait_median_ms']} ms, median feed call"
            f" {r['over_1_hop_processing_median_ms']} ms; {r['wait_over_1_hop']} were a hop late"
            " before the feed call began (a receiver taking no time would miss those too)",
        ),
        (
            "  finer, median",
            f"look-ahead {r['lookahead_median_ms']} ms of signal; the stream took"
            f" {r['stream_median_ms']} ms to deliver it ({r['over_1_hop_stream_median_ms']} ms"
            f" over 1 hop), the loop {r['wake_median_ms']} ms to wake"
            f" ({r['over_1_hop_wake_median_ms']}); the feed call spent"
            f" {r['feed_off_cpu_median_ms']} ms off the CPU"
            f" ({r['over_1_hop_feed_off_cpu_median_ms']})",
        ),
        (
            "stream lateness",
            f"median {r['stream_lateness_median_ms']} ms, p99 {r['stream_lateness_p99_ms']} ms,"
            f" max {r['stream_lateness_max_ms']} ms (samples seen after the board clock,"
            " against the fastest delivery)",
        ),
    ]
    rows += machine_rows(r)
    if "estimates_in_machine_stall" in r:
        rows.append(
            (
                "  estimates",
                f"{r['estimates_in_machine_stall']} overlapped a machine stall"
                f" ({r['over_1_hop_in_machine_stall']} of those over 1 hop)",
            )
        )
    rows.append(
        (
            "stand-in stalls",
            f"{r['standin_stalls']} gaps over {STANDIN_STALL_S * 1e3:.0f} ms between the"
            f" simulated board's captures, longest {r['standin_stall_max_ms']} ms;"
            f" {r['estimates_in_standin_stall']} estimates overlapped one"
            f" ({r['over_1_hop_in_standin_stall']} of those over 1 hop)",
        )
    )
    untouched = "no stall of either" if "machine_stalls" in r else "no stand-in stall"
    rows.append(
        (
            "host alone",
            f"estimates {untouched} touched: {r['over_1_hop_outside_stalls']} over 1 hop;"
            f" latency p99 {r['latency_p99_outside_stalls_hops']}, max"
            f" {r['latency_max_outside_stalls_hops']} hops",
        )
    )
    for name, text in rows:
        print(f"{name:<18} {text}")


def run_machine_only(seconds: float) -> dict[str, Any]:
    """Only the stall probes, for ``seconds``, on a machine left otherwise idle: what any
    live pipeline on it would lose."""
    from machine_stalls import StallProbes

    with StallProbes() as probes:
        time.sleep(seconds)
    assert probes.result is not None
    return {"seconds": seconds, "machine_only": True, **machine_figures(probes.result)}


def main() -> None:
    parser = argparse.ArgumentParser(description="live capture + GCAS at the tank-board rate")
    parser.add_argument("--seconds", type=float, default=30.0, help="streaming time, s")
    parser.add_argument("--quick", action="store_true", help="smoke run (1.5 s of streaming)")
    parser.add_argument(
        "--min-block-ms",
        type=float,
        default=1.0,
        help="least new signal per receiver call, ms (default 1)",
    )
    parser.add_argument("--profile", action="store_true", help="cProfile the host to stderr")
    parser.add_argument(
        "--every-block",
        action="store_true",
        help="call the receiver for every new block, not only when it can decide",
    )
    parser.add_argument(
        "--no-stall-probes",
        action="store_true",
        help="do not run the machine stall probes (one small process per CPU)",
    )
    parser.add_argument(
        "--machine-only",
        action="store_true",
        help="run only the stall probes for --seconds: the machine's own stalls",
    )
    parser.add_argument(
        "--dump",
        metavar="NPZ",
        help="also save the per-estimate and per-block times (NumPy .npz) for analysis",
    )
    parser.add_argument("--serve-board", nargs=4, metavar=("DELAY", "GAIN", "NOISE", "OUT"))
    args = parser.parse_args()
    if args.serve_board:
        delay, gain, noise, out = args.serve_board
        serve_board(int(delay), float(gain), float(noise), out)
        return
    seconds = 1.5 if args.quick else args.seconds
    if args.machine_only:
        result = run_machine_only(seconds)
        for name, text in machine_rows(result):
            print(f"{name:<18} {text}")
        print(json.dumps({"benchmark": "bench_live", **result}))
        return
    result = run_live(
        seconds,
        args.min_block_ms / 1e3,
        profile=args.profile,
        every_block=args.every_block,
        stall_probes=not args.no_stall_probes,
        dump=args.dump,
    )
    print_table(result)
    print(json.dumps({"benchmark": "bench_live", **result}))


if __name__ == "__main__":
    main()
