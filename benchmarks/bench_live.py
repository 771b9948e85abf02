"""The live pipeline at the tank-board rate: capture plus GCAS, in real time, on one host.

Setup: the simulated board firmware runs in a separate process (this file with
``--serve-board``), real-time paced, on a pseudo-terminal, so only the host's CPU is counted.
Its world returns a real echo: ADC channel 0 is the DAC output delayed by
:data:`ECHO_DELAY_SAMPLES` (a stationary target at ``c·delay/(2 fs)`` ≈ 3 m) at
:data:`ECHO_GAIN`, plus seeded white noise; ADC channel 1 monitors the DAC drive. The DAC is
fed by :class:`~hil.signals.synthesis.BlockSynthesizer` from the ``tank-board`` preset
(random cyclic code, 1 MS/s, 2 ADC channels int16). The host process runs the
:class:`~hil.devices.board.Board` driver (reader and writer threads), the capture loop and
:class:`~hil.acquisition.feed.ReceiverFeed` with GCAS on channel 0 (reverberation band off:
the echo is stationary). The loop is the one of ``hil tank-run``
(:class:`~hil.acquisition.capture.CaptureLoop`): it waits until the ring holds the
receiver's next decision index (no estimate can come out earlier) or one block, then feeds
everything the ring holds up to one block; with ``--every-block`` it feeds every
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
    import cProfile

    from machine_stalls import MachineStalls, StallProbes

    from hil.acquisition.capture import CapturedBlock, CaptureLoop
    from hil.devices.board import Board
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
    """Native thread ids of the reader and writer threads of the board driver's link."""
    link = getattr(board, "_link", None)
    return {
        name: getattr(getattr(link, attr, None), "native_id", None)
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
            # The stand-in's echo is stationary: the default reverberation band ("auto")
            # hides targets slower than the Doppler resolution, so it is off here (docs/receiver.md,
            # "Reverberation band"); with it on, no estimate comes out at all.
            "reverb_speed_mps": 0.0,
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


def _standin_stalls(path: str) -> npt.NDArray[np.float64]:
    """The stand-in board's stalls, shape (n, 2) (start, end monotonic s), from the file
    its process wrote at exit; none if it wrote nothing (it failed: its error is above)."""
    try:
        with open(path) as fh:
            return np.array(json.load(fh), dtype=np.float64).reshape(-1, 2)
    except (OSError, ValueError):
        return np.zeros((0, 2))


# --------------------------------------------------------------------------- the measured loop
@dataclass
class EstimateLog:
    """What the measured loop saw: the capture loop's ``on_fed`` observer, one call per fed
    block.

    Per estimate: ``boundary`` (board index of its hop boundary, ``start + t_s·fs``),
    ``emit`` (monotonic s when the feed call returned it), ``seen`` (monotonic s when the
    samples of the emitting block were seen), ``wanted`` (the board index the loop waited for
    before that call), ``cpu`` (main-thread CPU time of the emitting feed call, s),
    ``range_m`` (m) and ``speed_mps`` (m/s). Per block: ``feed_wall`` and ``feed_cpu`` (wall
    and main-thread CPU time of the feed call, s) and ``block_times`` ((wait began, samples
    seen), monotonic s).
    """

    start: int
    boundary: list[int] = field(default_factory=list)
    emit: list[float] = field(default_factory=list)
    seen: list[float] = field(default_factory=list)
    wanted: list[int] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)
    range_m: list[float] = field(default_factory=list)
    speed_mps: list[float] = field(default_factory=list)
    feed_wall: list[float] = field(default_factory=list)
    feed_cpu: list[float] = field(default_factory=list)
    block_times: list[tuple[float, float]] = field(default_factory=list)

    def __call__(self, block: CapturedBlock) -> None:
        self.feed_cpu.append(block.feed_cpu_s)
        self.feed_wall.append(block.fed_at - block.seen_at)
        self.block_times.append((block.wait_began, block.seen_at))
        for e in block.estimates:
            self.boundary.append(self.start + round(e.t_s * FS_HZ))
            self.emit.append(block.fed_at)
            self.seen.append(block.seen_at)
            self.wanted.append(block.wanted_index)
            self.cpu.append(block.feed_cpu_s)
            self.range_m.append(e.range_m)
            self.speed_mps.append(e.speed_mps)

    def wait_max_s(self) -> float:
        """The longest wait for new samples, s. A long wait means the samples came late
        (board process or reader thread starved), not that the receiver was slow."""
        return max((seen - began for began, seen in self.block_times), default=0.0)


