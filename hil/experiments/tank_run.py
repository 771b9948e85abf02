"""The towed-target tank run: waveform out, a towed pass on the stage, the estimator live,
the stage as ground truth, everything recorded.

Order of work (each step refuses with a clear message before the next touches anything):

1. the experiment file is validated (:mod:`hil.experiments.experiment`), the run folder is
   new (:func:`~hil.experiments.live.plan.new_run_folder`);
2. preflight without devices: calibrations required by the file present and recent; the
   receiver built (its compiled kernels loaded);
3. devices opened (:mod:`hil.experiments.live.devices`): the stage's limits read and the
   whole tow checked against them before homing, the board configured, then the stage
   homed and positioned;
4. continuous transmission starts, capture streams into the recording and into the same
   receiver path used offline, the stage makes its passes
   (:mod:`hil.experiments.live.session`);
5. a clean stop on completion, Ctrl-C, SIGTERM/SIGHUP, a lost device or any error:
   transmission off, stage held, the stop recorded as an event, files closed; then the
   telemetry mapped onto sample time and the outcome returned.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as dt
import logging
import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from hil.acquisition import HeapFreeze
from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.experiments.experiment import Experiment
from hil.experiments.live.board_state import (
    board_stopped,
    collect_sync_pairs,
    run_event,
    sample_index_at,
    stamped_in_callback,
    xrun_counts,
    xruns_since,
)
from hil.experiments.live.devices import RunDevices, refuse_mixed_devices
from hil.experiments.live.plan import new_run_folder
from hil.experiments.live.recorder import RunRecorder
from hil.experiments.live.session import LiveSession, SessionTiming, Telemetry
from hil.experiments.live.snapshot import instrument_snapshot
from hil.experiments.live.stops import RunInterrupted, StopSignals, stop_text
from hil.experiments.run_calibrations import RunCalibrations, load_run_calibrations
from hil.interrupts import interruption, interruption_behind
from hil.outputs import release_output_folder
from hil.recording.records import ReceiverSetup, RunEvent
from hil.recording.replay import build_receiver
from hil.signals.schedule_file import schedule_document

if TYPE_CHECKING:
    from hil.experiments.sim_tank import TankSimulation

_LOG = logging.getLogger(__name__)

#: Stage status polled every this many seconds of the driver clock (GRBL's 5 Hz).
STAGE_POLL_S = 0.2
#: Reports that took longer than this (s) to answer their query are left out of the truth:
#: the stage sampled its position somewhere in that time. A prompt reply measures up to
#: ~60 ms: GRBL answers at once, a USB serial adapter holds a short report up to its 16 ms
#: latency timer, and the driver reads every 20 ms with 20 ms sleeps between.
TELEMETRY_MAX_REPLY_S = 0.08
#: The live loop's cadence: 10 ms capture blocks, 5 Hz stage polls, 0.3 s of capture kept
#: after the stage stops (the last echoes still arrive), 50 ms waits for samples.
TIMING_BLOCK_S, TIMING_TAIL_S, TIMING_WAIT_S = 0.01, 0.3, 0.05
_INT16_SCALE = 1.0 / 32768.0


_LOG = logging.getLogger("hil.run")


@dataclass
class RunOutcome:
    """What a run produced (the report is built from it)."""

    folder: Path
    experiment: Experiment
    fs_hz: float
    start_index: int
    samples: int
    estimates: list[Estimate]
    telemetry: Telemetry
    dropped_samples: int
    dac_underruns: int
    adc_overruns: int
    events: list[tuple[str, int, int, str]]
    wall_s: float
    signal_s: float
    #: Constant-speed windows the stage driver predicted for each pass (driver clock, s): they
    #: tell the run when a pass is over; scoring uses what the telemetry saw (scored_mask).
    windows: list[tuple[float, float]]
    exact_truth: dict[str, np.ndarray] | None = None
    map_times: list[np.ndarray] = field(default_factory=list)
    map_power: list[np.ndarray] = field(default_factory=list)
    interrupted: bool = False
    error: str = ""
    latency_samples: int | None = None
    #: ADC values the simulated board clipped (None: a real device, or not counted).
    adc_clipped_samples: int | None = None
    #: Peak ADC input (full scale) the simulated world predicts before the run; > 1 clips.
    planned_adc_peak_fs: float | None = None
    #: Most the capture loop fell behind the board (samples held but not yet recorded and
    #: estimated), s of signal. The board's ring holds 8 s: past that, samples are lost.
    capture_backlog_max_s: float = 0.0
    #: The required calibrations the run applied (see :mod:`hil.experiments.run_calibrations`).
    calibrations: RunCalibrations = field(default_factory=RunCalibrations)


class LiveView:
    """One status line, redrawn in place on a terminal, or a line a second in a log."""

    def __init__(self, stream: TextIO | None = None, enabled: bool = True) -> None:
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.tty = self.stream.isatty()
        self._last = 0.0

    def update(self, text: str, *, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if self.tty:
            if force or now - self._last >= 0.1:
                self.stream.write("\r" + text[:150].ljust(150))
                self.stream.flush()
                self._last = now
        elif force or now - self._last >= 1.0:
            self.stream.write(text + "\n")
            self.stream.flush()
            self._last = now

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()


class CodewordMaps:
    """The GCAS receiver's time-codeword map as the run goes (for the report's figure),
    kept up to :data:`MAX_POINTS` points: ``times`` (s) and ``power`` arrays per call."""

    MAX_POINTS = 400_000

    def __init__(self) -> None:
        self.times: list[np.ndarray] = []
        self.power: list[np.ndarray] = []
        self._points = 0

    def on_map(self, t_s: np.ndarray, p: np.ndarray, speed: np.ndarray) -> None:
        if self._points < self.MAX_POINTS:
            self.times.append(np.asarray(t_s, dtype=float).copy())
            self.power.append(np.asarray(p, dtype=np.float32).copy())
            self._points += len(self.times[-1])

    def hooks(self, receiver: str) -> dict[str, Any]:
        """The receiver options that feed it (GCAS only)."""
        return {"on_map": self.on_map} if receiver in ("gcas", "gcas-mti", "gcas-bg") else {}


def receiver_setup(exp: Experiment) -> ReceiverSetup:
    """The live receiver's setup: its settings as the recording keeps them for replay."""
    settings = {
        "sound_speed_mps": exp.sound_speed_mps,
        "max_speed_mps": exp.max_speed_mps,
        "max_range_m": exp.max_range_m,
        "m_hops": exp.m_hops,
        **exp.receiver_options,
    }
    return ReceiverSetup(exp.receiver, settings, channel=exp.board_channel, scale=_INT16_SCALE)


