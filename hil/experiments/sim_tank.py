"""The built-in simulated tank: a simulated GRBL stage and a simulated board on real ptys,
with the acoustic world between them, all on one shared clock.

The towed target moves exactly as the simulated stage's carriage: the world's Live target
position at device sample ``n`` is the stage's true position at the board clock time of that
sample. The clock is scaled (:class:`ScaledClock`): simulated seconds may run slower than wall
seconds (``simulation.time_scale``), so a world that computes slower than real time still
gives a correct run; the host drivers see ordinary devices on ordinary serial ports.

Everything from :mod:`sim_devices` is imported inside the functions (DESIGN: the host never
imports simulated devices at module level).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol
from urllib.parse import parse_qs, urlsplit

import numpy as np

from hil.devices.clock import SleepUntil
from hil.errors import ConfigError
from hil.experiments.experiment import Experiment
from hil.experiments.towed_kernels import towed_positions

if TYPE_CHECKING:
    from hil.acquisition.device import StreamingDevice
    from hil.devices.clock import Clock, VirtualClock
    from hil.devices.grbl import ByteLink
    from hil.experiments.live.stops import DeviceLostError
    from hil.transports.base import Transport

# Simulated GRBL machine for the tank: 2.5 m/s, 2 m/s², 10 m of travel, 80 steps/mm.
STAGE_MAX_RATE_MM_MIN = 150_000.0
STAGE_ACCEL_MM_S2 = 2_000.0
STAGE_TRAVEL_MM = 10_000.0
# DAC reconstruction + ADC anti-alias group delay of the simulated board, samples.
CONVERTER_DELAY_SAMPLES = 64


class ScaledClock(SleepUntil):
    """Seconds that run at ``scale`` times the wall clock (:func:`time.monotonic`), counted
    from the monotonic instant ``wall0`` (default: now). ``time.monotonic`` is system-wide on
    Linux, so two processes given the same ``wall0`` and ``scale`` share one clock."""

    def __init__(self, scale: float, wall0: float | None = None) -> None:
        if not 0 < scale <= 1:
            raise ConfigError("simulation.time_scale", scale, "in (0, 1]")
        self.scale = float(scale)
        self._wall0 = time.monotonic() if wall0 is None else float(wall0)
        self._start = 0.0

    def __call__(self) -> float:
        return self._start + (time.monotonic() - self._wall0) * self.scale

    def now(self) -> float:
        """Current simulated time, s."""
        return self()

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of simulated time pass (``seconds / scale`` of wall time)."""
        if seconds > 0:
            time.sleep(seconds / self.scale)


class TankSimulation(Protocol):
    """The built-in simulated tank as a run uses it: in a child process on real time
    (:class:`SimulatedTankProcess`) or in this process on virtual time
    (:class:`~hil.experiments.virtual_tank.VirtualTank`)."""

    @property
    def clock(self) -> Clock:
        """The clock of the stage, the board and the run."""
        ...

    @property
    def stage_target(self) -> str | ByteLink:
        """What the stage driver opens (a pty path, or an in-memory link)."""
        ...

    def open_daq(self, fs: float) -> StreamingDevice:
        """The run's DAC/ADC in the tank (the simulated board or audio interface), open and
        configured at ``fs`` Hz, on :attr:`clock`."""
        ...

    @property
    def dac_underruns(self) -> int: ...

    @property
    def adc_overruns(self) -> int: ...

    @property
    def adc_clipped_samples(self) -> int | None:
        """ADC values the simulated board clipped (None: the board does not count them)."""
        ...

    def align(self, rate_hz: float) -> None: ...

    def stage_time(self, world_t: np.ndarray) -> np.ndarray: ...

    def true_stage_position(self, clock_t: np.ndarray) -> np.ndarray: ...

    def lost(self, grace_s: float = 0.0) -> DeviceLostError | None: ...

    def close(self) -> None: ...