@dataclass(frozen=True)
class HostUse:
    """What the host spent over the measured loop.

    ``wall0``: monotonic s at its start; ``wall_s``: its length, s; CPU time, s: the whole
    process (``cpu_s``), its main thread (``main_cpu_s``), the board driver's threads
    (``thread_cpu_s``, keys ``reader`` and ``writer``), the stand-in board's process
    (``standin_cpu_s``); ``rss_growth_bytes``: resident-set growth, bytes; ``steal_s``:
    hypervisor steal over the probes' CPUs, s (NaN without probes).
    """

    wall0: float
    wall_s: float
    cpu_s: float
    main_cpu_s: float
    thread_cpu_s: dict[str, float]
    standin_cpu_s: float
    rss_growth_bytes: float
    steal_s: float


class HostMeter:
    """Reads the host's CPU, memory and steal counters at the start (:meth:`start`) and at
    the end (:meth:`stop`) of the measured loop: the process, its main thread, the board
    driver's reader and writer threads, the stand-in board's process."""

    def __init__(self, board: Board, standin: StandinBoard, probes: StallProbes | None) -> None:
        self._standin = standin
        self._probes = probes
        self._threads = _board_thread_ids(board)
        self._thread0: dict[str, float] = {}
        self._rss0 = self._steal0 = self._wall0 = self._cpu0 = self._main0 = float("nan")
        self._standin0 = float("nan")

    def _steal_s(self) -> float:
        from machine_stalls import steal_s

        return steal_s(self._probes.cpus) if self._probes is not None else float("nan")

    def start(self) -> None:
        """Read the counters as the measured loop begins."""
        self._thread0 = {name: _thread_cpu_s(tid) for name, tid in self._threads.items()}
        self._rss0 = _rss_bytes()
        self._steal0 = self._steal_s()
        self._wall0, self._cpu0, self._main0 = time.monotonic(), _host_cpu_s(), time.thread_time()
        self._standin0 = self._standin.cpu_s()

    def stop(self) -> HostUse:
        """Read the counters as the measured loop ends; what was spent since :meth:`start`."""
        wall = time.monotonic() - self._wall0
        steal = self._steal_s() - self._steal0
        rss_growth = _rss_bytes() - self._rss0
        cpu = _host_cpu_s() - self._cpu0
        main_cpu = time.thread_time() - self._main0
        standin_cpu = self._standin.cpu_s() - self._standin0
        thread_cpu = {
            name: _thread_cpu_s(tid) - self._thread0[name] for name, tid in self._threads.items()
        }
        return HostUse(
            wall0=self._wall0,
            wall_s=wall,
            cpu_s=cpu,
            main_cpu_s=main_cpu,
            thread_cpu_s=thread_cpu,
            standin_cpu_s=standin_cpu,
            rss_growth_bytes=rss_growth,
            steal_s=steal,
        )


@dataclass(frozen=True)
class BoardTally:
    """The board's counters once the measured loop has ended.

    ``board_now``: the board index now (SYNC fit); ``missing``: the ring's zero-filled
    samples; ``gap_samples``: the gap detector's lost samples; ``dac_underruns`` and
    ``adc_overruns`` (-1 without a status report); ``annotations``: how many;
    ``stream_late_s``: each block's lateness against the board clock, s
    (:func:`_stream_lateness_s`).
    """

    board_now: int
    missing: int
    gap_samples: int
    dac_underruns: int
    adc_overruns: int
    annotations: int
    stream_late_s: npt.NDArray[np.float64]

    @classmethod
    def read(cls, board: Board, arrivals: Arrivals) -> BoardTally:
        """The counters of ``board`` now; ``arrivals`` times its blocks."""
        ring = board.ring
        assert ring is not None
        status = board.last_status
        return cls(
            board_now=board.board_index_now(),
            missing=ring.missing,
            gap_samples=board.gaps.gap_samples,
            dac_underruns=status.dac_underruns if status else -1,
            adc_overruns=status.adc_overruns if status else -1,
            annotations=len(board.annotations.all()),
            stream_late_s=_stream_lateness_s(board, arrivals),
        )


