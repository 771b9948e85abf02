"""The towed-target tank run: waveform out, a towed pass on the stage, the estimator live,
the stage as ground truth, everything recorded.

Order of work (each step refuses with a clear message before the next touches anything):

1. the experiment file is validated (:mod:`hil.experiments.experiment`);
2. preflight without devices: calibrations required by the file present and recent;
3. devices opened (simulated ones started first for ``sim://``): stage homed if needed, tow
   plan inside the stage's soft limits and speed limits, board rates and channels;
4. continuous transmission starts (DAC fed from the schedule), capture streams into the
   recording and into the same receiver code used offline (:class:`ReceiverFeed`), the stage
   makes its passes, telemetry is mapped onto sample time through the board's sync fit;
5. a clean stop on completion, Ctrl-C or any error: transmission off, stage held, files
   closed; then truth, summary and report.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TextIO

import numpy as np

from hil.acquisition import Annotation, AnnotationKind, HeapFreeze
from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.estimation.registry import make_receiver
from hil.experiments.experiment import Experiment
from hil.experiments.live.plan import StageLimits, check_tow, new_run_folder
from hil.experiments.live.stops import (
    DeviceLostError,
    LinkWatch,
    RunInterrupted,
    StopSignals,
    stop_text,
)
from hil.experiments.run_calibrations import RunCalibrations, load_run_calibrations
from hil.signals.schedule_file import schedule_document
from hil.signals.synthesis import BlockSynthesizer

if TYPE_CHECKING:
    from hil.recording.records import RunEvent

# Samples per capture block handed to the recording and the receiver (about 10-20 ms).
_BLOCK_S = 0.01
# Stage status polled every this many seconds of the driver clock (GRBL's 5 Hz).
STAGE_POLL_S = 0.2
#: Reports that took longer than this (s) to answer their query are left out of the truth:
#: the stage sampled its position somewhere in that time. A prompt reply measures up to
#: ~60 ms: GRBL answers at once, a USB serial adapter holds a short report up to its 16 ms
#: latency timer, and the driver reads every 20 ms with 20 ms sleeps between.
TELEMETRY_MAX_REPLY_S = 0.08
# Capture kept after the stage stops, s: the last echoes still arrive.
_TAIL_S = 0.3
_INT16_SCALE = 1.0 / 32768.0
# Capture used to measure the loopback latency at the start of every run, s.
_LATENCY_PROBE_S = 0.05
#: The board's watchdog (ms of its clock): it stops when the host has sent nothing for this
#: long (a crashed or stalled host), so a run never leaves it streaming unattended.
_WATCHDOG_MS = 1000
#: The simulated board's: the simulated tank is a child process on the same CPUs, scaled in
#: time, so a stall of the machine (seconds on a loaded CI host) must not stop it.
_SIM_WATCHDOG_MS = 10_000

# Board annotations as recording events: the recording's kinds are coarser (schema
# EVENT_KINDS); the event's text starts with the annotation's own kind.
EVENT_KIND: dict[AnnotationKind, str] = {
    AnnotationKind.GAP: "gap",
    AnnotationKind.SEQUENCE_GAP: "gap",
    AnnotationKind.OVERLAP: "note",
    AnnotationKind.FRAME_ERROR: "alarm",
    AnnotationKind.DAC_UNDERRUN: "underrun",
    AnnotationKind.ADC_OVERRUN: "overrun",
    AnnotationKind.WATCHDOG: "alarm",
    AnnotationKind.DISCONNECT: "alarm",
    AnnotationKind.RECONNECT: "note",
    AnnotationKind.ALARM: "alarm",
    AnnotationKind.PROTOCOL_ERROR: "alarm",
    AnnotationKind.START_RETRY: "note",
}


def run_event(annotation: Annotation) -> RunEvent:
    """A board annotation as a recording event (kind mapped by :data:`EVENT_KIND`, the text
    led by the annotation's own kind).

    >>> from hil.acquisition import Annotation
    >>> run_event(Annotation(120, AnnotationKind.SEQUENCE_GAP, 2, "seq 5 expected"))
    RunEvent(kind='gap', sample_index=120, length=2, text='sequence_gap: seq 5 expected')
    """
    from hil.recording.records import RunEvent

    return RunEvent(
        EVENT_KIND[annotation.kind],
        annotation.sample_index,
        annotation.length,
        f"{annotation.kind.value}: {annotation.detail}",
    )


def board_stopped(board: Any) -> str | None:
    """Why the board stopped streaming on its own (its watchdog expired: the host sent it
    nothing for the watchdog timeout), as an error message; None while it streams. A run
    stops at once on it: no more samples will come.

    Works for any device with ``annotations.of_kind`` (the board, the audio interface).
    """
    annotations = getattr(board, "annotations", None)
    if annotations is None:
        return None
    stops = annotations.of_kind(AnnotationKind.WATCHDOG)
    if not stops:
        return None
    at = stops[0]
    return (
        f"the board stopped streaming at sample {at.sample_index} ({at.detail}): the host"
        " sent it nothing for its watchdog timeout, so the host stalled (a loaded machine, a"
        " slow disk); the recording holds everything before it"
    )


class XrunStatus(Protocol):
    """A device status with xrun counters: the board's
    :class:`~firmware_protocol.messages.Status` (counted since the board powered up) or the
    audio interface's :class:`~hil.devices.audio.daq.AudioDaqStatus` (since the stream
    started)."""

    @property
    def dac_underruns(self) -> int: ...

    @property
    def adc_overruns(self) -> int: ...


def xrun_counts(status: XrunStatus | None) -> tuple[int, int]:
    """``(dac_underruns, adc_overruns)`` in a device's status; ``(0, 0)`` before any status.

    >>> from hil.devices.audio.daq import AudioDaqStatus
    >>> xrun_counts(AudioDaqStatus(frames=4096, overruns=2, underruns=1))
    (1, 2)
    """
    if status is None:
        return 0, 0
    return int(status.dac_underruns), int(status.adc_overruns)


def xruns_since(before: tuple[int, int], status: XrunStatus | None) -> tuple[int, int]:
    """``(dac_underruns, adc_overruns)`` since the counts ``before`` (from
    :func:`xrun_counts`), in ``status``. A counter lower than before has restarted (the
    board was power-cycled and the driver reconnected): its count is then the new value."""
    (dac, adc), (dac0, adc0) = xrun_counts(status), before
    return (dac - dac0 if dac >= dac0 else dac), (adc - adc0 if adc >= adc0 else adc)


def sample_zero_time_s(pairs: list[tuple[int, float]], fs: float) -> float | None:
    """Host time (s) of board sample 0, from SYNC pairs ``(sample_index, host_time_s)`` by
    minimum-delay filtering; None without pairs.

    A SYNC is stamped when the host reads it, which during streaming is after the ADC
    frames queued before it, so every pair is late by a varying backlog: with the known
    sample rate ``fs`` (Hz), the least-delayed pair gives the offset. The backlog is a few
    ms on a quiet machine but seconds after a stall of the host or the board, and then most
    pairs can be that late: only the least-delayed pair counts, however few are near it.
    No pair is early: the board's clock fit starts afresh when CONFIGURE is acknowledged and
    the link delivers in order, so a SYNC from an earlier configuration never reaches it.

    >>> pairs = [(1000, 11.003), (2000, 12.0015), (3000, 13.004)]  # delays 3, 1.5, 4 ms
    >>> late = [(4000 + k, 17.0 + k / 1000) for k in range(0, 5000, 500)]  # 3 s late
    >>> round(sample_zero_time_s(pairs + late, 1000.0), 6)
    10.0015
    """
    if not pairs:
        return None
    return float(min(host_t - index / fs for index, host_t in pairs))


def collect_sync_pairs(board: Any, run_pairs: list[tuple[int, float]]) -> None:
    """Append to ``run_pairs`` the board's SYNC pairs ``(sample_index, host_time_s)`` it does
    not hold yet. The board's clock fit keeps only its latest pairs (a sliding window), so
    the run keeps its own list: every pair is recorded, and the least-delayed one of the
    whole run is never forgotten."""
    fit = getattr(board, "clock_fit", None) if board is not None else None
    pairs = fit.pair_list() if fit is not None else []
    last = run_pairs[-1][0] if run_pairs else None
    run_pairs.extend(p for p in pairs if last is None or p[0] > last)


def measure_latency(monitor: np.ndarray, sent: np.ndarray, max_lag: int = 4096) -> int:
    """Integer-sample delay of ``monitor`` (the DAC drive as captured) behind ``sent``.

    >>> x = np.random.default_rng(0).normal(size=2000)
    >>> measure_latency(np.concatenate([np.zeros(37), x])[:2000], x)
    37
    """
    return measure_loopback(monitor, sent, max_lag)[0]


#: Least normalised correlation between the DAC monitor input and the transmitted samples
#: that counts as a loopback (a cabled monitor gives about 1; an open input about 0).
LOOPBACK_MIN_CORRELATION = 0.5


def measure_loopback(
    monitor: np.ndarray, sent: np.ndarray, max_lag: int = 4096
) -> tuple[int, float]:
    """``(delay, correlation)``: the integer-sample delay (0 .. ``max_lag``) of ``monitor``
    behind ``sent`` (both shape ``(n,)``) and the normalised correlation at that delay
    (1 for a scaled, delayed copy; about 0 when the monitor does not carry ``sent``).

    >>> x = np.random.default_rng(0).normal(size=2000)
    >>> lag, rho = measure_loopback(0.1 * np.concatenate([np.zeros(37), x])[:2000], x)
    >>> lag, round(rho, 3)
    (37, 1.0)
    >>> measure_loopback(np.zeros(2000), x)
    (0, 0.0)
    """
    n = min(monitor.shape[0], sent.shape[0])
    lags = min(max_lag, n - 1)
    nfft = 1 << (2 * n - 1).bit_length()
    m, s = np.asarray(monitor[:n], dtype=float), np.asarray(sent[:n], dtype=float)
    spectrum = np.fft.rfft(m, nfft) * np.conj(np.fft.rfft(s, nfft))
    # The envelope of the cross-correlation (its analytic signal: positive frequencies
    # doubled): a few tones a couple of kHz apart give a correlation whose carrier peaks
    # repeat every few hundred µs, and a delay between two samples can put a neighbouring
    # carrier peak above the true one. The envelope peaks at the delay.
    analytic = np.zeros(nfft, dtype=complex)
    analytic[: spectrum.size] = spectrum
    analytic[1 : spectrum.size - 1] *= 2.0
    envelope = np.abs(np.fft.ifft(analytic))
    lag = int(np.argmax(envelope[: lags + 1]))
    # Over the overlap at that delay: monitor[lag:] against sent[:n - lag].
    energy = float(np.sum(m[lag:] ** 2) * np.sum(s[: n - lag] ** 2))
    rho = float(envelope[lag] / np.sqrt(energy)) if energy > 0 else 0.0
    return lag, rho


def _loopback_latency(lat: int, rho: float, cals: RunCalibrations) -> tuple[int, str]:
    """The receiver's latency (samples) and the recording's note about it: measured on the
    DAC monitor input when it carries the loopback, else the required latency calibration's,
    else the run cannot place its sample 0 (RuntimeError: the run stops and says why)."""
    calibrated = cals.latency_samples
    if rho >= LOOPBACK_MIN_CORRELATION:
        note = f"loopback latency {lat} samples"
        if calibrated is not None and calibrated != lat:
            note += f" (calibration {cals.id_of('latency')} says {calibrated})"
        return lat, note
    if calibrated is None:
        raise RuntimeError(
            f"no loopback on the DAC monitor input (ADC input 2, channel 1): normalised"
            f" correlation {rho:.2f} < {LOOPBACK_MIN_CORRELATION}, so the loopback latency"
            " cannot be measured. Connect the transmit drive to ADC input 2 (on an audio"
            " interface: output 2, which plays the same signal; on the board: a tap on its"
            " DAC output; docs/tank-run.md), or require a latency calibration:"
            ' calibration.required = ["latency"]'
        )
    return calibrated, (
        f"loopback latency {calibrated} samples from calibration {cals.id_of('latency')}"
        f" (the DAC monitor input carried no loopback: correlation {rho:.2f})"
    )


def stage_limits(stage: Any) -> StageLimits:
    """The limits an open :class:`~hil.devices.grbl.GrblStage` reported (its ``$$``)."""
    low, high = stage.limits
    settings = stage.settings
    return StageLimits(low, high, settings.max_rate, settings.acceleration)


@dataclass
class Telemetry:
    """Stage telemetry mapped onto sample time."""

    host_time_s: list[float] = field(default_factory=list)
    sample_index: list[int] = field(default_factory=list)
    position_m: list[float] = field(default_factory=list)
    velocity_mps: list[float] = field(default_factory=list)
    state: list[str] = field(default_factory=list)
    #: How long each report took to arrive after its query, s (``StageStatus.reply_s``).
    reply_s: list[float] = field(default_factory=list)


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
    exact_truth: Any = None
    map_times: list[np.ndarray] = field(default_factory=list)
    map_power: list[np.ndarray] = field(default_factory=list)
    interrupted: bool = False
    error: str = ""
    latency_samples: int | None = None
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
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
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


def run_experiment(
    exp: Experiment,
    *,
    folder: Path | None = None,
    view: LiveView | None = None,
) -> RunOutcome:
    """Run ``exp`` end to end (see the module docstring) and return what it produced.

    Raises ConfigError for problems found before anything transmits. Once transmission
    has started, every failure (a ConfigError too) stops the run safely and is reported in
    :attr:`RunOutcome.error`, with what was recorded until then.
    """
    from hil.devices.board import Board
    from hil.devices.board_settings import BoardSettings
    from hil.devices.grbl import GrblStage
    from hil.devices.stage_errors import StageTimeoutError
    from hil.recording.records import ReceiverSetup, RunEvent, StageTelemetry
    from hil.recording.replay import ReceiverFeed
    from hil.recording.writer import RunWriter

    fs = float(exp.waveform.fs_hz)
    if fs != int(fs):
        raise ConfigError("waveform.fs_hz", fs, "a whole number of Hz (a board rate)")
    # The required calibrations: checked before anything is touched, then applied.
    cals = load_run_calibrations(exp, fs)
    calibration_ids = list(cals.ids)
    exp = cals.apply(exp)
    # Never overwrite a run, never leave output_dir: refused before any device is opened.
    folder = new_run_folder(exp.output_dir, exp.name, folder, dt.datetime.now())
    view = view or LiveView()

    tank: Any = None
    clock: Any = None
    board_url, stage_url = exp.board_url, exp.stage_url
    if exp.simulated:
        from hil.experiments.sim_tank import SimulatedTankProcess

        experiment_file = folder / "experiment.toml"
        experiment_file.write_text(exp.text, encoding="utf-8")
        tank = SimulatedTankProcess(exp, experiment_file, folder)
        board_url, stage_url, clock = tank.board_port, tank.stage_port, tank.clock
    elif exp.board_url.startswith("sim://") or exp.stage_url.startswith("sim://"):
        raise ConfigError(
            "devices",
            f"board {exp.board_url}, stage {exp.stage_url}",
            "both simulated (sim://) or both real",
            "the simulated target follows the simulated stage",
        )

    stage: Any = None
    board: Any = None
    backlog_max = 0  # samples: the most the capture loop fell behind the board
    writer: Any = None
    outcome_error = ""
    interrupted = False
    estimates: list[Estimate] = []
    telemetry = Telemetry()
    windows: list[tuple[float, float]] = []
    map_t: list[np.ndarray] = []
    map_p: list[np.ndarray] = []
    latency: list[int] = []  # the run's loopback latency measurement, samples
    run_pairs: list[tuple[int, float]] = []  # every SYNC pair of the run
    sync_seen = 0  # of them in the recording
    wall0 = time.monotonic()
    next_index = 0
    start_index = 0
    # The device's xrun counters before transmission starts (a board counts them since it
    # powered up, and only while streaming); None until it has reported a status.
    xruns_before: tuple[int, int] | None = None
    transmitting = False
    heap = HeapFreeze()
    signals = StopSignals().__enter__()
    try:
        # ---- receiver first: building it loads its compiled kernels (on a fresh install it
        # compiles them, tens of seconds). Later, with the board streaming, a stall that long
        # would overflow the capture ring; now nothing moves or transmits meanwhile.
        view.update(
            "receiver: loading its compiled kernels (a first run compiles them)", force=True
        )
        extra: dict[str, Any] = dict(exp.receiver_options)
        if exp.receiver == "gcas":

            def on_map(t_s: np.ndarray, p: np.ndarray, speed: Any) -> None:
                if sum(len(a) for a in map_t) < 400_000:
                    map_t.append(np.asarray(t_s, dtype=float).copy())
                    map_p.append(np.asarray(p, dtype=np.float32).copy())

            extra["on_map"] = on_map
        receiver = make_receiver(
            exp.receiver,
            exp.schedule,
            fs,
            sound_speed_mps=exp.sound_speed_mps,
            max_speed_mps=exp.max_speed_mps,
            max_range_m=exp.max_range_m,
            m_hops=exp.m_hops,
            **extra,
        )
        wall0 = time.monotonic()  # the run's wall time, without that set-up

        # ---- plan: the stage's limits as it reports them ($$, read on connecting, before
        # homing), the whole tow checked against them; nothing has moved yet.
        stage = GrblStage(stage_url, clock=clock).open()
        tow = check_tow(exp.tow, stage_limits(stage))
        plan = tow.plan

        # ---- board: open, configure (refused before sending if it cannot); nothing
        # transmits until start().
        settings = BoardSettings(sample_rate_hz=int(fs), dac_channels=1, adc_channels=2)
        if board_url.startswith("audio://"):
            from hil.devices.audio.daq import AudioDaq

            board = AudioDaq.from_url(board_url, sample_rate_hz=int(fs), ring_seconds=8.0).open()
        else:
            board = Board(
                board_url,
                settings=settings,
                clock=clock,
                ring_seconds=8.0,
                keepalive_ms=_SIM_WATCHDOG_MS if tank is not None else _WATCHDOG_MS,
            ).open()
        board.configure()
        if tank is not None:
            tank.align(fs)

        # ---- act: home if needed, position for the first pass, then transmit.
        try:
            status = stage.status()
            if status.state.name == "ALARM" or status.alarm is not None:
                view.update("stage: homing", force=True)
                stage.home()
            view.update("stage: positioning for the first pass", force=True)
            stage.move_to(tow.ready_m, stage.settings.max_rate)
        except (OSError, StageTimeoutError) as exc:
            raise lost_stage(tank, exp.stage_url, exc) from exc

        # ---- transmission: the schedule from the first transmitted sample
        synth = BlockSynthesizer(exp.schedule, fs, amplitude=exp.amplitude)
        # Board and audio interface both ask for samples by their number in the
        # transmission: sample k plays at start_index + k.
        if board.last_status is not None:
            xruns_before = xrun_counts(board.last_status)
        start_index = board.start(synth.render)
        transmitting = True
        next_index = start_index
        doc = schedule_document(
            exp.schedule,
            fs,
            0.0,
            sound_speed_mps=exp.sound_speed_mps,
            amplitude=exp.amplitude,
            spec=exp.waveform.to_dict(),
        )
        rx_settings = {
            "sound_speed_mps": exp.sound_speed_mps,
            "max_speed_mps": exp.max_speed_mps,
            "max_range_m": exp.max_range_m,
            "m_hops": exp.m_hops,
            **exp.receiver_options,
        }
        setup = ReceiverSetup(
            exp.receiver, rx_settings, channel=exp.board_channel, scale=_INT16_SCALE
        )

        def open_writer(origin_sample: int) -> Any:
            # Created once the loopback latency is known: the recording's origin is the
            # receiver's sample 0 (start + latency), so a replay feeds the receiver exactly
            # as live did.
            return RunWriter.create(
                folder / "run.h5",
                fs_hz=fs,
                n_channels=2,
                dtype="int16",
                schedule_document=doc,
                receiver=setup,
                experiment_toml=exp.text,
                calibration_ids=calibration_ids,
                origin_sample=origin_sample,
            )

        telemetry_backlog: list[StageTelemetry] = []
        feed: ReceiverFeed | None = None
        pending: list[tuple[int, np.ndarray]] = []

        block = max(256, int(round(_BLOCK_S * fs)))
        now = stage._clock.now
        last_poll = -1.0
        pass_no = 0
        moving = False
        tail_until: float | None = None
        deadline = now() + exp.max_duration_s
        board_watch = LinkWatch(board.annotations, now)
        heap.start()  # setup done: its objects stay out of the collector's full passes
        while True:
            # Stage: start the next pass when idle, poll at most 5 Hz, record telemetry.
            t_now = now()
            lost = lost_device(tank, board_watch, exp.board_url)
            if lost is not None:
                raise lost
            if t_now - last_poll >= STAGE_POLL_S:
                try:
                    st = stage.status()
                except (OSError, StageTimeoutError) as exc:
                    raise lost_stage(tank, exp.stage_url, exc) from exc
                # Timed from the reply: status() paces itself at 5 Hz from its own last
                # query, so timing from before the call made it sleep out a whole interval
                # at every poll, and the capture in between got one block per 0.2 s.
                last_poll = now()
                fit = board.clock_fit
                idx = (
                    int(fit.sample_index(st.host_time))
                    if fit is not None and fit.pairs >= 2
                    else -1
                )
                telemetry.host_time_s.append(st.host_time)
                telemetry.sample_index.append(idx)
                telemetry.position_m.append(st.position)
                telemetry.velocity_mps.append(st.velocity)
                telemetry.state.append(st.state.name)
                telemetry.reply_s.append(st.reply_s)
                record = StageTelemetry(st.host_time, idx, st.position, st.velocity, st.state.name)
                if writer is None:
                    telemetry_backlog.append(record)
                else:
                    writer.append_telemetry(record)
                idle = st.state.name == "IDLE"
                # A pass starts only once capture flows into the receiver and the recording
                # (the loopback latency is measured): no part of it goes unrecorded.
                capturing = feed is not None
                if (
                    capturing
                    and idle
                    and not moving
                    and pass_no < plan.repeats
                    and tail_until is None
                ):
                    first, last = (
                        (plan.start_m, plan.end_m)
                        if pass_no % 2 == 0
                        else (plan.end_m, plan.start_m)
                    )
                    try:
                        w = stage.run_profile(
                            first, last, plan.speed_mps, plan.run_up_m, plan.run_down_m, wait=False
                        )
                    except (OSError, StageTimeoutError) as exc:
                        raise lost_stage(tank, exp.stage_url, exc) from exc
                    windows.append((w.t_start, w.t_end))
                    pass_no += 1
                    moving = True
                elif moving and idle and now() > windows[-1][1]:
                    moving = False
                    if pass_no >= plan.repeats:
                        tail_until = now() + _TAIL_S
                if st.alarm is not None:
                    raise RuntimeError(f"stage alarm {st.alarm} during the run")
            if xruns_before is None and board.last_status is not None:
                # No status before the start: the first one is the baseline.
                xruns_before = xrun_counts(board.last_status)
            # Sync pairs into the recording as they arrive.
            collect_sync_pairs(board, run_pairs)
            if writer is not None:
                for index, host_t in run_pairs[sync_seen:]:
                    writer.append_sync(index, host_t)
                sync_seen = len(run_pairs)
            # Capture: what the board holds goes to the recording and the receiver, in blocks
            # of at most `block`. Once the receiver runs, the loop waits only until its next
            # decision index when that comes first, so an estimate leaves as soon as its
            # look-ahead has arrived (not at the end of a fixed block).
            while board.wait_for_samples(
                max(next_index + 1, feed.wait_index(block))
                if feed is not None
                else next_index + block,
                timeout_s=0.05,
            ):
                held = board.ring.end_index  # >= the index waited for
                n = min(held, next_index + block) - next_index
                backlog_max = max(backlog_max, held - next_index)
                data = board.read(next_index, n)
                if writer is not None:
                    writer.append_samples(next_index, data)
                if feed is None:
                    # Loopback latency, measured on this run: the DAC monitor channel against
                    # the transmitted samples. The receiver's sample 0 is the first sample
                    # that can hold the echo of transmit sample 0.
                    pending.append((next_index, data))
                    got = sum(b.shape[0] for _, b in pending)
                    if got >= _LATENCY_PROBE_S * fs:
                        captured = np.concatenate([b for _, b in pending])
                        # Its own synthesizer: the one transmitting renders on the board's
                        # writer thread (or the audio callback) and is not re-entrant.
                        reference = BlockSynthesizer(exp.schedule, fs, amplitude=exp.amplitude)
                        lat, rho = measure_loopback(
                            captured[:, 1] * _INT16_SCALE, reference.render(0, captured.shape[0])
                        )
                        lat, latency_note = _loopback_latency(lat, rho, cals)
                        latency.append(lat)
                        writer = open_writer(start_index + lat)
                        writer.append_event(RunEvent("note", start_index, lat, latency_note))
                        for record in telemetry_backlog:
                            writer.append_telemetry(record)
                        for first_i, blk in pending:
                            writer.append_samples(first_i, blk)
                        feed = ReceiverFeed(
                            receiver,
                            origin=start_index + lat,
                            channel=exp.board_channel,
                            scale=_INT16_SCALE,
                        )
                        for first_i, blk in pending:
                            skip = max(0, start_index + lat - first_i)
                            if skip < blk.shape[0]:
                                new = feed.feed(first_i + skip, blk[skip:])
                                writer.append_estimates(new)
                                estimates.extend(new)
                        pending.clear()
                else:
                    new = feed.feed(next_index, data)
                    if new:
                        writer.append_estimates(new)
                        estimates.extend(new)
                next_index += n
                if now() - last_poll >= STAGE_POLL_S:
                    break
            stopped = board_stopped(board)
            if stopped is not None:
                raise RuntimeError(stopped)
            signal_s = (next_index - start_index) / fs
            est = estimates[-1] if estimates else None
            view.update(
                f"t {signal_s:6.2f} s | pass {pass_no}/{plan.repeats} | stage x "
                f"{telemetry.position_m[-1]:+.3f} m | "
                + (
                    f"R̂ {est.range_m:6.3f} m  v̂ {est.speed_mps:+.2f} m/s | "
                    if est
                    else "no estimate yet | "
                )
                + f"{len(estimates)} estimates | dropped {board.ring.missing if board.ring else 0}"
            )
            if tail_until is not None and now() >= tail_until:
                # End on captured samples, not on the clock: a capture that lags still
                # records the whole pass and its last echoes.
                # The board's clock at tail_until, from the least-delayed SYNC: a board that
                # falls behind its clock (a simulated world computing slowly) delivers every
                # later SYNC late, and a fit through them would end the capture early.
                collect_sync_pairs(board, run_pairs)
                zero = sample_zero_time_s(run_pairs, fs)
                end_index = int((tail_until - zero) * fs) if zero is not None else 0
                if next_index >= end_index:
                    break
            if now() > deadline:
                raise RuntimeError(f"run.max_duration_s = {exp.max_duration_s} s exceeded")
        if feed is not None and writer is not None:
            tail = feed.finish()
            writer.append_estimates(tail)
            estimates.extend(tail)
    except KeyboardInterrupt as exc:
        interrupted = True
        how = exc.signal_name if isinstance(exc, RunInterrupted) else "Ctrl-C"
        outcome_error = f"interrupted ({how})"
    except ConfigError as exc:
        if not transmitting:
            raise  # found before anything transmits: the file or the set-up is wrong
        # Once transmitting, a refusal (say, a capture read the ring no longer holds) is a
        # failure of the run: stop safely and report it with what was recorded.
        outcome_error = f"ConfigError: {exc}"
    except Exception as exc:  # any failure: stop safely below, report it
        outcome_error = f"{type(exc).__name__}: {exc}"
    finally:
        signals.stopping()
        heap.stop()
        view.close()
        refused = sys.exc_info()[0] is not None  # a refusal before transmitting, raised
        failing = interrupted or bool(outcome_error) or refused
        _safe_stop(board, stage, writer, hold=failing)
        if refused and tank is not None:
            tank.close()  # no outcome follows: stop the simulated tank's process here
        if refused:
            signals.__exit__(None, None, None)
    # Telemetry onto sample time after the run, by minimum-delay filtering of the SYNC pairs:
    # a SYNC is stamped when the host reads it, which during streaming is after the ADC
    # frames queued before it, so every pair is late by a varying backlog. With the known
    # sample rate, the least-delayed pair gives the host-time offset of sample 0.
    collect_sync_pairs(board, run_pairs)
    offset = sample_zero_time_s(run_pairs, fs)
    if offset is not None:
        telemetry.sample_index = [int(round((t - offset) * fs)) for t in telemetry.host_time_s]
    dropped = int(board.ring.missing) if board is not None and board.ring is not None else 0
    events: list[tuple[str, int, int, str]] = []
    if board is not None:
        for a in board.annotations.all():
            ev = run_event(a)
            events.append((ev.kind, ev.sample_index, ev.length, ev.text))
    exact = None
    dac_underruns = adc_overruns = 0
    if tank is not None:
        tank.close()
        dac_underruns, adc_overruns = tank.dac_underruns, tank.adc_overruns
        if next_index > start_index:
            with contextlib.suppress(Exception):
                exact = _exact_truth(tank, exp, fs, start_index, estimates)
    elif board is not None:
        dac_underruns, adc_overruns = xruns_since(xruns_before or (0, 0), board.last_status)
    stop_kind, stop_reason = stop_text(interrupted=interrupted, error=outcome_error)
    events.append((stop_kind, next_index, 0, stop_reason))
    with contextlib.suppress(Exception):
        if writer is not None:
            for kind, index, length, text in events:
                writer.append_event(RunEvent(kind, index, length, text))
            for index, host_t in run_pairs[sync_seen:]:  # those that came after the loop
                writer.append_sync(index, host_t)
    _close(writer)
    signals.__exit__(None, None, None)
    return RunOutcome(
        folder=folder,
        experiment=exp,
        fs_hz=fs,
        start_index=start_index,
        samples=next_index - start_index,
        estimates=estimates,
        telemetry=telemetry,
        dropped_samples=dropped,
        dac_underruns=dac_underruns,
        adc_overruns=adc_overruns,
        events=events,
        wall_s=time.monotonic() - wall0,
        signal_s=(next_index - start_index) / fs,
        windows=windows,
        exact_truth=exact,
        map_times=map_t,
        map_power=map_p,
        interrupted=interrupted,
        error=outcome_error,
        latency_samples=latency[0] if latency else None,
        capture_backlog_max_s=backlog_max / fs,
        calibrations=cals,
    )


def lost_device(tank: Any, board_watch: LinkWatch, board_url: str) -> DeviceLostError | None:
    """The device found lost since the last look: the simulated tank's process (it serves
    both simulated devices), else the board (its link down past
    :data:`~hil.experiments.live.stops.LOST_AFTER_S`); None while all are there."""
    if tank is not None and tank.exit_code() is not None:
        return tank_lost(tank)
    why = board_watch.lost()
    if why is None:
        return None
    return DeviceLostError(
        "board", board_url, why, "its USB cable and power (and that no other program holds it)"
    )


def tank_lost(tank: Any) -> DeviceLostError:
    """The simulated tank's process ended under the run."""
    return DeviceLostError(
        "the built-in simulated tank",
        f"(process {tank.pid})",
        f"its process exited with code {tank.exit_code()}",
        "that nothing killed it (its errors are printed above)",
    )