def _recording_options(
    exp: Experiment, fs: float, setup: ReceiverSetup, cals: RunCalibrations
) -> dict[str, Any]:
    """:meth:`~hil.recording.RunWriter.create` options of the run's recording (but its
    origin, known once the loopback latency is measured)."""
    doc = schedule_document(
        exp.schedule,
        fs,
        0.0,
        sound_speed_mps=exp.sound_speed_mps,
        amplitude=exp.amplitude,
        spec=exp.waveform.to_dict(),
    )
    return {
        "fs_hz": fs,
        "n_channels": 2,
        "dtype": "int16",
        "schedule_document": doc,
        "receiver": setup,
        "experiment_toml": exp.text,
        "calibration_ids": list(cals.ids),
        "title": exp.name,
    }


@dataclass
class _Ending:
    """How the run ended: interrupted (Ctrl-C, a stop signal) and/or the error's text."""

    interrupted: bool = False
    error: str = ""


def run_experiment(
    exp: Experiment,
    *,
    folder: Path | None = None,
    view: LiveView | None = None,
    on_estimates: Callable[[list[Estimate]], None] | None = None,
    stop: threading.Event | None = None,
    virtual_time: bool = False,
) -> RunOutcome:
    """Run ``exp`` end to end (see the module docstring) and return what it produced.

    Raises ConfigError for problems found before anything transmits. Once transmission
    has started, every failure (a ConfigError too) stops the run safely and is reported in
    :attr:`RunOutcome.error`, with what was recorded until then.

    ``on_estimates`` gets the receiver's estimates as they come (on the run's thread);
    setting ``stop`` (from any thread) stops the run as Ctrl-C does. ``virtual_time`` runs
    the built-in simulated tank in this process on virtual time
    (:mod:`hil.experiments.virtual_tank`: deterministic, as fast as the CPU allows).
    """
    fs = float(exp.waveform.fs_hz)
    if fs != int(fs):
        raise ConfigError("waveform.fs_hz", fs, "a whole number of Hz (a board rate)")
    cals = load_run_calibrations(exp, fs)  # checked before anything is touched
    exp = cals.apply(exp)
    folder = new_run_folder(exp.output_dir, exp.name, folder, dt.datetime.now())
    try:
        return _run_in_folder(
            exp, folder, fs, cals, view or LiveView(), on_estimates, stop, virtual_time
        )
    finally:
        release_output_folder(folder)