@dataclass(frozen=True)
class LiveRun:
    """Everything one live run recorded, the input of its figures.

    Board indices: ``start`` (the receiver's sample 0), ``n_total`` (samples to process),
    ``next_index`` (the capture loop's next index at the end), ``held_end`` (the ring's end
    index at the end), ``backlog_max`` (samples, the capture loop's largest backlog).
    ``machine``: the probes' stalls while streaming (None without probes); ``flushed``:
    estimates the receiver still held at the end of input.
    """

    seconds: float
    start: int
    n_total: int
    next_index: int
    held_end: int
    backlog_max: int
    use: HostUse
    machine: MachineStalls | None
    board: BoardTally
    log: EstimateLog
    arrivals: Arrivals
    flushed: int = 0


def measure_loop(
    capture: CaptureLoop,
    end_target: int,
    meter: HostMeter,
    probes: StallProbes | None,
    profiler: cProfile.Profile | None,
) -> tuple[HostUse, MachineStalls | None, int | None]:
    """Run ``capture`` up to board index ``end_target`` with the heap frozen, as the tank run
    does (no 75 ms full collection mid-stream); the host's use, the machine's stalls over
    that time (None without probes) and the ring's end index right after the loop (None if
    the ring is empty)."""
    from hil.acquisition import HeapFreeze

    heap = HeapFreeze()
    heap.start()
    if profiler is not None:
        profiler.enable()
    meter.start()
    while capture.next_index < end_target:
        if capture.step(2.0, limit=end_target) is None:
            raise RuntimeError(
                f"no samples past board index {capture.next_index} for 2 s: the board stalled"
            )
    use = meter.stop()
    ring = capture.source.ring
    held_end = ring.end_index if ring is not None else None
    heap.stop()
    machine = None
    if probes is not None:
        # The machine while streaming (not while the board and probes started).
        machine = probes.stop().between(use.wall0, use.wall0 + use.wall_s, use.steal_s)
    if profiler is not None:
        profiler.disable()
    return use, machine, held_end


def stream_live(
    standin: StandinBoard,
    design: LiveDesign,
    seconds: float,
    min_block_s: float,
    every_block: bool,
    probes: StallProbes | None,
    profiler: cProfile.Profile | None,
) -> LiveRun:
    """Open the Board driver on the stand-in's pty and stream ``seconds`` (s) through the
    capture loop of ``hil tank-run`` and GCAS; ``min_block_s`` (s) is the feed period with
    ``every_block``."""
    from hil.acquisition.capture import CaptureLoop
    from hil.acquisition.feed import ReceiverFeed
    from hil.devices.board import Board
    from hil.devices.board_settings import BoardSettings

    settings = BoardSettings(sample_rate_hz=FS_HZ, dac_channels=1, adc_channels=ADC_CHANNELS)
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
        log = EstimateLog(start)
        # The capture loop of hil tank-run: it waits, as the run does, for the receiver's
        # next decision (nothing can come out before it) or one block when no decision
        # comes within it; with --every-block for every min_block samples instead.
        min_block = max(1, int(round(min_block_s * FS_HZ)))
        capture = CaptureLoop(
            board,
            start,
            int(round(MAX_BLOCK_S * FS_HZ)),
            feed=feed,
            on_fed=log,
            every=min_block if every_block else None,
        )
        n_total = int(round(seconds * FS_HZ))
        meter = HostMeter(board, standin, probes)
        use, machine, held_end = measure_loop(capture, start + n_total, meter, probes, profiler)
        tally = BoardTally.read(board, arrivals)
    return LiveRun(
        seconds=seconds,
        start=start,
        n_total=n_total,
        next_index=capture.next_index,
        held_end=held_end or start,
        backlog_max=capture.backlog_max,
        use=use,
        machine=machine,
        board=tally,
        log=log,
        arrivals=arrivals,
        flushed=len(feed.finish()),
    )


