"""The built-in simulated tank as a JACK client, for a run through a real audio stack.

``hil sim-serve tank --jack`` runs it: a private JACK server on the dummy driver
(:class:`~hil.devices.audio.jack_server.JackDummyServer`) at the waveform's rate, the
simulated tank's GRBL controller on a pty, and the tank's acoustic world as a client of that
server through PortAudio (:class:`TankJackClient`). A run is then an ordinary real-device run:
``board = "audio://JACK?rate=...&blocksize=..."`` (PortAudio's JACK host API, the path a USB
audio interface takes) and ``stage = "/dev/pts/N"``.

Wiring (made by the tank when a run opens its stream, before it starts): the run's output 1
(``PortAudio:out_0``) drives the tank's transmitter (the tank's ``in_0``); the tank's
``out_0`` is the hydrophone, into the run's input 1 (``in_0``); its ``out_1`` the DAC
monitor, ``CONVERTER_DELAY_SAMPLES`` late, into the run's input 2 (``in_1``). Both inputs
come from the tank, so the loopback latency the run measures on the monitor holds for the
hydrophone too, whatever order JACK runs its clients in.

Time: the tank's world starts at the first non-silent sample on its transmitter input (the
run's first transmitted sample: JACK's digital path carries exact zeros before it). The
simulation's time is the tank stream's sample time: the GRBL controller runs on it
(:class:`AudioPacedClock`), and the carriage position an input sample's echo is rendered
with is the controller's at that sample's time. The server runs in real time (the dummy
driver has no slower pace: ``simulation.time_scale`` does not apply to it) and
synchronously (each period waits for every client), so a world that computes slower than
real time slows the whole stream instead of losing samples: the run sees a device at its
nominal rate whose pace against the wall clock varies, and maps its wall-clock-dated stage
telemetry through its callback's stamps
(:func:`~hil.experiments.live.board_state.sample_index_at`).

Everything from :mod:`sim_devices` is imported inside the functions (DESIGN: the host never
imports simulated devices at module level).
"""

from __future__ import annotations

import logging
import queue
import re
import threading
from collections import defaultdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hil.devices.audio.contract import BlockTime, FloatArray, StatusFlags
from hil.devices.audio.settings import AudioSettings
from hil.errors import ConfigError
from hil.experiments.experiment import Experiment, parse_experiment
from hil.experiments.sim_tank import build_tank_world, tank_stage_config

if TYPE_CHECKING:
    from hil.devices.audio.jack_server import JackDummyServer
    from hil.devices.audio.portaudio_backend import SoundDeviceDuplex

_LOG = logging.getLogger(__name__)

#: Frames per JACK period by default (5.3 ms at 192 kHz): the world renders a block per
#: period (its per-call overhead grows at smaller blocks), and the loop's latency, several
#: periods, stays inside what a run's latency probe measures (75 ms).
DEFAULT_PERIOD = 1024
#: The PortAudio device name of a JACK server (its ``system`` device, JACK host API).
JACK_DEVICE = "JACK"
#: Seconds between looks at the server's ports for a run to wire.
WIRING_POLL_S = 0.1
#: Periods the world renders behind the audio callback (the tank's own latency): room for
#: the world's compute time to vary from block to block (GIL, a busy machine).
PIPELINE_BLOCKS = 2
#: Longest wait of the audio callback for a block the world has not rendered yet, s (under
#: the server's client timeout, so the server never drops the tank).
LATE_WAIT_S = 9.0
#: Silent periods on the transmitter input that end a run (a run transmits without a
#: break from its first sample to its last): the world stops, the next one is built.
END_SILENT_BLOCKS = 8
#: The worker's job number that builds the next run's world.
ARM = -1

#: A device line of the experiment file: ``key = "URL"`` or ``key = 'URL'`` at a line start.
_DEVICE_LINE = r"""(?m)^{key}\s*=\s*(?:"[^"]*"|'[^']*')"""
_PORT = re.compile(r"^(?P<client>[^:]+):(?P<port>.+)$")