@dataclass
class SimulatedTank:
    """The running simulated devices; ``board_port``/``stage_port`` are pty paths."""

    board_port: str
    stage_port: str
    clock: ScaledClock
    board_sim: Any
    stage_sim: Any
    world: Any
    _offset: list[float] = field(default_factory=lambda: [0.0])
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def align_world_time(self, rate_hz: float) -> None:
        """Tie world time (device sample / rate) to the shared clock after CONFIGURE."""
        now = self.clock()
        index = self.board_sim.call(lambda b: b.sample_index(now))
        self._offset[0] = now - index / rate_hz

    def stage_time(self, world_t: np.ndarray) -> np.ndarray:
        """Shared-clock time (s) of world times (s)."""
        return np.asarray(world_t, dtype=np.float64) + self._offset[0]

    def true_stage_position(self, clock_t: np.ndarray) -> np.ndarray:
        """The simulated carriage's true position (m) at shared-clock times (s)."""
        t = np.asarray(clock_t, dtype=np.float64)
        return np.asarray(self.stage_sim.call(lambda g: g.true_position(t)))

    def close(self) -> None:
        """Stop both simulated devices."""
        for sim in (self.board_sim, self.stage_sim):
            with contextlib.suppress(Exception):  # best effort at shutdown
                sim.close()


def tank_stage_config() -> Any:
    """The simulated tank's GRBL controller (a ``sim_devices.stage.config.GrblSimConfig``):
    a fast 10 m axis with homing, soft and hard limits on, powered up in ALARM 20 mm from
    home, so a run homes it first."""
    from sim_devices.stage.config import GrblSimConfig

    return GrblSimConfig(
        steps_per_mm=80.0,
        max_rate_mm_min=STAGE_MAX_RATE_MM_MIN,
        acceleration_mm_s2=STAGE_ACCEL_MM_S2,
        max_travel_mm=STAGE_TRAVEL_MM,
        homing=True,
        soft_limits=True,
        hard_limits=True,
        status_mask=3,  # MPos and Bf
        homing_seek_mm_min=6000.0,
        homing_feed_mm_min=600.0,
        homing_debounce_ms=0,  # optical switches: no bounce to wait out
        homing_cycles=("X",),  # one carriage axis: GRBL built with HOMING_CYCLE_0 = X
        switch_axes="X",
        power_up_position_mm=-20.0,
        host_silence_timeout_s=5.0,
    )


class _TowedTarget:
    """The towed target's position (m, tank frame, shape ``(n, 3)``) at channel times ``t``
    (s from the world's first block), following the carriage.

    Every echo path and every fixed-point iteration asks for positions over the same block:
    the carriage is sampled once per block on a 1 ms grid, with its velocity, and filled in
    by a cubic Hermite, exact in its constant-speed and constant-acceleration phases (a
    piecewise-linear fill would put a corner every millisecond, and the echo's delay grid
    solves every interval holding a corner sample by sample).
    """

    GRID_S = 1e-3

    def __init__(
        self,
        exp: Experiment,
        carriage_motion: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    ) -> None:
        self.exp = exp
        self.motion = carriage_motion
        self.fs = float(exp.waveform.fs_hz)
        #: The world whose first block is channel time 0 (set once it exists).
        self.world: Any = None
        self._grid = np.zeros(0)
        self._x = self._v = np.zeros(0)
        self._origin = np.asarray(exp.stage_origin_m, dtype=np.float64)
        self._axis = np.asarray(exp.stage_axis, dtype=np.float64)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        origin = self.world.origin_index or 0
        tq = np.asarray(t, dtype=np.float64) + origin / self.fs  # device sample time
        lo, hi = float(tq.min()), float(tq.max())
        h = self.GRID_S
        if self._grid.size == 0 or lo < self._grid[0] or hi > self._grid[-1]:
            self._grid = np.arange(np.floor(lo / h) - 2, np.ceil(hi / h) + 3) * h
            x, v = self.motion(self._grid)
            self._x = np.ascontiguousarray(x, dtype=np.float64)
            self._v = np.ascontiguousarray(v, dtype=np.float64)
        # One compiled pass: _hermite then Experiment.target_position, the same bits.
        out = np.empty((tq.size, 3))
        towed_positions(
            tq.reshape(-1), self._grid, h, self._x, self._v, self._origin, self._axis, out
        )
        return out.reshape(*tq.shape, 3)