def run_live(
    seconds: float,
    min_block_s: float,
    profile: bool = False,
    every_block: bool = False,
    stall_probes: bool = True,
    dump: str | None = None,
) -> dict[str, Any]:
    """Stream ``seconds`` (s) through Board + capture loop + GCAS; the figures (module
    docstring). ``min_block_s`` (s): the feed period with ``every_block``; ``profile``:
    cProfile the host to stderr; ``dump``: an .npz path for the per-estimate and per-block
    times."""
    from machine_stalls import StallProbes

    design = tank_board_design()
    probes = StallProbes() if stall_probes else None
    profiler = None
    if profile:
        import cProfile

        profiler = cProfile.Profile()
    try:
        if probes is not None:
            probes.start()  # before the board: their start-up must not land in the stream
        with StandinBoard() as standin:
            run = stream_live(standin, design, seconds, min_block_s, every_block, probes, profiler)
    finally:
        if probes is not None:
            probes.close()  # after stop() nothing is left; on an error, kill them
    timing = EstimateTiming.of(run.log, run.arrivals)
    stalls = StallOverlap.of(run.machine, standin.stalls, timing, run.use)
    if dump is not None:
        dump_times(dump, run, timing, stalls)
    result = live_figures(run, design, timing, stalls)
    if profiler is not None:
        import pstats

        pstats.Stats(profiler, stream=sys.stderr).sort_stats("cumulative").print_stats(30)
    return result


# --------------------------------------------------------------------------- accounting
@dataclass(frozen=True)
class EstimateTiming:
    """When each estimate's boundary and samples arrived, shape (n_estimates,) each.

    Board indices: ``boundary`` (the estimate's hop boundary) and ``wanted`` (the index the
    loop waited for before the emitting feed call). Monotonic s: ``boundary_seen`` and
    ``wanted_seen`` (when the ring first held that sample, NaN if never), ``seen`` (when the
    emitting block's samples were seen), ``emit`` (when the feed call returned the estimate).
    ``cpu``: the emitting feed call's main-thread CPU time, s.
    """

    boundary: npt.NDArray[np.int64]
    wanted: npt.NDArray[np.int64]
    boundary_seen: npt.NDArray[np.float64]
    wanted_seen: npt.NDArray[np.float64]
    seen: npt.NDArray[np.float64]
    emit: npt.NDArray[np.float64]
    cpu: npt.NDArray[np.float64]

    @classmethod
    def of(cls, log: EstimateLog, arrivals: Arrivals) -> EstimateTiming:
        """The timing of the estimates in ``log``, their samples' arrivals from ``arrivals``."""
        boundary = np.asarray(log.boundary, dtype=np.int64)
        wanted = np.asarray(log.wanted, dtype=np.int64)
        return cls(
            boundary=boundary,
            wanted=wanted,
            boundary_seen=arrivals.time_of(boundary),
            wanted_seen=arrivals.time_of(wanted - 1),  # the last sample the loop waited for
            seen=np.asarray(log.seen),
            emit=np.asarray(log.emit),
            cpu=np.asarray(log.cpu),
        )

    @property
    def latency_s(self) -> npt.NDArray[np.float64]:
        """From the boundary's arrival to the estimate, s."""
        return self.emit - self.boundary_seen

    @property
    def wait_s(self) -> npt.NDArray[np.float64]:
        """The first part of the latency: waiting for the samples past the boundary that the
        receiver needs (its look-ahead, plus any stall of the stream), s."""
        return self.seen - self.boundary_seen

    @property
    def processing_s(self) -> npt.NDArray[np.float64]:
        """The second part: the feed call, s."""
        return self.emit - self.seen

    @property
    def stream_s(self) -> npt.NDArray[np.float64]:
        """The wait, finer: the stream delivering the look-ahead, s."""
        return self.wanted_seen - self.boundary_seen

    @property
    def wake_s(self) -> npt.NDArray[np.float64]:
        """The wait, finer: the loop waking up once the look-ahead was there, s."""
        return self.seen - self.wanted_seen

    @property
    def off_cpu_s(self) -> npt.NDArray[np.float64]:
        """The feed call's time off the CPU (waiting for a core or the GIL), s."""
        return self.processing_s - self.cpu


