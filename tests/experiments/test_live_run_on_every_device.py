"""The same live-run suite on every DAC/ADC a run can name: the Python simulated board and
the simulated audio interface on virtual time (fast tier), the C reference firmware in the
board's place and the simulated tank behind a JACK server through PortAudio (``hil sim-serve
tank --jack`` in its own process, the run in this one, as a lab with a USB audio interface
runs it) in real time (slow; they need ``cc``/``make``, and ``jackd`` with PortAudio); the
QEMU board's cases skip, saying why (:data:`NOT_RUNNABLE`). Each run starts, streams,
tracks the towed target, stops when its tow is done, records what was connected, and
replays to the same estimates; stopped by its caller, it stops safely and says so; its
board lost mid-run, it stops and names it.

Thresholds are those the device's own tests hold (test_tank_run_virtual,
test_tank_run_audio, test_tank_run_jack): the C firmware runs in real time against the
scaled tank, so its run carries the machine's scheduling in its timing. This module holds
the suite's real-time tank runs with the C firmware as the board (each one costs its pass's
wall time): the completed run here is the one that shows the firmware, behind the tank
through its HAL (``sim_devices.board.c_firmware.CFirmwareBoardOnPty``), completes a run and
tracks.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from hil.environment import environment
from hil.estimation.base import Estimate
from hil.experiments import api
from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from hil.experiments.jack_tank import DEFAULT_PERIOD
from hil.experiments.run_scoring import summarize
from hil.experiments.tank_run import LiveView, RunOutcome, run_experiment
from hil.recording.reader import RunRecording
from tests.experiments.conftest import (
    SHORT_AUDIO_EXPERIMENT,
    SHORT_CLI_EXPERIMENT,
    near_home,
    serve_jack_tank,
)

SHORT = DEFAULT_EXPERIMENT.replace("end_m = -5.0", "end_m = -3.5")
#: SHORT started 0.1 m from home (its run-up from -0.1 m), for the runs stopped mid-pass (by
#: their caller, or their device lost): positioning the carriage 1.4 m out to SHORT's run-up
#: costs about 3.5 s of wall time at time_scale 0.4 before the run streams, and their stop
#: comes within the pass's first metre.
NEAR_HOME = SHORT.replace("start_m = -2.0", "start_m = -0.7")


@dataclass(frozen=True)
class Device:
    """One DAC/ADC of the suite: its experiment ``board`` URL and what a run on it shows."""

    board: str
    virtual_time: bool
    #: The measured loopback, samples: the tank's converters (64) and any buffering; None:
    #: it varies from run to run (:attr:`latency_step` then gives its structure).
    latency_samples: int | None
    range_rmse_m: float
    speed_rmse_mps: float
    detection_rate: float
    #: The recording's instrument group that describes the device.
    group: str
    needs_c: bool = False
    needs_jack: bool = False
    #: With ``latency_samples`` None: the least latency, and the step it comes in, samples.
    latency_min: int = 0
    latency_step: int = 1

    def experiment(self, text: str = SHORT) -> str:
        text = text.replace('board = "sim://board"', f'board = "{self.board}"')
        if self.virtual_time or self.needs_jack:
            return text
        # The simulated tank in real time: slowed to the CPU this machine has to spare now.
        return text.replace("time_scale = 0.4", f"time_scale = {load_time_scale():.3f}")

    def latency_holds(self, latency: int) -> bool:
        """Whether a run's measured loopback ``latency`` (samples) is this device's."""
        if self.latency_samples is not None:
            return latency == self.latency_samples
        return latency >= self.latency_min and (latency - 64) % self.latency_step == 0


#: The built-in experiment's time scale, which the real-time simulated tank (world, C
#: firmware, GRBL twin, receiver: about 1 CPU s per wall s) keeps up with on an idle core.
IDLE_TIME_SCALE = 0.4


def load_time_scale() -> float:
    """The simulated tank's time scale for a real-time run now: :data:`IDLE_TIME_SCALE` times
    the share of a core this process can expect (cores / the 1-minute load average, at most
    1), at least 0.05. A run slower than its capture fills its 8 s ring and fails (measured at
    load 13: 'read more often or enlarge the ring'); slowed as the machine is loaded, the
    run's CPU per wall second stays what an idle core gives."""
    cores = os.cpu_count() or 1
    share = min(1.0, cores / max(os.getloadavg()[0], 1e-9))
    return max(0.05, IDLE_TIME_SCALE * share)


