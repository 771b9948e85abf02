"""The live part of a run, once its devices are open: transmit, capture, tow, record.

:class:`LiveSession` composes the parts: the :class:`~hil.acquisition.capture.CaptureLoop`
(its blocks go to the :class:`~hil.experiments.live.latency.LatencyProbe` until the loopback
latency is known, then to the recording and the receiver), the
:class:`~hil.experiments.live.tow.TowController` (given every stage report), the
:class:`~hil.experiments.live.recorder.RunRecorder`, and the checks that stop the run (a
lost device, a board that stopped by its watchdog, ``run.max_duration_s``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import cast

from hil.acquisition.capture import CapturedBlock, CaptureLoop
from hil.acquisition.feed import ReceiverFeed
from hil.estimation.base import Estimate, Receiver, SaysNotices
from hil.experiments.experiment import Experiment
from hil.experiments.live.board_state import (
    collect_sync_pairs,
    sample_index_at,
    stamped_in_callback,
)
from hil.experiments.live.devices import RunDevices
from hil.experiments.live.latency import LatencyProbe
from hil.experiments.live.plan import CheckedTow
from hil.experiments.live.recorder import RunRecorder
from hil.experiments.live.stops import DeviceLostError, LinkWatch
from hil.experiments.live.tow import TowController, TowPhase
from hil.experiments.run_calibrations import RunCalibrations
from hil.recording.records import RunEvent, StageTelemetry
from hil.signals.synthesis import BlockSynthesizer


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


@dataclass(frozen=True)
class SessionTiming:
    """The loop's cadence: samples per capture block, stage poll interval (driver s), capture
    kept after the last pass (driver s), the wait for samples per step (real s), int16
    codes to full scale."""

    block: int
    poll_s: float
    tail_s: float
    wait_s: float
    scale: float


class LiveSession:
    """Transmission (:meth:`transmit`), then capture and tow (:meth:`run`) of one run with
    its open ``devices`` (see the module docstring); ``status`` is given the live status
    line's text.
    """

    def __init__(
        self,
        exp: Experiment,
        devices: RunDevices,
        tow: CheckedTow,
        receiver: Receiver,
        recorder: RunRecorder,
        cals: RunCalibrations,
        timing: SessionTiming,
        status: Callable[[str], None],
    ) -> None:
        self.exp, self.devices, self.receiver = exp, devices, receiver
        # Asked once: a runtime protocol check looks the method up through the receiver's
        # wrappers (tracker, input stage), a tenth of a millisecond at every block.
        self._says_notices = isinstance(receiver, SaysNotices)
        self.board, self.stage, clock = devices.opened()
        self.recorder, self.cals, self.timing, self.status = recorder, cals, timing, status
        self.fs = float(exp.waveform.fs_hz)
        self.now: Callable[[], float] = clock.now
        self.tow = TowController(tow, self.stage, timing.tail_s)
        self.telemetry = Telemetry()
        self.estimates: list[Estimate] = []
        #: Events the receiver gave (an echo beyond its Doppler span, once per side; clutter,
        #: once per range), as recorded: ``(kind, board sample index, length, text)``.
        self.notices: list[tuple[str, int, int, str]] = []
        self._origin = 0  # board index of the receiver's sample 0
        self.start_index = 0
        self.latency: int | None = None
        self.capture: CaptureLoop | None = None
        self.probe: LatencyProbe | None = None
        self.transmitting = False
        #: Called with each new batch of estimates (on the run's thread).
        self.on_estimates: Callable[[list[Estimate]], None] | None = None
        #: The device's xrun counters before transmission, once it reported a status.
        self.xruns_before: tuple[int, int] | None = None
        self.board_watch = LinkWatch(self.board.annotations, self.now)

    @property
    def next_index(self) -> int:
        """Board index of the next sample to capture."""
        return self.capture.next_index if self.capture is not None else self.start_index

    # ---------------------------------------------------------------- transmission
    def transmit(self) -> None:
        """Start transmission: schedule sample k plays at board index ``start_index + k``."""
        exp, board = self.exp, self.board
        synth = BlockSynthesizer(exp.schedule, self.fs, amplitude=exp.amplitude)
        self.start_index = board.start(synth.render)
        self.transmitting = True
        self.probe = LatencyProbe(
            exp.schedule, self.fs, exp.amplitude, self.start_index, self.timing.scale, self.cals
        )
        self.capture = CaptureLoop(
            board, self.start_index, self.timing.block, on_block=self._on_block, on_fed=self._on_fed
        )

    def _on_block(self, block: CapturedBlock) -> None:
        if self.probe is None:
            self.recorder.samples(block.first_index, block.data)
        elif self.probe.add(block.first_index, block.data):
            self._attach_receiver(self.probe)
            self.probe = None

    def _on_fed(self, block: CapturedBlock) -> None:
        self._emit(block.estimates)
        self._say_notices()

    def _say_notices(self) -> None:
        """Each notice of the receiver (:class:`~hil.estimation.base.SaysNotices`: an echo
        beyond its Doppler span, clutter), once: a ``note`` event of the recording (logged as
        its events are) at the detection's board sample."""
        if not self._says_notices:
            return
        says = cast(SaysNotices, self.receiver)  # checked once, in __init__
        for seen in says.notices()[len(self.notices) :]:
            event = ("note", self._origin + int(round(seen.t_s * self.fs)), 0, seen.text())
            self.notices.append(event)
            self.recorder.events([event])

    def _emit(self, estimates: list[Estimate]) -> None:
        """New estimates: recorded, kept, and given to :attr:`on_estimates`."""
        if not estimates:
            return
        self.recorder.estimates(estimates)
        self.estimates.extend(estimates)
        if self.on_estimates is not None:
            self.on_estimates(estimates)

    def _attach_receiver(self, probe: LatencyProbe) -> None:
        """The latency measured: the recording opens with the receiver's sample 0 as its
        origin, the probe's blocks are recorded and fed, and the receiver gets the rest."""
        assert self.capture is not None
        lat, note = probe.measure()
        self.latency = lat
        origin = self._origin = self.start_index + lat
        self.recorder.open(origin, RunEvent("note", self.start_index, lat, note))
        feed = ReceiverFeed(
            self.receiver, origin=origin, channel=self.exp.board_channel, scale=self.timing.scale
        )
        for first, data in probe.blocks:
            self.recorder.samples(first, data)
        for first, data in probe.blocks:
            self._emit(feed.feed(first, data))  # drops what comes before the origin
        self._say_notices()
        self.capture.feed = feed

    # ---------------------------------------------------------------- the loop
    def run(self, deadline: float, checks: Callable[[], None]) -> None:
        """Capture and tow until the tow's tail is captured (or driver-clock time
        ``deadline``: an error); ``checks`` is called every loop turn and raises what stops
        the run (a lost device, a board stopped by its watchdog)."""
        assert self.capture is not None
        next_poll = -1.0
        while True:
            checks()
            if self.now() >= next_poll:
                self._poll_stage()
                # Timed from the reply: status() paces itself at 5 Hz from its own last
                # query, so timing from before the call would sleep out a whole interval.
                next_poll = self.now() + self.timing.poll_s
            self.recorder.sync(self._collect_sync)
            self.capture.run_while(partial(self._before, next_poll), self.timing.wait_s)
            self.status(self._status_line())
            if self._tail_captured():
                break
            if self.now() > deadline:
                raise RuntimeError(f"run.max_duration_s = {self.exp.max_duration_s} s exceeded")
        if self.capture.feed is not None:
            self._emit(self.capture.feed.finish())

    def _before(self, t: float) -> bool:
        """Whether the driver clock is before ``t`` (s)."""
        return self.now() < t

    def _collect_sync(self, pairs: list[tuple[int, float]]) -> None:
        collect_sync_pairs(self.board.clock_fit, pairs)

    def _poll_stage(self) -> None:
        """One stage report: into the telemetry and the recording, then to the tow."""
        stage, board = self.stage, self.board
        with self.devices.stage_link(self.exp.stage_url):
            st = stage.status()
            fit = board.clock_fit
            idx = int(fit.sample_index(st.host_time)) if fit is not None and fit.pairs >= 2 else -1
            tel = self.telemetry
            tel.host_time_s.append(st.host_time)
            tel.sample_index.append(idx)
            tel.position_m.append(st.position)
            tel.velocity_mps.append(st.velocity)
            tel.state.append(st.state.name)
            tel.reply_s.append(st.reply_s)
            self.recorder.telemetry(
                StageTelemetry(
                    st.host_time, idx, st.position, st.velocity, st.state.name, st.reply_s
                )
            )
            self.tow.on_report(st, self.now(), capturing=self.recorder.open_)

    def _tail_captured(self) -> bool:
        """Every pass done and the capture past its tail, on captured samples, not the
        clock: a capture that lags still records the whole pass and its last echoes. The
        device's sample at the tail's end comes from the sync pairs as it stamps them
        (:func:`~hil.experiments.live.board_state.sample_index_at`: a board that falls
        behind its clock delivers every later SYNC late)."""
        until = self.tow.tail_until
        if self.tow.phase is not TowPhase.TAIL or until is None or self.now() < until:
            return False
        self.recorder.sync(self._collect_sync)
        mapped = sample_index_at(
            [until],
            self.recorder.sync_pairs,
            self.fs,
            in_callback=stamped_in_callback(self.exp.board_url),
        )
        end_index = int(mapped[0]) if mapped is not None else 0
        return self.next_index >= end_index

    def _status_line(self) -> str:
        signal_s = (self.next_index - self.start_index) / self.fs
        est = self.estimates[-1] if self.estimates else None
        ring = self.board.ring
        x = self.telemetry.position_m[-1] if self.telemetry.position_m else float("nan")
        return (
            f"t {signal_s:6.2f} s | pass {self.tow.passes_started}/{len(self.tow.tow.passes)}"
            f" | stage x {x:+.3f} m | "
            + (
                f"R̂ {est.range_m:6.3f} m  v̂ {est.speed_mps:+.2f} m/s | "
                if est
                else "no estimate yet | "
            )
            + f"{len(self.estimates)} estimates | dropped {ring.missing if ring else 0}"
        )

    def lost(self) -> DeviceLostError | None:
        """A device found lost since the last look (:meth:`RunDevices.lost`), else None."""
        return self.devices.lost(self.exp.board_url, self.board_watch)

    def backlog_s(self) -> float:
        """Most the capture fell behind the board, s of signal."""
        return (self.capture.backlog_max if self.capture is not None else 0) / self.fs