@dataclass(frozen=True)
class StallOverlap:
    """Which estimates a stall touched (the stall overlaps the time from the boundary's
    arrival to the estimate), bool shape (n_estimates,): ``in_machine`` (a machine stall: the
    hypervisor or kernel held a CPU away from every thread) and ``in_standin`` (a stall of
    the stand-in board's pump: it shares the host's CPUs, hardware would not);
    ``standin_s``: the stand-in's stalls within the measured loop, clipped to it, s.
    """

    in_machine: npt.NDArray[np.bool_]
    in_standin: npt.NDArray[np.bool_]
    standin_s: npt.NDArray[np.float64]

    @property
    def clear(self) -> npt.NDArray[np.bool_]:
        """The estimates that neither kind of stall touched."""
        return ~self.in_machine & ~self.in_standin

    @classmethod
    def of(
        cls,
        machine: MachineStalls | None,
        standin: npt.NDArray[np.float64],
        timing: EstimateTiming,
        use: HostUse,
    ) -> StallOverlap:
        """The overlaps of ``machine``'s stalls and the stand-in's ``standin`` (shape (n, 2),
        start and end monotonic s) with the estimates of ``timing``, over ``use``'s loop."""
        from machine_stalls import overlapping

        seen, emit = timing.boundary_seen, timing.emit
        if machine is not None:
            in_machine = machine.overlapping(seen, emit)
        else:
            in_machine = np.zeros(emit.shape, dtype=bool)
        t0, t1 = use.wall0, use.wall0 + use.wall_s
        run = standin[(standin[:, 1] >= t0) & (standin[:, 0] <= t1)]
        return cls(
            in_machine=in_machine,
            in_standin=overlapping(standin[:, 0], standin[:, 1], seen, emit),
            standin_s=np.minimum(run[:, 1], t1) - np.maximum(run[:, 0], t0),
        )


def dump_times(path: str, run: LiveRun, timing: EstimateTiming, stalls: StallOverlap) -> None:
    """Save the per-estimate and per-block times of ``run`` to ``path`` (NumPy .npz), for
    analysis: board indices, monotonic s and CPU s as in :class:`EstimateTiming`,
    :class:`EstimateLog` and :class:`Arrivals`."""
    arr_index, arr_time = run.arrivals.arrays()
    np.savez(
        path,
        boundary=timing.boundary,
        boundary_seen=timing.boundary_seen,
        wanted=timing.wanted,
        wanted_seen=timing.wanted_seen,
        feed_cpu_of_estimate=timing.cpu,
        seen=timing.seen,
        emit=timing.emit,
        in_machine_stall=stalls.in_machine,
        in_standin_stall=stalls.in_standin,
        arrival_end_index=arr_index,
        arrival_time=arr_time,
        feed_wall=np.asarray(run.log.feed_wall),
        block_times=np.asarray(run.log.block_times),
        feed_cpu=np.asarray(run.log.feed_cpu),
        start=run.start,
        wall0=run.use.wall0,
    )


# --------------------------------------------------------------------------- the figures
def _hops(x: npt.NDArray[np.float64], percentile: float, hop_s: float) -> float:
    """A percentile of ``x`` (s) in hops of ``hop_s`` s, rounded; NaN when ``x`` holds no
    finite value."""
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan")
    return round(float(np.percentile(x, percentile)) / hop_s, 3)