JACK_PERIOD = DEFAULT_PERIOD  # frames, the served JACK tank's
DEVICES = {
    "python-board": Device("sim://board", True, 64, 0.03, 0.05, 1.0, "board"),
    "audio-interface": Device("sim://audio?blocksize=256", True, 64 + 2 * 256, 0.03, 0.05,
                              1.0, "audio"),
    "c-firmware": Device("sim://board?impl=c", False, 64, 0.6, 0.1, 0.9, "board", True),
    # Measured through JACK (test_tank_run_jack, load 7 with the stream 2-26 times slower
    # than the wall clock): range RMSE 0.019 m, speed 0.004 m/s, detection 1.0: the
    # simulated board's thresholds hold. Its loop latency is 2 periods of JACK's round trip,
    # the tank's 2-period pipeline and 64 samples of converters, plus half periods that
    # PortAudio's JACK host API adds when a stream starts on a busy server.
    # JACK runs in real time and varies from run to run (test_tank_run_jack's bounds and
    # measured spread: detection 0.96-1.0, range RMSE 0.009-0.037 m).
    "jack": Device(f"audio://JACK?rate=192000&blocksize={JACK_PERIOD}", False, None, 0.05,
                   0.05, 0.95, "audio", needs_jack=True, latency_min=4 * JACK_PERIOD + 64,
                   latency_step=JACK_PERIOD // 2),
}  # fmt: skip


#: DAC/ADCs a run can name that this suite cannot run on, and why (their cases skip, saying so).
NOT_RUNNABLE = {
    "qemu-mcu": (
        "the C firmware on QEMU's Cortex-M4 offers 16 and 8 kHz, what its emulated UART "
        "carries (tests/board/test_board_qemu_mcu.py), and its analog path is a loopback "
        "cable in software: a tank run needs the waveform's 192 kHz and the tank's echoes"
    ),
}
PARAMS = [
    pytest.param(name, id=name, marks=[] if DEVICES[name].virtual_time else [pytest.mark.slow])
    for name in DEVICES
] + [
    pytest.param(name, id=name, marks=[pytest.mark.skip(reason=why)])
    for name, why in NOT_RUNNABLE.items()
]


def _require(device: Device, require_system: Callable[[bool, str], None]) -> None:
    if device.needs_c:
        from sim_devices.board import c_firmware

        missing = c_firmware.toolchain_missing()
        require_system(missing is None, f"C firmware not buildable: {missing}")
    if device.needs_jack:
        from hil.devices.audio import portaudio_available
        from hil.devices.audio.jack_server import missing_tools

        missing_jack = missing_tools()
        require_system(not missing_jack, f"JACK is not installed ({', '.join(missing_jack)})")
        ok, why = portaudio_available()
        require_system(ok, f"PortAudio is not available: {why}")


@dataclass
class ServedJackTank:
    """``hil sim-serve tank --jack`` running in its own process (the tank's world, its GRBL
    controller on a pty, the JACK server it started), with this process's PortAudio on that
    server: the experiment to run on it, and the process."""

    experiment: str
    process: subprocess.Popen[str]


@contextlib.contextmanager
def served_jack_tank(folder: Path, text: str = SHORT) -> Iterator[ServedJackTank]:
    """Serve the simulated tank on a private JACK server (unique name) for experiment
    ``text`` (its tow), point this process's PortAudio at it, and stop both at the end."""
    import sounddevice

    from hil.devices.audio import rescan_devices

    exp_in = folder / "short.toml"
    exp_in.write_text(text, encoding="utf-8")
    command = [sys.executable, "-m", "hil.cli.main", "sim-serve", "tank", "--jack",
               "--experiment", str(exp_in)]  # fmt: skip
    root = Path(__file__).resolve().parents[2]
    jack_env = environment(
        JACK_DEFAULT_SERVER=f"hil-suite-{os.getpid()}-{uuid.uuid4().hex[:6]}",
        JACK_NO_START_SERVER="1",
    )
    # PortAudio's JACK client closes before its server goes; PortAudio re-opens after.
    terminated = False
    try:
        with jack_env:
            env = dict(
                os.environ,
                PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]),
            )
            with serve_jack_tank(command, env) as (printed, proc):
                try:
                    rescan_devices()  # PortAudio enumerated devices before this server ran
                    yield ServedJackTank(printed.read_text(encoding="utf-8"), proc)
                finally:
                    sounddevice._terminate()
                    terminated = True
    finally:
        if not terminated:
            sounddevice._terminate()
        sounddevice._initialize()