def served_experiment(exp: Experiment, pty: str, period: int) -> str:
    """``exp``'s text with ``[devices]`` pointing at the served tank: the board is the JACK
    server through PortAudio at the waveform's rate and ``period`` frames a block, the stage
    the pty ``pty``. Checked by parsing it. Through a real audio stack the devices are real
    ones, which have no simulated empty-tank background: a ``gcas-bg`` receiver with
    ``background = "simulated"`` becomes ``gcas-mti`` (the clutter canceller, which needs no
    capture)."""
    rate = int(exp.waveform.fs_hz)
    board = f'board = "audio://{JACK_DEVICE}?rate={rate}&blocksize={period}"'
    stage = f'stage = "{pty}"'
    text, n_board = re.subn(_DEVICE_LINE.format(key="board"), board, exp.text)
    text, n_stage = re.subn(_DEVICE_LINE.format(key="stage"), stage, text)
    if exp.receiver == "gcas-bg" and exp.receiver_options.get("background") == "simulated":
        text = re.sub(r'(?m)^name = "gcas-bg"[ \t]*$', 'name = "gcas-mti"', text, count=1)
        text = re.sub(r'(?m)^options = \{ background = "simulated" \}[ \t]*\n', "", text)
    if n_board != 1 or n_stage != 1:
        raise ConfigError(
            "devices",
            f"{n_board} board and {n_stage} stage lines",
            'one board = "URL" and one stage = "URL" line in [devices]',
            "write the devices of the experiment file as the built-in one does",
        )
    parse_experiment(text)
    return text


class AudioPacedClock:
    """The stage clock of the JACK tank (s): the tank stream's sample time, so the GRBL
    controller moves the carriage in the same seconds the echoes are rendered in, however
    the server's pace varies. Between two periods it runs on with the wall clock at
    ``time_scale``, at most one period past the last one (it waits when the server waits).

    >>> c = AudioPacedClock(period_s=0.01, time_scale=0.5, wall=lambda: 100.0)
    >>> c.advance(2.0); c()
    2.0
    >>> c._wall = lambda: 100.004; round(c(), 6)
    2.002
    >>> c._wall = lambda: 101.0; c()
    2.01
    """

    def __init__(self, period_s: float, time_scale: float, wall: Any = None) -> None:
        import time as wallclock

        self._wall = wall or wallclock.monotonic
        self.period_s = float(period_s)
        self.time_scale = float(time_scale)
        # (stream time s, wall time s then): one tuple, so a reader in another thread never
        # pairs a new stream time with an old wall time.
        self._last = (0.0, self._wall())

    def advance(self, audio_s: float) -> None:
        """The stream reached ``audio_s`` (its sample index / rate) now."""
        self._last = (float(audio_s), self._wall())

    def __call__(self) -> float:
        audio_s, at = self._last
        ahead = (self._wall() - at) * self.time_scale
        return audio_s + min(max(ahead, 0.0), self.period_s)