def _cpu_figures(run: LiveRun) -> dict[str, Any]:
    """Host CPU in cores (CPU s over wall s), by part, and the resident-set growth, MiB."""
    use = run.use
    wall, cpu, main_cpu, thread_cpu = use.wall_s, use.cpu_s, use.main_cpu_s, use.thread_cpu_s
    return {
        "host_cpu_cores": round(cpu / wall, 3),
        "main_thread_cores": round(main_cpu / wall, 3),
        "gcas_cores": round(float(sum(run.log.feed_cpu)) / wall, 3),
        "board_threads_cores": round((cpu - main_cpu) / wall, 3),
        "reader_thread_cores": round(thread_cpu["reader"] / wall, 3),
        # What the CPU target names, capture plus GCAS: the reader thread and the
        # main thread (capture loop + GCAS); the host figure, which the target is checked
        # on, also holds the DAC writer (transmission) and everything else in the process.
        "capture_gcas_cores": round((thread_cpu["reader"] + main_cpu) / wall, 3),
        "writer_thread_cores": round(thread_cpu["writer"] / wall, 3),
        "sim_board_process_cores": round(use.standin_cpu_s / wall, 3),
        "host_rss_growth_mib": round(use.rss_growth_bytes / 2**20, 2),
    }


def _feed_call_figures(log: EstimateLog) -> dict[str, Any]:
    """The feed call per block, wall and main-thread CPU time, ms; the longest wait, ms."""
    feed_wall, feed_cpu = log.feed_wall, log.feed_cpu
    return {
        "feed_call_median_ms": round(float(np.median(feed_wall)) * 1e3, 3),
        "feed_call_p99_ms": round(float(np.percentile(feed_wall, 99)) * 1e3, 3),
        "feed_call_max_ms": round(float(np.max(feed_wall)) * 1e3, 3),
        "feed_call_cpu_p99_ms": round(float(np.percentile(feed_cpu, 99)) * 1e3, 3),
        "feed_call_cpu_max_ms": round(float(np.max(feed_cpu)) * 1e3, 3),
        "wait_for_samples_max_ms": round(log.wait_max_s() * 1e3, 3),
    }


def _keep_up_figures(run: LiveRun) -> dict[str, Any]:
    """Samples (board elapsed, processed, captured, missing, lost, backlog), the board's
    underruns/overruns and annotations, and whether the host kept up."""
    board = run.board
    processed = run.next_index - run.start
    final_backlog = run.held_end - run.next_index
    # Kept up: nothing lost, and when the last block was done the receiver was behind the
    # capture by less than KEEP_UP_BACKLOG_S (a transient stall may leave a backlog, a
    # receiver slower than real time leaves one that grows with the run).
    keeps_up = bool(
        board.missing == 0
        and board.gap_samples == 0
        and board.adc_overruns <= 0
        and board.dac_underruns == 0  # the transmitter was fed in time too
        and processed == run.n_total
        and final_backlog <= KEEP_UP_BACKLOG_S * FS_HZ
    )
    return {
        "board_samples_elapsed": int(board.board_now - run.start),
        "samples_processed": int(processed),
        "samples_captured": int(run.held_end - run.start),
        "ring_missing_samples": int(board.missing),
        "gap_samples": int(board.gap_samples),
        "dac_underruns": int(board.dac_underruns),
        "adc_overruns": int(board.adc_overruns),
        "annotations": board.annotations,
        "final_backlog_samples": int(final_backlog),
        "max_backlog_samples": int(run.backlog_max),
        "keeps_up": keeps_up,
    }


def _estimate_figures(run: LiveRun, design: LiveDesign) -> dict[str, Any]:
    """How many estimates, per s, how many at the echo's range (within 0.1 m); their median
    range (m) and speed (m/s); the hop, s."""
    ranges = np.asarray(run.log.range_m)
    speeds = np.asarray(run.log.speed_mps)
    n = len(run.log.boundary)
    return {
        "estimates": n,
        "estimates_flushed": run.flushed,
        "estimates_per_s": round(n / run.use.wall_s, 1),
        "estimates_on_target": int(np.count_nonzero(np.abs(ranges - design.echo_range_m) < 0.1)),
        "echo_range_m": round(design.echo_range_m, 4),
        "median_range_m": round(float(np.median(ranges)), 4) if ranges.size else None,
        "median_speed_mps": round(float(np.median(speeds)), 4) if speeds.size else None,
        "hop_s": design.schedule.hop_s,
    }