def _experiment(
    name: str, stack: contextlib.ExitStack, folder: Path, text: str = SHORT
) -> tuple[str, ServedJackTank | None]:
    """The experiment ``text`` on device ``name``; for JACK, the served tank's (served until
    ``stack`` closes)."""
    device = DEVICES[name]
    if not device.needs_jack:
        return device.experiment(text), None
    tank = stack.enter_context(served_jack_tank(folder, text))
    assert f'board = "{device.board}"' in tank.experiment
    return tank.experiment, tank


@pytest.fixture(scope="module", params=PARAMS)
def completed(
    request: pytest.FixtureRequest,
    tmp_path_factory: pytest.TempPathFactory,
    require_system: Callable[[bool, str], None],
) -> tuple[Device, RunOutcome]:
    """A whole short run on the device (one per device, shared by the tests below)."""
    device = DEVICES[request.param]
    _require(device, require_system)
    # In real time, the short pass near home (no positioning before it streams).
    virtual = device.virtual_time
    if request.param == "python-board":
        # The same run as test_tank_run_virtual's (SHORT on the Python board on virtual
        # time, no live view): the conftest runs it once for both.
        assert device.experiment() == SHORT_CLI_EXPERIMENT and device.virtual_time
        outcome: RunOutcome = request.getfixturevalue("short_virtual_outcome")
        return device, outcome
    if request.param == "audio-interface":
        # The same run as test_tank_run_audio's on virtual time: the conftest runs it once.
        assert device.experiment() == SHORT_AUDIO_EXPERIMENT and device.virtual_time
        return device, request.getfixturevalue("audio_virtual_cli_run")[2]
    base = tmp_path_factory.mktemp(request.param)
    with contextlib.ExitStack() as stack:
        text, _ = _experiment(request.param, stack, base, SHORT if virtual else near_home(SHORT))
        outcome = run_experiment(
            parse_experiment(text),
            folder=base / "run",
            view=LiveView(enabled=False),
            virtual_time=device.virtual_time,
        )
    return device, outcome


@pytest.mark.slow
def test_a_run_starts_streams_tracks_and_stops_when_its_tow_is_done(
    completed: tuple[Device, RunOutcome],
) -> None:
    device, outcome = completed
    summary = summarize(outcome)
    assert summary["error"] == "" and not summary["interrupted"]
    assert summary["dropped_samples"] == 0
    if device.needs_jack:
        # The synchronous server's late periods are xruns that lose no sample: each one is
        # counted, and recorded as an event.
        kinds = [event[0] for event in outcome.events]
        assert summary["adc_overruns"] == kinds.count("overrun")
        assert summary["dac_underruns"] == kinds.count("underrun")
        # A real interface: nothing simulated counts clipped samples; the callback raises
        # an alarm per clipped block.
        assert summary["adc_clipped_samples"] is None and summary["adc_clipping_alarms"] == 0
    else:
        assert summary["adc_overruns"] == 0
        # Counted by the device itself (the C firmware counts as the Python board does).
        assert summary["adc_clipped_samples"] == 0
    assert device.latency_holds(summary["loopback_latency_samples"])
    assert summary["scored_estimates"] >= 50
    assert summary["detection_rate"] >= device.detection_rate
    assert summary["range_rmse_m"] < device.range_rmse_m
    assert summary["speed_rmse_mps"] < device.speed_rmse_mps
    assert outcome.events[-1][3] == "stop: completed"