def _run_in_folder(
    exp: Experiment,
    folder: Path,
    fs: float,
    cals: RunCalibrations,
    view: LiveView,
    on_estimates: Callable[[list[Estimate]], None] | None,
    stop: threading.Event | None,
    virtual_time: bool,
) -> RunOutcome:
    """:func:`run_experiment` in its claimed ``folder``: the receiver built, the devices
    opened, the run and its safe stop; the outcome."""
    # The receiver first: building it loads (on a fresh install: compiles) its kernels, tens
    # of seconds that, with the board streaming, would overflow the capture ring.
    view.update("receiver: loading its compiled kernels (a first run compiles them)", force=True)
    maps = CodewordMaps()
    exp = with_background(exp, folder)
    setup = receiver_setup(exp)
    receiver = build_receiver(setup, exp.schedule, fs, **maps.hooks(exp.receiver))
    planned = _planned_levels(exp, view)
    wall0 = time.monotonic()  # the run's wall time, without that set-up
    devices = RunDevices(virtual_time=virtual_time)
    recorder = RunRecorder(folder / "run.h5", _recording_options(exp, fs, setup, cals))
    ending = _Ending()
    session: LiveSession | None = None
    # Set-up done (the receiver's kernels and tables, SciPy, numba): its objects go out of the
    # collector's full passes before any device opens, not once one is open. The collection
    # before the freeze holds the GIL for about 0.1 s of CPU, which a loaded machine
    # stretches past a second of wall time (a tenth of a core at load 16 on 2 cores): with
    # a board open, its keepalives would stop for that long and its watchdog stop the stream.
    # On virtual time nothing streams while it runs: the pass is left out (HeapFreeze).
    with StopSignals() as signals, HeapFreeze(collect=not virtual_time):
        try:
            tow = devices.open(exp, folder, fs, view)
            board, stage, _ = devices.opened()
            recorder.describe(instrument_snapshot(board, exp.board_url, stage, exp.stage_url))
            timing = SessionTiming(
                max(256, round(TIMING_BLOCK_S * fs)),
                STAGE_POLL_S,
                TIMING_TAIL_S,
                TIMING_WAIT_S,
                _INT16_SCALE,
            )
            session = LiveSession(exp, devices, tow, receiver, recorder, cals, timing, view.update)
            session.on_estimates = on_estimates
            _transmit_and_tow(session, exp.max_duration_s, stop)
        except KeyboardInterrupt as exc:
            how = interruption(exc)
            ending = _Ending(True, f"interrupted ({how})")
        except ConfigError as exc:
            if session is None or not session.transmitting:
                raise  # found before anything transmits: the file or the set-up is wrong
            # Once transmitting, a refusal is a failure of the run: stop safely, report it.
            ending = _Ending(False, f"ConfigError: {exc}")
        except Exception as exc:  # any failure: stop safely below, report it
            stopped = interruption_behind(exc)
            cause = devices.cause_of(exc)
            ending = (
                _Ending(True, f"interrupted ({interruption(stopped)})")
                if stopped is not None
                else _Ending(False, f"{type(cause).__name__}: {cause}")
            )
        finally:
            signals.stopping()  # a second signal must not break off the safe stop
            view.close()
            refused = sys.exc_info()[0] is not None  # a refusal before transmitting, raised
            devices.safe_stop(hold=ending.interrupted or bool(ending.error) or refused)
            with contextlib.suppress(Exception):
                recorder.flush()
            if refused and devices.tank is not None:
                devices.tank.close()  # no outcome follows: stop the simulated tank here
        outcome = _outcome(exp, folder, fs, cals, devices, recorder, session, maps, ending, wall0)
        outcome.planned_adc_peak_fs = planned
        if signals.ignored:
            _LOG.warning(
                "ignored during the safe stop, which had to finish: %s", ", ".join(signals.ignored)
            )
        return outcome