def _latency_figures(timing: EstimateTiming, hop_s: float) -> dict[str, Any]:
    """Estimate latency in hops of ``hop_s`` s, its parts in ms, all and over one hop."""
    lat_s, wait_s, proc_s = timing.latency_s, timing.wait_s, timing.processing_s
    stream_s, wake_s, off_cpu_s = timing.stream_s, timing.wake_s, timing.off_cpu_s
    over = lat_s > hop_s
    return {
        "latency_median_hops": _hops(lat_s, 50, hop_s),
        "latency_p99_hops": _hops(lat_s, 99, hop_s),
        "latency_max_hops": _hops(lat_s, 100, hop_s),
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
        "lookahead_median_ms": _ms((timing.wanted - timing.boundary) / FS_HZ, 50),
        "stream_median_ms": _ms(stream_s, 50),
        "over_1_hop_stream_median_ms": _ms(stream_s[over], 50),
        "wake_median_ms": _ms(wake_s, 50),
        "over_1_hop_wake_median_ms": _ms(wake_s[over], 50),
        "feed_off_cpu_median_ms": _ms(off_cpu_s, 50),
        "over_1_hop_feed_off_cpu_median_ms": _ms(off_cpu_s[over], 50),
    }


def _stream_lateness_figures(board: BoardTally) -> dict[str, Any]:
    """The blocks' lateness against the board clock, ms (median, p99, max)."""
    late_s = board.stream_late_s
    return {
        "stream_lateness_median_ms": _ms(late_s, 50),
        "stream_lateness_p99_ms": _ms(late_s, 99),
        "stream_lateness_max_ms": _ms(late_s, 100),
    }


def _stall_figures(
    run: LiveRun, timing: EstimateTiming, stalls: StallOverlap, hop_s: float
) -> dict[str, Any]:
    """The machine's and the stand-in's stalls, the estimates each touched, and the latency
    (hops of ``hop_s`` s) over the estimates neither touched."""
    lat_s, clear = timing.latency_s, stalls.clear
    over = lat_s > hop_s
    standin_s = stalls.standin_s
    in_machine: dict[str, Any] = {}
    if run.machine is not None:
        in_machine = {
            "estimates_in_machine_stall": int(np.count_nonzero(stalls.in_machine)),
            "over_1_hop_in_machine_stall": int(np.count_nonzero(over & stalls.in_machine)),
        }
    return {
        **machine_figures(run.machine),
        **in_machine,
        "standin_stalls": int(standin_s.size),
        "standin_stall_max_ms": round(float(standin_s.max()) * 1e3, 3) if standin_s.size else 0.0,
        "estimates_in_standin_stall": int(np.count_nonzero(stalls.in_standin)),
        "over_1_hop_in_standin_stall": int(np.count_nonzero(over & stalls.in_standin)),
        "over_1_hop_outside_stalls": int(np.count_nonzero(over & clear)),
        "latency_p99_outside_stalls_hops": _hops(lat_s[clear], 99, hop_s),
        "latency_max_outside_stalls_hops": _hops(lat_s[clear], 100, hop_s),
    }


def _target_figures(cores: float, keeps_up: bool, max_lat_hops: float) -> dict[str, Any]:
    """The targets, the ratios target/measured (host CPU ``cores``, the maximum latency
    ``max_lat_hops``) and whether all targets are met."""
    return {
        "target_cpu_cores": TARGET_CPU_CORES,
        "cpu_ratio": round(TARGET_CPU_CORES / max(cores, 1e-9), 2),
        "target_latency_hops": TARGET_LATENCY_HOPS,
        "latency_ratio": round(TARGET_LATENCY_HOPS / max_lat_hops, 2) if max_lat_hops > 0 else None,
        "meets_targets": bool(
            keeps_up and cores < TARGET_CPU_CORES and max_lat_hops <= TARGET_LATENCY_HOPS
        ),
    }