@pytest.mark.slow
def test_the_recording_replays_to_the_live_estimates(completed: tuple[Device, RunOutcome]) -> None:
    from hil.recording.replay import compare_estimates, replay

    _, outcome = completed
    with RunRecording.open(outcome.folder / "run.h5") as rec:
        live = rec.estimates()
        agreement, words = compare_estimates(live, replay(rec))
    assert len(live) == len(outcome.estimates) > 50
    assert agreement == "equal", words


def test_the_recording_names_the_device_it_ran_on(completed: tuple[Device, RunOutcome]) -> None:
    import h5py

    from hil.recording.instrument import read_entry

    device, outcome = completed
    with h5py.File(outcome.folder / "run.h5", "r") as f:
        entry = read_entry(f)
    assert entry is not None
    assert entry["instrument"][device.group]["url"] == device.board
    assert entry["instrument"]["stage"]["build_info"].startswith("[VER:1.1h.")


@pytest.mark.slow
@pytest.mark.parametrize("name", PARAMS)
def test_a_run_stopped_by_its_caller_stops_safely_and_says_so(
    name: str, tmp_path: Path, require_system: Callable[[bool, str], None]
) -> None:
    device = DEVICES[name]
    _require(device, require_system)
    folder = tmp_path / "run"
    seen = 0
    with contextlib.ExitStack() as stack:
        text, _ = _experiment(name, stack, tmp_path, NEAR_HOME)
        run: Any = api.iterate(  # a generator: closing it ends the run
            parse_experiment(text), folder=folder, virtual_time=device.virtual_time
        )
        with contextlib.closing(run):  # closing it stops the run as Ctrl-C does, and waits
            for item in run:
                seen += isinstance(item, Estimate)
                if seen == 5:
                    break
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["interrupted"] is True, (seen, summary["error"])
    assert summary["error"] == "interrupted (stopped by the caller)"
    with RunRecording.open(folder / "run.h5") as rec:
        assert rec.events()[-1].text == "stop: interrupted (stopped by the caller)"
        assert len(rec.estimates()) >= 5


@pytest.mark.parametrize("name", PARAMS)
def test_a_board_lost_mid_run_stops_the_run_naming_it(
    name: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    require_system: Callable[[bool, str], None],
) -> None:
    """The Python board's link unplugged (its fault plan), the audio interface pulled out,
    the simulated tank's process that holds the C firmware killed, the JACK server stopped
    (:func:`_jack_server_lost_mid_run`): each after the 30th estimate, mid-pass. The run
    stops and names what it lost."""
    from hil.experiments import audio_tank, sim_tank, virtual_tank

    device = DEVICES[name]
    _require(device, require_system)
    if device.needs_jack:
        _jack_server_lost_mid_run(device, tmp_path)
        return
    tanks: list[Any] = []
    kind: Any = {
        "python-board": virtual_tank.VirtualTank,
        "audio-interface": audio_tank.AudioTank,
        "c-firmware": sim_tank.SimulatedTankProcess,
    }[name]
    original = kind.__init__

    def keep(self: Any, *args: Any, **kwargs: Any) -> None:
        original(self, *args, **kwargs)
        tanks.append(self)

    monkeypatch.setattr(kind, "__init__", keep)
    seen: list[Estimate] = []
    with contextlib.ExitStack() as stack:
        text, _ = _experiment(name, stack, tmp_path, NEAR_HOME)

        def lose_after_30(estimates: list[Estimate]) -> None:
            if len(seen) < 30 <= len(seen) + len(estimates):
                if name == "python-board":
                    tanks[0].board_faults.disconnect()
                elif name == "audio-interface":
                    tanks[0].unplug_interface()
                else:
                    os.kill(tanks[0].pid, signal.SIGKILL)
            seen.extend(estimates)

        outcome = run_experiment(
            parse_experiment(text),
            folder=tmp_path / "run",
            view=LiveView(enabled=False),
            on_estimates=lose_after_30,
            virtual_time=device.virtual_time,
        )
    if name == "python-board":
        assert outcome.error.startswith(
            f"DeviceLostError: board {device.board} lost: its link dropped"
        )
    elif name == "audio-interface":
        assert outcome.error.startswith(
            f"AudioStreamLost: {device.board}: the audio stream ended at sample "
        ), outcome.error
        assert outcome.error.endswith(
            ": check the interface's cable and power (on JACK: that its server still runs),"
            " and that no other program took it"
        )
    else:
        assert outcome.error == (
            f"DeviceLostError: the built-in simulated tank (process {tanks[0].pid}) lost: its"
            " process exited with code -9; check that nothing killed it (its errors are"
            " printed above)"
        )
    assert len(seen) >= 30 and not outcome.interrupted
    with RunRecording.open(outcome.folder / "run.h5") as rec:
        assert rec.events()[-1].text == f"stop: error: {outcome.error}"