#: ``[receiver] options.background`` of a ``gcas-bg`` run on the built-in simulated tank:
#: capture the empty tank before the run (docs/tank-run.md, "Empty-tank background").
SIMULATED_BACKGROUND = "simulated"


def with_background(exp: Experiment, folder: Path) -> Experiment:
    """``exp`` with its ``gcas-bg`` receiver's background ready: ``background =
    "simulated"`` captures the built-in tank's empty tank
    (:func:`~hil.experiments.calibration.background.simulated_background`) into the run
    folder's ``background.npy`` and names that file instead (so the recording's receiver
    settings, and a replay, find it); refused with real devices, whose background is a
    capture of the real tank. Other receivers and given paths: ``exp`` unchanged."""
    if exp.receiver != "gcas-bg":
        return exp
    given = exp.receiver_options.get("background")
    if given != SIMULATED_BACKGROUND:
        return exp
    refuse_mixed_devices(exp)  # before the background's own rule: the pair is the error
    if not exp.simulated:
        raise ConfigError(
            "receiver.options.background",
            given,
            "the path of an empty-tank capture (.npy) with real devices",
            "record the tank with the target out of the beam and average it: "
            "hil docs tank-run, 'Empty-tank background'",
        )
    from hil.experiments.calibration.background import save_background, simulated_background

    path = save_background(folder / "background.npy", simulated_background(exp))
    options = {**exp.receiver_options, "background": str(path.resolve())}
    return dataclasses.replace(exp, receiver_options=options)


def _planned_levels(exp: Experiment, view: LiveView) -> float | None:
    """The simulated tank's peak ADC input (full scale) planned before the run, with a
    warning when it would clip; None for real devices (no model of their water)."""
    if not (exp.board_url.startswith("sim://") and exp.stage_url.startswith("sim://")):
        return None
    from hil.experiments.sim_tank import planned_adc_peak_fs

    peak = planned_adc_peak_fs(exp)
    if peak > 1.0:
        text = (
            f"warning: the planned levels clip the ADC: peak input {peak:.2f} × full scale at"
            " the tow's closest point (simulation.source_level_db, waveform.amplitude,"
            " simulation.gain_db): lower one by "
            f"{20.0 * math.log10(peak):.1f} dB or more"
        )
        _LOG.warning("%s", text)
        view.update(text, force=True)
    return peak


def _transmit_and_tow(
    session: LiveSession, max_duration_s: float, stop: threading.Event | None
) -> None:
    """Transmission on, then capture and tow until done; raises what stops the run."""
    board = session.board
    # The xrun counters before transmission (a board counts since it powered up); without a
    # status before the start, the first one is the baseline.
    if board.last_status is not None:
        session.xruns_before = xrun_counts(board.last_status)
    session.transmit()

    def checks() -> None:
        if stop is not None and stop.is_set():
            raise RunInterrupted("stopped by the caller")
        if session.xruns_before is None and board.last_status is not None:
            session.xruns_before = xrun_counts(board.last_status)
        lost = session.lost()
        if lost is not None:
            raise lost
        stopped = board_stopped(board)
        if stopped is not None:
            raise RuntimeError(stopped)

    session.run(session.now() + max_duration_s, checks)


def _event_tuple(event: RunEvent) -> tuple[str, int, int, str]:
    return (event.kind, event.sample_index, event.length, event.text)