def _ambient(exp: Experiment, source_level_db: float) -> Any:
    """The noise and volume reverberation of the tank (a ``sim_devices`` channel built from
    a scenario: its ``reverberation``, ``noise`` and ``noise_scale``)."""
    from sim_devices.acoustics.scenario import build_channel, parse_scenario

    sim = exp.simulation
    scenario: dict[str, Any] = {
        "preset": exp.preset,
        "family": exp.waveform.family,
        "fs_hz": float(exp.waveform.fs_hz),
        "seed": sim.seed,
        "environment": {"sound_speed_mps": exp.sound_speed_mps},
        "sonar": {
            "position_m": list(exp.transducer_m),
            "source_level_db": source_level_db,
            "sensitivity_db": sim.sensitivity_db,
            "gain_db": sim.gain_db,
        },
        "noise": {"self_noise_db": sim.noise_level_db},
    }
    if sim.reverberation:
        scenario["reverberation"] = {
            "scattering_strength_db": sim.scattering_strength_db,
            "density_per_m3": 20.0,
            "min_range_m": 0.3,
            "max_range_m": float(np.sqrt(sum(s * s for s in exp.tank_size_m))),
        }
    return build_channel(parse_scenario(scenario))


def build_tank_world(
    exp: Experiment,
    carriage_motion: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    *,
    with_target: bool = True,
) -> Any:
    """The acoustic tank of ``exp`` behind the simulated board (a
    ``sim_devices.acoustics.dac_world.ScheduleWorld``: DAC block in, 2 ADC channels out).

    ``carriage_motion(t)``: the simulated carriage's position (m, stage coordinates) and
    velocity (m/s) at world times ``t`` (s: device sample / rate, from the world's first
    block); the towed target follows it through :meth:`Experiment.target_position`.
    ``with_target=False``: the empty tank (the target taken out; everything else the same),
    what a background capture records.
    """
    from sim_devices.acoustics.channel import Channel, DirectBlast, Receiver, Target
    from sim_devices.acoustics.dac_world import ScheduleWorld
    from sim_devices.acoustics.tank import Tank
    from sim_devices.acoustics.tank_response import TankEchoSettings
    from sim_devices.acoustics.trajectory import Fixed, Live

    sim = exp.simulation
    fs = float(exp.waveform.fs_hz)
    target = _TowedTarget(exp, carriage_motion)
    live = Live(target, max_speed_mps=STAGE_MAX_RATE_MM_MIN / 60_000.0)
    receiver = Receiver(sensitivity_db=sim.sensitivity_db, gain_db=sim.gain_db, full_scale_v=1.0)
    # The DAC plays the schedule at ``amplitude`` of full scale: that sets the source level.
    source_level = sim.source_level_db + 20.0 * float(np.log10(exp.amplitude))
    ambient = _ambient(exp, source_level)
    delay = CONVERTER_DELAY_SAMPLES
    # Exact echoes of the transmitted schedule; the converter latency delays everything.
    channel = Channel(
        exp.schedule.shifted(delay / fs),
        fs,
        Fixed(exp.transducer_m),
        source_level,
        exp.sound_speed_mps,
        targets=[Target(live, sim.target_strength_db)] if with_target else [],
        receiver=receiver,
        tank=Tank(
            *exp.tank_size_m,
            wall_reflection=sim.wall_reflection,
            bottom_reflection=sim.bottom_reflection,
        ),
        image_order=sim.image_order,
        tank_echoes=(
            TankEchoSettings(order=sim.tank_echo_order, tail=sim.late_tail, seed=sim.seed + 7)
            if sim.tank_echoes
            else None
        ),
        tx_beam=_transducer(exp, sim.transducer_beam, sim.transducer_radius_m),
        rx_beam=_transducer(exp, sim.hydrophone_beam, sim.hydrophone_radius_m),
        direct_blast=DirectBlast(coupling_db=-80.0, separation_m=0.05),
        reverberation=ambient.reverberation,
        noise=ambient.noise,
        noise_scale=ambient.noise_scale,
    )
    target.world = ScheduleWorld(channel, converter_delay_samples=delay, adc_channels=2)
    return target.world