#: Deadlock guard for the JACK lost-mid-run child process: its run's short tow takes 20-40 s
#: of wall time at load 2-10; PortAudio's JACK host API, when it hangs, waits 600 s.
JACK_LOST_RUN_TIMEOUT_S = 300.0


def _child_processes(pid: int) -> dict[int, str]:
    """The child processes of ``pid`` and their program names (Linux ``/proc``)."""
    children: dict[int, str] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            cmdline = Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
            children[int(child)] = Path(cmdline[0].decode()).name
    return children


def _jack_server_lost_mid_run(device: Device, folder: Path) -> None:
    """The served tank's JACK server stopped (SIGTERM) after the 30th estimate of a run in
    its own process (:mod:`tests.experiments.jack_lost_run`): the run stops naming the
    interface, records the stream it had to abandon as a disconnect, writes its recording
    and summary, and its process exits. This process keeps PortAudio off that server (its
    JACK client would outlive the server, and terminating PortAudio then aborts)."""
    exp_in = folder / "short.toml"
    exp_in.write_text(NEAR_HOME, encoding="utf-8")
    name = f"hil-suite-{os.getpid()}-{uuid.uuid4().hex[:6]}"
    root = Path(__file__).resolve().parents[2]
    with environment(JACK_DEFAULT_SERVER=name, JACK_NO_START_SERVER="1"):
        env = dict(
            os.environ, PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])
        )
        command = [sys.executable, "-m", "hil.cli.main", "sim-serve", "tank", "--jack",
                   "--experiment", str(exp_in)]  # fmt: skip
        try:
            with serve_jack_tank(command, env) as (printed, proc):
                children = _child_processes(proc.pid)
                jackd = [pid for pid, program in children.items() if program == "jackd"]
                assert len(jackd) == 1, children
                child = subprocess.run(
                    [sys.executable, "-m", "tests.experiments.jack_lost_run", str(printed),
                     str(folder / "run"), str(jackd[0])],
                    capture_output=True, text=True, env=env, timeout=JACK_LOST_RUN_TIMEOUT_S,
                    check=False,
                )  # fmt: skip
        finally:
            # The semaphores of a server's clients outlive it when it stops before they close.
            for leftover in Path("/dev/shm").glob(f"jack_sem.*_{name}_*"):
                leftover.unlink(missing_ok=True)
    assert child.returncode == 0, child.stderr[-3000:]
    result = json.loads(child.stdout.strip().splitlines()[-1])
    error = result["error"]
    assert error.startswith(f"AudioStreamLost: {device.board}: the audio stream ended at sample ")
    assert error.endswith(
        "(on JACK: that its server still runs), and that no other program took it"
    )
    assert result["seen"] >= 30 and not result["interrupted"]
    run = Path(result["folder"])
    summary = json.loads((run / "summary.json").read_text())
    assert summary["error"] == error
    with RunRecording.open(run / "run.h5") as rec:
        events = rec.events()
    assert events[-1].text == f"stop: error: {error}"
    assert events[-2].text == (
        f"disconnect: {device.board}: the stream on 0 'system' (JACK Audio Connection Kit, 2 in,"
        " 2 out): its host ended it without finishing (a JACK server that shut down does this);"
        " stopping or closing it would wait on that host"
    )
    assert "PortAudio stream abandoned: the stream on 0 'system'" in child.stderr