class TankJackClient:
    """The tank's acoustic world of ``exp`` as a JACK client (see the module docstring).

    ``carriage_motion(t)`` gives the simulated carriage's position (m) and velocity (m/s) at
    stage clock times ``t`` (s); ``clock`` is the stage clock, an :class:`AudioPacedClock`
    this client advances. The client's stream is PortAudio's over JACK: 1 input (the
    transmitter), 2 outputs (hydrophone, DAC monitor).

    The world renders in a worker thread, ``pipeline_blocks`` periods behind the audio
    callback: the callback copies blocks in and out, so a block that takes longer than a
    period to render does not hold up the server, as long as the world keeps up on
    average. The output is that many periods later than the input (a fixed latency,
    measured by the run with the rest of the loop). When the world falls further behind,
    the callback waits for it (:attr:`late_blocks`): the synchronous server waits, the whole
    stream slows, no sample is lost; a block not rendered within :data:`LATE_WAIT_S` is
    played as silence (:attr:`lost_blocks`).
    """

    def __init__(
        self,
        exp: Experiment,
        period: int,
        carriage_motion: Any,
        clock: Any,
        *,
        device: str | int = JACK_DEVICE,
        pipeline_blocks: int = PIPELINE_BLOCKS,
        truth_dir: Path | None = None,
    ) -> None:
        from hil.signals.synthesis import BlockSynthesizer

        if int(pipeline_blocks) != pipeline_blocks or pipeline_blocks < 1:
            raise ConfigError("pipeline_blocks", pipeline_blocks, "an integer >= 1")
        self.exp = exp
        self.fs = float(exp.waveform.fs_hz)
        self.period = int(period)
        self._carriage_motion = carriage_motion
        self._clock = clock
        self.settings = AudioSettings(
            samplerate=self.fs, channels_in=1, channels_out=2, blocksize=self.period,
            device=device,
        )  # fmt: skip
        # The first transmitted sample that is not exactly zero: the world's origin is that
        # many samples before the first non-silent input sample.
        first = BlockSynthesizer(exp.schedule, self.fs, amplitude=exp.amplitude).read(64)
        nonzero = np.flatnonzero(first)
        self._first_nonzero = int(nonzero[0]) if nonzero.size else 0
        self._lock = threading.Lock()
        self._armed: Any = None  # the world for the next run, built off the audio thread
        self._world: Any = None
        self._origin: int | None = None
        self.runs_started = 0
        # Each run's exact truth (hil.experiments.exact_truth) goes to ``truth_dir`` when it
        # ends: (run number, origin, the sample after its last sound) of the runs ended, for
        # a thread of its own to write (the world's worker arms the next run meanwhile: a run
        # that starts right after another must find its world ready), None to stop it.
        self.truth_dir = truth_dir
        self._sounding_until = 0
        self._ended: queue.SimpleQueue[tuple[int, int, int] | None] = queue.SimpleQueue()
        #: The truth tables written, one per run ended (paths).
        self.truth_files: list[Path] = []
        # The pipeline: slot ``seq % slots`` holds block ``seq``'s input, its world, the
        # world sample of its first input sample, the silent samples before the onset, and
        # (once rendered) its output.
        self.pipeline_blocks = int(pipeline_blocks)
        slots = self.pipeline_blocks + 2
        self._in = np.zeros((slots, self.period), dtype=np.float64)
        self._out = np.zeros((slots, self.period, 2), dtype=np.float32)
        self._job_world: list[Any] = [None] * slots
        self._job_first = [0] * slots
        self._job_skip = [0] * slots
        self._ready = [-1] * slots
        self._jobs: queue.SimpleQueue[int | None] = queue.SimpleQueue()
        self._seq = 0
        self._silent_blocks = 0
        self._rendered = threading.Condition()
        #: Blocks the callback waited for (the stream slowed down), and blocks not rendered
        #: within :data:`LATE_WAIT_S` (played as silence: a gap in the echo).
        self.late_blocks = 0
        self.lost_blocks = 0
        self.error: BaseException | None = None
        self.backend: SoundDeviceDuplex | None = None
        self.client_name: str | None = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.wired: set[str] = set()

    # ------------------------------------------------------------------ set-up
    def start(self) -> TankJackClient:
        """Open the stream on the JACK server, learn the client name it got, start it, and
        start the world's worker and the wiring of runs (threads)."""
        from hil.devices.audio.jack_ports import jack_ports
        from hil.devices.audio.portaudio_backend import SoundDeviceDuplex

        self._warm_up()
        self._arm()
        before = _clients(jack_ports())
        backend = self.backend = SoundDeviceDuplex(self.settings)
        backend.open(self._callback)
        new = sorted(set(_clients(jack_ports())) - set(before))
        if len(new) != 1:
            backend.close()
            raise RuntimeError(f"expected one new JACK client for the tank, found {new}")
        self.client_name = new[0]
        for target, name in (
            (self._render, "tank-world"),
            (self._wire_runs, "tank-wiring"),
            (self._write_truths, "tank-truth"),
        ):
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)
        backend.start()
        return self

    def _warm_up(self) -> None:
        """Render one block of a throwaway world: the first block of the first world loads
        and compiles what every later one reuses (seconds on a busy machine), which would
        otherwise hold up the run's first periods."""
        world = build_tank_world(self.exp, lambda t: (np.zeros_like(t), np.zeros_like(t)))
        world(np.zeros((self.period, 1)), 0)

    def _arm(self) -> None:
        """Build the world of the next run (off the audio thread)."""
        world = build_tank_world(self.exp, self._carriage)
        with self._lock:
            self._armed = world

    def _carriage(self, world_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # World time 0 is the input sample ``origin``: stream time origin / fs.
        assert self._origin is not None
        t = np.asarray(world_t, dtype=np.float64) + self._origin / self.fs
        return self._carriage_motion(t)

    # ------------------------------------------------------------------ audio thread
    def _callback(
        self,
        indata: FloatArray,
        outdata: FloatArray,
        frames: int,
        time: BlockTime,
        status: StatusFlags,
    ) -> None:
        # Real-time path: copies into preallocated slots and a job number handed to the
        # worker; it waits only for a block the world is late with (see the class
        # docstring; the lock only guards swapping a prebuilt world in).
        seq = self._seq
        self._seq = seq + 1
        slot = seq % len(self._ready)
        x = indata[:, 0]
        if self._origin is None and self._armed is not None:
            onset = np.flatnonzero(x)
            if onset.size:
                k = max(0, int(onset[0]) - self._first_nonzero)
                with self._lock:
                    self._world, self._armed = self._armed, None
                    self._origin = time.sample_index + k
                    self.runs_started += 1
        self._clock.advance(time.sample_index / self.fs)
        if self._origin is not None and not x.any():
            self._silent_blocks += 1
            if self._silent_blocks >= END_SILENT_BLOCKS:
                # The run stopped transmitting: the world is done; the next is built.
                self._ended.put((self.runs_started, self._origin, self._sounding_until))
                with self._lock:
                    self._origin, self._world = None, None
                self._jobs.put(ARM)
        else:
            self._silent_blocks = 0
            self._sounding_until = time.sample_index + frames
        if self._origin is not None:
            first = time.sample_index - self._origin
            self._in[slot] = x
            self._job_world[slot] = self._world
            self._job_first[slot] = max(first, 0)
            self._job_skip[slot] = max(-first, 0)
            self._ready[slot] = -1
            self._jobs.put(seq)
        else:
            self._job_world[slot] = None
        done = seq - self.pipeline_blocks
        if done < 0:
            outdata.fill(0.0)
            return
        done_slot = done % len(self._ready)
        if self._job_world[done_slot] is None:
            outdata.fill(0.0)  # before the run's first sample
            return
        if self._ready[done_slot] != done:
            # Back-pressure: the synchronous server waits for this callback, so waiting
            # for the world slows the whole stream (every client) instead of a gap.
            self.late_blocks += 1
            with self._rendered:
                self._rendered.wait_for(lambda: self._ready[done_slot] == done, LATE_WAIT_S)
        if self._ready[done_slot] == done:
            outdata[:] = self._out[done_slot]
        else:
            outdata.fill(0.0)
            self.lost_blocks += 1

    # ------------------------------------------------------------------ worker threads
    def _write_truths(self) -> None:
        """Write the exact truth of each run that ended (:mod:`hil.experiments.exact_truth`),
        until told to stop: the carriage as its controller planned it, from the run's first
        sample (world time 0, the tank stream's ``origin``) to its last sound."""
        from hil.experiments.exact_truth import FILE_PATTERN, truth_table, write_truth

        while (ended := self._ended.get()) is not None:
            n, origin, until = ended
            if self.truth_dir is None:
                continue
            t0 = origin / self.fs

            def motion(t: np.ndarray, t0: float = t0) -> tuple[np.ndarray, np.ndarray]:
                return self._carriage_motion(t + t0)

            table = truth_table(self.exp, motion, max(until - origin, 0) / self.fs)
            path = self.truth_dir / FILE_PATTERN.format(n=n)
            try:
                write_truth(path, table)
            except OSError as error:  # the tank serves on; the run only lacks its table
                _LOG.warning("the exact truth of run %d was not written to %s: %s", n, path, error)
                continue
            self.truth_files.append(path)

    def _render(self) -> None:
        while True:
            seq = self._jobs.get()
            if seq is None:
                return
            if seq == ARM:
                self._arm()
                continue
            slot = seq % len(self._ready)
            world, skip = self._job_world[slot], self._job_skip[slot]
            out = self._out[slot]
            try:
                out[:skip] = 0.0
                out[skip:] = world(self._in[slot, skip:, None], self._job_first[slot])
            except BaseException as exc:  # reported by check(); the tank plays silence
                self.error = exc
                return
            with self._rendered:
                self._ready[slot] = seq
                self._rendered.notify_all()

    def _wire_runs(self) -> None:
        from hil.devices.audio.jack_ports import JackToolError, connect, jack_ports

        me = self.client_name
        while not self._stop.wait(WIRING_POLL_S):
            try:
                clients = _clients(jack_ports())
            except JackToolError:
                continue  # the server is stopping, or busy: look again
            self.wired &= set(clients)  # a run that closed its stream is gone
            for client, ports in clients.items():
                if client == me or client in self.wired or not client.startswith("PortAudio"):
                    continue
                if not {"out_0", "in_0", "in_1"} <= ports:
                    continue
                connect(f"{client}:out_0", f"{me}:in_0")
                connect(f"{me}:out_0", f"{client}:in_0")
                connect(f"{me}:out_1", f"{client}:in_1")
                self.wired.add(client)

    def check(self) -> None:
        """Raise what stopped the world's worker or the stream, if anything did."""
        if self.error is not None:
            raise RuntimeError(f"the tank's world failed: {self.error!r}") from self.error
        if self.backend is not None and not self.backend.active:
            self.backend.wait(0)  # re-raises a callback exception
            raise RuntimeError("the tank's JACK stream stopped (is the JACK server gone?)")

    @property
    def xruns(self) -> int:
        """Xruns the tank's own stream reported."""
        return 0 if self.backend is None else len(self.backend.xruns)

    def close(self) -> None:
        """Stop the threads and close the stream; the truth of a run still sounding is
        written up to its last sound, and every truth queued before the truth thread stops."""
        self._stop.set()
        if self.backend is not None:
            self.backend.close()
        self._jobs.put(None)
        if self._origin is not None:
            self._ended.put((self.runs_started, self._origin, self._sounding_until))
            self._origin = None
        self._ended.put(None)
        if not any(thread.name == "tank-truth" for thread in self._threads):
            self._write_truths()  # a client never started: its truths are written here
        for thread in self._threads:
            thread.join(timeout=5)


def _clients(ports: list[str]) -> dict[str, set[str]]:
    """Port short names by client, from full port names.

    >>> found = _clients(["system:capture_1", "PortAudio:in_0", "PortAudio:out_0"])
    >>> {client: sorted(ports) for client, ports in sorted(found.items())}
    {'PortAudio': ['in_0', 'out_0'], 'system': ['capture_1']}
    """
    found: dict[str, set[str]] = defaultdict(set)
    for port in ports:
        m = _PORT.match(port)
        if m:
            found[m["client"]].add(m["port"])
    return dict(found)


class JackTankServer:
    """``hil sim-serve tank --jack``: a JACK dummy server (real time, synchronous), the
    tank's GRBL controller on a pty, the tank as a JACK client; :meth:`write`
    writes the experiment file a run takes (see the module docstring)."""

    def __init__(self, exp: Experiment, period: int = DEFAULT_PERIOD) -> None:
        self.exp = exp
        self.period = int(period)
        self.server: JackDummyServer | None = None
        self.stage: Any = None
        self.tank: TankJackClient | None = None

    def start(self) -> JackTankServer:
        """Start the server, the controller and the tank client (in that order)."""
        from hil.devices.audio.jack_server import DummyServerSettings, JackDummyServer
        from hil.devices.audio.portaudio_backend import rescan_devices
        from sim_devices.stage.on_pty import SimulatedGrblOnPty

        settings = DummyServerSettings(int(self.exp.waveform.fs_hz), self.period)
        try:
            self.server = JackDummyServer(settings).start()
            # The server's periods come at most at real time (slower when a client is late).
            clock = AudioPacedClock(self.period / settings.samplerate, 1.0)
            self.stage = SimulatedGrblOnPty(tank_stage_config(), clock=clock).start()
            rescan_devices()  # PortAudio lists a server started after it loaded only now
            stage = self.stage

            def carriage(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
                return stage.call(lambda g: g.carriage_motion(t))

            self.tank = TankJackClient(self.exp, self.period, carriage, clock).start()
        except BaseException:
            self.close()
            raise
        return self

    @property
    def stage_port(self) -> str:
        """The pty of the tank's GRBL controller."""
        if self.stage is None:
            raise RuntimeError("start() the served tank first")
        return str(self.stage.port_name)

    def write(self, path: Path) -> Path:
        """Write the experiment file of a run on the served tank to ``path``; each run's
        exact truth goes beside it from then on (``truth-run-N.csv``,
        :mod:`hil.experiments.exact_truth`)."""
        path.write_text(served_experiment(self.exp, self.stage_port, self.period), "utf-8")
        if self.tank is not None:
            self.tank.truth_dir = path.parent
        return path

    def close(self) -> None:
        """Stop the tank client, the controller and the server."""
        if self.tank is not None:
            from hil.devices.audio.portaudio_backend import import_sounddevice

            self.tank.close()
            # PortAudio's JACK client must close before its server goes (PortAudio aborts
            # the process at exit otherwise); this process opens no stream after this.
            import_sounddevice()._terminate()
        if self.stage is not None:
            self.stage.close()
        if self.server is not None:
            self.server.close()

    def __enter__(self) -> JackTankServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