def lost_stage(tank: Any, url: str, exc: BaseException) -> DeviceLostError:
    """The stage stopped answering (``exc``: what the driver raised)."""
    if tank is not None and tank.exit_code() is not None:
        return tank_lost(tank)
    return DeviceLostError(
        "stage",
        url,
        f"{type(exc).__name__}: {exc}",
        "the controller's USB cable and power, and that no other program holds its port",
    )


def _safe_stop(board: Any, stage: Any, writer: Any, *, hold: bool) -> None:
    """Transmission off, stage held, data flushed: each step even if another fails.

    ``hold`` (an interrupted or failed run) sends the feed hold unconditionally: the
    interruption may have landed inside a status query, so a fresh query cannot be trusted
    to tell whether the queued move is still running.
    """
    if board is not None:
        with contextlib.suppress(Exception):
            board.stop()
    if stage is not None:
        with contextlib.suppress(Exception):
            # Short-circuit: with hold, no status query at all.
            if hold or stage.status().state.name in ("RUN", "JOG"):
                stage.stop()
    if writer is not None:
        with contextlib.suppress(Exception):
            writer.flush()
    if board is not None:
        with contextlib.suppress(Exception):
            board.close()
    if stage is not None:
        with contextlib.suppress(Exception):
            stage.close()


def _close(writer: Any) -> None:
    if writer is not None:
        with contextlib.suppress(Exception):
            writer.close()


def _exact_truth(
    tank: Any, exp: Experiment, fs: float, start_index: int, estimates: list[Estimate]
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