#: Stretch of the simulated ADC input rendered to plan the levels, s (past the tank's longest
#: echo delay; the own echoes and tail are steady from the first sample).
PLAN_SPAN_S = 0.05


def planned_adc_peak_fs(exp: Experiment) -> float:
    """The largest ADC input (full-scale units, 1 = the converter's full scale) the built-in
    tank of ``exp`` produces with the target at the tow's closest point: echoes, the tank's
    own echoes and tail, direct blast, reverberation and noise over :data:`PLAN_SPAN_S`
    after the longest echo delay. Above 1 the run's ADC clips."""
    x_near = max(exp.tow.start_m, exp.tow.end_m, key=lambda x: -float(
        np.linalg.norm(exp.target_position(np.array([x]))[0] - np.asarray(exp.transducer_m))
    ))  # fmt: skip

    def parked(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.full(t.shape, float(x_near)), np.zeros(t.shape)

    world = build_tank_world(exp, parked)
    world.origin_index = 0
    fs = float(exp.waveform.fs_hz)
    settle = int(np.ceil(2.0 * np.sqrt(sum(s * s for s in exp.tank_size_m)) * 2 / 1400.0 * fs))
    channel = world.channel
    channel.read_components(settle, clip=False)
    span = channel.read_components(int(PLAN_SPAN_S * fs), clip=False)["input_fs"]
    peak = float(np.max(np.abs(span)))
    return peak


def beam_axis(exp: Experiment) -> np.ndarray:
    """The simulated transducers' axis (unit vector): from the transducer towards the towed
    target's position at stage x = 0 (``tank.stage_origin_m``), along the tow line."""
    d = np.asarray(exp.stage_origin_m, dtype=float) - np.asarray(exp.transducer_m, dtype=float)
    norm = float(np.sqrt(d @ d))
    return d / norm if norm > 0 else np.asarray(exp.stage_axis, dtype=float)


def _transducer(exp: Experiment, kind: str, radius_m: float) -> Any:
    """A ``sim_devices`` transducer of ``kind`` (omni, or a piston of ``radius_m`` at the
    waveform's centre frequency) on :func:`beam_axis`."""
    from sim_devices.acoustics.beam import OmniBeam, PistonBeam
    from sim_devices.acoustics.directivity import Transducer

    pattern: Any = OmniBeam()
    if kind == "piston":
        pattern = PistonBeam.from_radius(
            radius_m, float(exp.waveform.center_hz), float(exp.sound_speed_mps)
        )
    return Transducer(pattern, beam_axis(exp))


def _hermite(t: np.ndarray, grid: np.ndarray, x: np.ndarray, v: np.ndarray, h: float) -> np.ndarray:
    """Cubic Hermite through positions ``x`` and velocities ``v`` on the uniform ``grid``
    (spacing ``h`` s), at times ``t`` inside it."""
    k = np.clip(((t - grid[0]) / h).astype(np.int64), 0, grid.size - 2)
    s = (t - grid[k]) / h
    s2 = s * s
    s3 = s2 * s
    return (
        (2 * s3 - 3 * s2 + 1) * x[k]
        + (s3 - 2 * s2 + s) * h * v[k]
        + (-2 * s3 + 3 * s2) * x[k + 1]
        + (s3 - s2) * h * v[k + 1]
    )


def start_simulated_tank(exp: Experiment, wall0: float | None = None) -> SimulatedTank:
    """Start the simulated stage and board for ``exp`` (in this process) and return them."""
    from sim_devices.board import SimulatedBoardOnPty
    from sim_devices.stage.on_pty import SimulatedGrblOnPty

    clock = ScaledClock(exp.simulation.time_scale, wall0)
    stage_sim = SimulatedGrblOnPty(tank_stage_config(), clock=clock).start()
    holder: dict[str, SimulatedTank] = {}

    def carriage_motion(world_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = holder["tank"].stage_time(world_t)
        return stage_sim.call(lambda g: g.carriage_motion(t))

    world = build_tank_world(exp, carriage_motion)
    # Ticks of 100 ms wall: the world computes whole frames, not a few samples per call.
    # ``sim://board?impl=c`` puts the C reference firmware in the Python board's place.
    if parse_qs(urlsplit(exp.board_url).query).get("impl", ["python"])[0] == "c":
        from sim_devices.board.c_firmware import CFirmwareBoardOnPty

        board_sim: Any = CFirmwareBoardOnPty(clock=clock, world=world, poll_interval=0.1)
    else:
        board_sim = SimulatedBoardOnPty(clock=clock, world=world, poll_interval=0.1)
    board_sim.start()
    tank = SimulatedTank(
        board_sim.port_name, stage_sim.port_name, clock, board_sim, stage_sim, world
    )
    holder["tank"] = tank
    return tank


class SimulatedTankProcess:
    """The simulated tank in a child process (its own core and interpreter: the acoustic
    world does not compete with the host's capture and estimator for the GIL).

    The child prints the two pty paths; the host shares its clock (same ``wall0`` and
    scale). :meth:`align` ties world time to the clock after the board is configured;
    :meth:`close` stops the child, which then writes the simulated carriage's true
    trajectory (1 ms grid) for the exact-truth check.
    """

    def __init__(self, exp: Experiment, experiment_file: Path, folder: Path) -> None:
        import json
        import subprocess
        import sys

        self.clock = ScaledClock(exp.simulation.time_scale)
        self.folder = folder
        self._offset = 0.0
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "hil.experiments.sim_tank", str(experiment_file),
             repr(self.clock._wall0), str(folder)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert self._proc.stdout is not None
        line = self._proc.stdout.readline()
        if not line:
            raise RuntimeError("the simulated tank process did not start")
        ports = json.loads(line)
        self.board_port: str = ports["board"]
        self.stage_port: str = ports["stage"]
        self.board_target: str | Transport = self.board_port
        self.stage_target: str | ByteLink = self.stage_port
        self.virtual_time: VirtualClock | None = None
        self._trajectory: tuple[np.ndarray, np.ndarray] | None = None
        self.dac_underruns = 0
        self.adc_overruns = 0
        self.adc_clipped_samples: int | None = None

    def _ask(self, text: str) -> str:
        assert self._proc.stdin is not None and self._proc.stdout is not None
        self._proc.stdin.write(text + "\n")
        self._proc.stdin.flush()
        return self._proc.stdout.readline().strip()

    @property
    def pid(self) -> int:
        """The child process's id."""
        return self._proc.pid

    def exit_code(self) -> int | None:
        """The child's exit code once it ended (negative: killed by that signal), else None."""
        return self._proc.poll()

    def lost(self, grace_s: float = 0.0) -> DeviceLostError | None:
        """The child process, if it ended under the run.

        ``grace_s`` (s): how long to wait for its exit when a link to it already failed.
        A killed process hangs up its ptys while the kernel tears it down, a moment before
        it can be reaped; without the wait the run would blame the link, not the tank.
        """
        from subprocess import TimeoutExpired

        from hil.experiments.live.stops import DeviceLostError

        code = self.exit_code()
        if code is None and grace_s > 0:
            try:
                code = self._proc.wait(timeout=grace_s)
            except TimeoutExpired:
                code = None
        if code is None:
            return None
        return DeviceLostError(
            "the built-in simulated tank",
            f"(process {self.pid})",
            f"its process exited with code {code}",
            "that nothing killed it (its errors are printed above)",
        )

    def open_daq(self, fs: float) -> StreamingDevice:
        """The simulated board on its pty, open and configured at ``fs`` Hz; its watchdog
        is long (:data:`~hil.devices.table.SIM_WATCHDOG_MS`): the tank is a
        child process on the same CPUs, scaled in time."""
        from hil.devices.table import SIM_WATCHDOG_MS, open_board

        board = open_board(self.board_target, fs, self.clock, SIM_WATCHDOG_MS)
        board.configure()
        return board

    def align(self, rate_hz: float) -> None:
        """Tie world time to the shared clock (after CONFIGURE)."""
        self._offset = float(self._ask(f"align {rate_hz!r}"))

    def stage_time(self, world_t: np.ndarray) -> np.ndarray:
        """Shared-clock time (s) of world times (s)."""
        return np.asarray(world_t, dtype=np.float64) + self._offset

    def close(self) -> None:
        """Stop the child and load the carriage trajectory it wrote."""
        import json

        if self._proc.poll() is None:
            with contextlib.suppress(Exception):
                counters = json.loads(self._ask("stop"))
                self.dac_underruns = int(counters.get("dac_underruns", 0))
                self.adc_overruns = int(counters.get("adc_overruns", 0))
                clipped = counters.get("adc_clipped_samples")
                self.adc_clipped_samples = None if clipped is None else int(clipped)
            with contextlib.suppress(Exception):
                self._proc.wait(timeout=10)
            if self._proc.poll() is None:
                self._proc.kill()
                self._proc.wait(timeout=10)
        for pipe in (self._proc.stdin, self._proc.stdout):
            if pipe is not None:
                with contextlib.suppress(Exception):
                    pipe.close()
        path = self.folder / "sim_stage_trajectory.npz"
        if path.exists():
            data = np.load(path)
            self._trajectory = (data["t"], data["x"])

    def true_stage_position(self, clock_t: np.ndarray) -> np.ndarray:
        """The simulated carriage's true position (m) at shared-clock times (s)."""
        if self._trajectory is None:
            raise RuntimeError("the trajectory is read after close()")
        t, x = self._trajectory
        return np.asarray(np.interp(np.asarray(clock_t, dtype=float), t, x))


def _serve(argv: list[str]) -> int:
    """Child process: run the simulated tank until told to stop (see SimulatedTankProcess)."""
    import json
    import signal
    import sys

    from hil.experiments.experiment import load_experiment

    # Ctrl-C in the terminal reaches the whole process group: the host decides when the
    # simulated tank stops (it sends "stop" after holding the stage and stopping the board).
    # So do SIGTERM and SIGHUP sent to the group: the host stops safely on them, then stops
    # the tank; a host that dies closes this process's stdin, which ends it too.
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
    exp = load_experiment(Path(argv[0]))
    wall0 = float(argv[1])
    folder = Path(argv[2])
    tank = start_simulated_tank(exp, wall0)
    t_first = tank.clock()
    print(json.dumps({"board": tank.board_port, "stage": tank.stage_port}), flush=True)
    for line in sys.stdin:
        word, _, arg = line.strip().partition(" ")
        if word == "align":
            tank.align_world_time(float(arg))
            print(repr(tank._offset[0]), flush=True)
        elif word == "stop":
            counters = {
                "dac_underruns": int(tank.board_sim.call(lambda b: b.dac_underruns)),
                "adc_overruns": int(tank.board_sim.call(lambda b: b.adc_overruns)),
                "adc_clipped_samples": int(tank.board_sim.call(lambda b: b.adc_clipped_samples)),
            }
            t_end = tank.clock()
            grid = np.arange(t_first, t_end + 1e-3, 1e-3)
            np.savez(folder / "sim_stage_trajectory.npz", t=grid,
                     x=tank.true_stage_position(grid))  # fmt: skip
            tank.close()
            print(json.dumps(counters), flush=True)
            return 0
    tank.close()
    return 0


if __name__ == "__main__":  # pragma: no cover - the child process entry point
    import sys

    sys.exit(_serve(sys.argv[1:]))