def live_figures(
    run: LiveRun, design: LiveDesign, timing: EstimateTiming, stalls: StallOverlap
) -> dict[str, Any]:
    """The run's figures, one flat dict in the order of the table (module docstring)."""
    hop_s = design.schedule.hop_s
    blocks = len(run.log.block_times)
    result: dict[str, Any] = {
        "seconds": run.seconds,
        "wall_s": round(run.use.wall_s, 3),
        "blocks": blocks,
        "mean_block_samples": round((run.next_index - run.start) / max(blocks, 1), 1),
        **_cpu_figures(run),
        **_feed_call_figures(run.log),
        **_keep_up_figures(run),
        **_estimate_figures(run, design),
        **_latency_figures(timing, hop_s),
        **_stream_lateness_figures(run.board),
        **_stall_figures(run, timing, stalls, hop_s),
    }
    cores = run.use.cpu_s / run.use.wall_s
    result.update(_target_figures(cores, result["keeps_up"], result["latency_max_hops"]))
    return result


def machine_figures(machine: Any) -> dict[str, Any]:
    """The stall probes' summary, keys prefixed ``machine_`` (empty without probes)."""
    if machine is None:
        return {}
    return {f"machine_{k}": v for k, v in machine.summary().items()}


# --------------------------------------------------------------------------- the table
#: Table rows: (name, text).
Rows = list[tuple[str, str]]


def machine_rows(r: dict[str, Any]) -> Rows:
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


def _cpu_rows(r: dict[str, Any]) -> Rows:
    """The table's first section: what was streamed, the host's CPU by part, its memory."""
    return [
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
    ]


def _keep_up_rows(r: dict[str, Any]) -> Rows:
    """The feed call's times, keeping up (samples, losses, backlog, board counters) and the
    estimates."""
    return [
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
    ]


def _latency_rows(r: dict[str, Any]) -> Rows:
    """The estimate latency (hops), its parts (ms) and the stream's lateness (ms)."""
    return [
        (
            "latency",
            f"median {r['latency_median_hops']:.3f}, p99 {r['latency_p99_hops']:.3f},"
            f" max {r['latency_max_hops']:.3f} hops (hop {r['hop_s'] * 1e3:.1f} ms; target <="
            f" {TARGET_LATENCY_HOPS}); {r['estimates_over_1_hop']} estimates over 1 hop",
        ),
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


def _stall_rows(r: dict[str, Any]) -> Rows:
    """The machine's and the stand-in's stalls, the estimates they touched, and the latency
    over the estimates neither touched."""
    rows = machine_rows(r)
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
    return rows


def print_rows(rows: Rows) -> None:
    """Table rows on stdout: the name in 18 columns, then the text."""
    for name, text in rows:
        print(f"{name:<18} {text}")


def print_table(r: dict[str, Any]) -> None:
    """The figures of :func:`run_live` as a table on stdout."""
    print_rows(_cpu_rows(r) + _keep_up_rows(r) + _latency_rows(r) + _stall_rows(r))


def run_machine_only(seconds: float) -> dict[str, Any]:
    """Only the stall probes, for ``seconds``, on a machine left otherwise idle: what any
    live pipeline on it would lose."""
    from machine_stalls import StallProbes

    with StallProbes() as probes:
        time.sleep(seconds)
    assert probes.result is not None
    return {"seconds": seconds, "machine_only": True, **machine_figures(probes.result)}


def build_parser() -> argparse.ArgumentParser:
    """The command line (module docstring); ``--serve-board`` runs the stand-in board."""
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
    return parser


def main() -> None:
    args = build_parser().parse_args()
    if args.serve_board:
        delay, gain, noise, out = args.serve_board
        serve_board(int(delay), float(gain), float(noise), out)
        return
    seconds = 1.5 if args.quick else args.seconds
    if args.machine_only:
        result = run_machine_only(seconds)
        print_rows(machine_rows(result))
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