def _outcome(
    exp: Experiment,
    folder: Path,
    fs: float,
    cals: RunCalibrations,
    devices: RunDevices,
    recorder: RunRecorder,
    session: LiveSession | None,
    maps: CodewordMaps,
    ending: _Ending,
    wall0: float,
) -> RunOutcome:
    """What the run produced, once its devices are stopped: the telemetry mapped onto sample
    time by the least-delayed SYNC pair of the whole run, the board's events and the stop's,
    the xruns, the exact truth of a simulated run; the recording closed."""
    board, tank = devices.board, devices.tank
    with contextlib.suppress(Exception):
        fit = board.clock_fit if board is not None else None
        recorder.sync(lambda pairs: collect_sync_pairs(fit, pairs))
    start = session.start_index if session is not None else 0
    samples = session.next_index - start if session is not None else 0
    estimates = session.estimates if session is not None else []
    telemetry = session.telemetry if session is not None else Telemetry()
    mapped = sample_index_at(
        telemetry.host_time_s,
        recorder.sync_pairs,
        fs,
        in_callback=stamped_in_callback(exp.board_url),
    )
    if mapped is not None:
        telemetry.sample_index = np.round(mapped).astype(np.int64).tolist()
        # One time base: the recording's telemetry gets the mapping the summary uses.
        with contextlib.suppress(Exception):
            recorder.map_telemetry_times(telemetry.sample_index)
    events = [] if board is None else [_event_tuple(run_event(a)) for a in board.annotations.all()]
    kind, text = stop_text(interrupted=ending.interrupted, error=ending.error)
    events.append((kind, start + samples, 0, text))
    exact, xruns, clipped = None, (0, 0), None
    if tank is not None:
        tank.close()
        xruns = tank.dac_underruns, tank.adc_overruns
        clipped = tank.adc_clipped_samples
        if samples > 0:
            with contextlib.suppress(Exception):
                exact = _exact_truth(tank, exp, fs, start, estimates)
    elif board is not None and session is not None:
        xruns = xruns_since(session.xruns_before or (0, 0), board.last_status)
    with contextlib.suppress(Exception):
        recorder.events(events)
    with contextlib.suppress(Exception):
        recorder.close()
    # The receiver's notices were recorded as they came, before the events above.
    notices = session.notices if session is not None else []
    events = [*notices, *events]
    return RunOutcome(
        folder=folder,
        experiment=exp,
        fs_hz=fs,
        start_index=start,
        samples=samples,
        estimates=estimates,
        telemetry=telemetry,
        dropped_samples=int(board.ring.missing) if board is not None and board.ring else 0,
        dac_underruns=xruns[0],
        adc_overruns=xruns[1],
        adc_clipped_samples=clipped,
        events=events,
        wall_s=time.monotonic() - wall0,
        signal_s=samples / fs,
        windows=session.tow.windows if session is not None else [],
        exact_truth=exact,
        map_times=maps.times,
        map_power=maps.power,
        interrupted=ending.interrupted,
        error=ending.error,
        latency_samples=session.latency if session is not None else None,
        capture_backlog_max_s=session.backlog_s() if session is not None else 0.0,
        calibrations=cals,
    )


def _exact_truth(
    tank: TankSimulation,
    exp: Experiment,
    fs: float,
    start_index: int,
    estimates: list[Estimate],
) -> dict[str, np.ndarray]:
    """Simulation only: the exact target range and closing speed at each estimate's bounce
    instant, from the simulated stage's true position (a check of the telemetry truth)."""
    if not estimates:
        return {"range_m": np.zeros(0), "speed_mps": np.zeros(0)}
    t_b = np.array([(e.t_s + e.t_tx_s) / 2.0 for e in estimates])
    world_t = (start_index + t_b * fs) / fs
    h = 1e-3
    x0 = tank.true_stage_position(tank.stage_time(world_t))
    x1 = tank.true_stage_position(tank.stage_time(world_t + h))
    r0, r1 = exp.range_at(x0), exp.range_at(x1)
    return {"range_m": r0, "speed_mps": -(r1 - r0) / h}
