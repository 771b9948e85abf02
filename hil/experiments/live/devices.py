"""The devices of a run, opened in the order that lets every check refuse before anything
moves or transmits: the simulated tank's process (for ``sim://``), the stage (its ``$$``
limits read on connecting, the whole tow checked against them, before homing), the board
(configured: refused before sending if it cannot), then the stage homed and positioned.

:class:`RunDevices` holds what is open so far, so a failure at any step stops and closes
exactly that (:meth:`RunDevices.safe_stop`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from hil.acquisition.device import StreamingDevice
from hil.devices.stage_errors import StageTimeoutError
from hil.devices.table import (
    SIM_AUDIO,
    WATCHDOG_MS,
    entry_for,
    is_simulated,
    open_real_daq,
    open_stage,
)
from hil.devices.table import SIM_WATCHDOG_MS as SIM_WATCHDOG_MS  # re-exported
from hil.errors import ConfigError, TransportError
from hil.experiments.experiment import Experiment
from hil.experiments.live.plan import CheckedTow, StageLimits, check_tow
from hil.experiments.live.stops import DeviceLostError, LinkWatch
from hil.experiments.stage_checks import raise_first_failure, tow_checks

if TYPE_CHECKING:
    from hil.devices.clock import Clock
    from hil.devices.grbl import ByteLink, GrblStage
    from hil.experiments.sim_tank import TankSimulation


def refuse_mixed_devices(exp: Experiment) -> None:
    """Refuse a simulated board with a real stage or the other way round (:class:`ConfigError`
    naming both): the simulated target follows the simulated stage."""
    if is_simulated(exp.board_url) != is_simulated(exp.stage_url):
        raise ConfigError(
            "devices",
            f"board {exp.board_url}, stage {exp.stage_url}",
            "both simulated (sim://) or both real",
            "the simulated target follows the simulated stage",
        )


class StatusLine(Protocol):
    """Where the run says what it is doing (the live view)."""

    def update(self, text: str, *, force: bool = False) -> None: ...


#: What a stage's link failing raises: its port (OSError), its byte link, GRBL not answering.
STAGE_LINK_FAILURES = (OSError, TransportError, StageTimeoutError)
#: How long (s) a failed link waits for the simulated tank's process to be reaped before
#: the link itself is blamed: a killed process hangs up its ptys a moment before it exits.
LINK_LOST_GRACE_S = 2.0


def stage_limits(stage: GrblStage) -> StageLimits:
    """The limits an open :class:`~hil.devices.grbl.GrblStage` reported (its ``$$``)."""
    low, high = stage.limits
    settings = stage.settings
    return StageLimits(low, high, settings.max_rate, settings.acceleration)


@dataclass
class RunDevices:
    """The run's devices as far as they are open (None: not yet)."""

    tank: TankSimulation | None = None
    stage: GrblStage | None = None
    board: StreamingDevice | None = None
    #: The driver clock of the stage, the board and the run (``now()``, ``sleep()``, s):
    #: the simulated tank's (scaled, or virtual), else the wall clock.
    clock: Clock | None = None
    #: Run the built-in simulated tank in this process on virtual time
    #: (:class:`~hil.experiments.virtual_tank.VirtualTank`) instead of a real-time child.
    virtual_time: bool = False

    def open(self, exp: Experiment, folder: Path, fs: float, view: StatusLine) -> CheckedTow:
        """Open everything (see the module docstring); the checked tow."""
        from hil.devices.clock import MonotonicClock

        stage_target, open_device = self._start_simulation(exp, folder)
        clock = self.clock = self.clock or MonotonicClock()  # one for stage, board and run
        stage = self.stage = open_stage(stage_target, clock=clock).open()
        # Every wait of the stage looks at the other devices: one lost while the stage homes
        # or positions stops the run within a wait step, not when the motion ends.
        stage.while_waiting = partial(self.raise_if_lost, exp.board_url, None)
        # The controller's settings and the tow against what it reported (its $$), before
        # anything moves: the plan, then the checks `hil stage settings --check` shows.
        tow = check_tow(exp.tow, stage_limits(stage))
        raise_first_failure(tow_checks(exp.tow, stage.settings, stage.limits))
        self.board = open_device(fs, clock)
        stage.while_waiting = partial(
            self.raise_if_lost, exp.board_url, LinkWatch(self.board.annotations, clock.now)
        )
        if self.tank is not None:
            self.tank.align(fs)
        with self.stage_link(exp.stage_url):
            # Out of any alarm: reset a critical one, then home ($22=1) or unlock ($22=0).
            stage.make_ready(lambda step: view.update(f"stage: {step}", force=True))
            view.update("stage: positioning for the first pass", force=True)
            stage.move_to(tow.ready_m, stage.settings.max_rate)
        return tow

    def _start_simulation(
        self, exp: Experiment, folder: Path
    ) -> tuple[str | ByteLink, Callable[[float, Clock], StreamingDevice]]:
        """The stage to open and how to open the DAC/ADC (at a rate, on a clock), open and
        configured (2 ADC channels: the hydrophone and the DAC monitor): the simulated
        tank's, started here for ``sim://`` devices, else the experiment's URLs through the
        device table (:mod:`hil.devices.table`)."""
        if exp.simulated:
            tank = self.tank = self._simulated_tank(exp, folder)
            self.clock = tank.clock
            return tank.stage_target, lambda fs, _clock: tank.open_daq(fs)
        refuse_mixed_devices(exp)
        if self.virtual_time:
            raise ConfigError(
                "virtual time",
                f"board {exp.board_url}, stage {exp.stage_url}",
                "simulated devices (sim://) only",
                "real devices run on real time: drop --virtual-time",
            )
        return exp.stage_url, lambda fs, clock: self._open_real_daq(exp.board_url, fs, clock)

    @staticmethod
    def _open_real_daq(url: str, fs: float, clock: Clock) -> StreamingDevice:
        # The watchdog is read here, at opening, so a test can lengthen it for a slow host.
        device = open_real_daq(url, fs, clock, WATCHDOG_MS)
        device.configure()
        return device

    def _simulated_tank(self, exp: Experiment, folder: Path) -> TankSimulation:
        if entry_for(exp.board_url) is SIM_AUDIO:  # the simulated audio interface
            from hil.experiments.audio_tank import AudioTank

            return AudioTank(exp, virtual=self.virtual_time)
        if self.virtual_time:
            from hil.experiments.virtual_tank import VirtualTank

            return VirtualTank(exp)
        from hil.experiments.sim_tank import SimulatedTankProcess

        experiment_file = folder / "experiment.toml"
        experiment_file.write_text(exp.text, encoding="utf-8")
        return SimulatedTankProcess(exp, experiment_file, folder)

    def opened(self) -> tuple[StreamingDevice, GrblStage, Clock]:
        """The board (or audio interface), the stage and the driver clock, once :meth:`open`
        opened them."""
        if self.board is None or self.stage is None or self.clock is None:
            raise RuntimeError("the run's devices are not open: call RunDevices.open first")
        return self.board, self.stage, self.clock

    def tank_lost(self, grace_s: float = 0.0) -> DeviceLostError | None:
        """The simulated tank, if it ended under the run (``grace_s``: seconds to wait for
        its exit, when a link to it already failed)."""
        return self.tank.lost(grace_s) if self.tank is not None else None

    def cause_of(self, error: Exception) -> Exception:
        """What to report for a run that failed with ``error``: the simulated tank's loss
        where its process ended (waiting :data:`LINK_LOST_GRACE_S` for it), else ``error``.
        The tank serves the board and the stage, so once it is gone any of their links fails
        in its own way (a transport timeout waiting for the board's credit, a broken pty),
        whichever noticed first; the loss is the cause. An error that is already a device's
        loss is kept."""
        if isinstance(error, DeviceLostError) or self.tank is None:
            return error
        return self.tank_lost(LINK_LOST_GRACE_S) or error

    def lost(self, board_url: str, board_watch: LinkWatch | None) -> DeviceLostError | None:
        """A device found lost since the last look: the simulated tank's process first (it
        serves both simulated devices), then the board's link (``board_watch``, None before
        the board is open), else None."""
        lost = self.tank_lost()
        if lost is not None or board_watch is None:
            return lost
        why = board_watch.lost()
        if why is None:
            return None
        return self.tank_lost(LINK_LOST_GRACE_S) or DeviceLostError(
            "board",
            board_url,
            why,
            "its USB cable and power (and that no other program holds it)",
        )

    def raise_if_lost(self, board_url: str, board_watch: LinkWatch | None) -> None:
        """Raise :meth:`lost`'s error, if there is one (the stage's ``while_waiting``)."""
        lost = self.lost(board_url, board_watch)
        if lost is not None:
            raise lost

    @contextlib.contextmanager
    def stage_link(self, url: str) -> Iterator[None]:
        """Inside, a failure of the stage's link (the port's OSError, a transport error, no
        answer in time) is raised as the stage lost (:meth:`stage_lost`); a refusal (an
        alarm, ``error:N``) is the stage answering and passes as it is."""
        try:
            yield
        except STAGE_LINK_FAILURES as exc:
            raise self.stage_lost(url, exc) from exc

    def stage_lost(self, url: str, exc: BaseException) -> DeviceLostError:
        """The stage stopped answering (``exc``: what its driver raised)."""
        return self.tank_lost(LINK_LOST_GRACE_S) or DeviceLostError(
            "stage",
            url,
            f"{type(exc).__name__}: {exc}",
            "the controller's USB cable and power, and that no other program holds its port",
        )

    def safe_stop(self, *, hold: bool) -> None:
        """Transmission off, stage held, both closed: each step even if another fails.

        ``hold`` (an interrupted or failed run) sends the feed hold unconditionally: the
        interruption may have landed inside a status query, so a fresh query cannot be
        trusted to tell whether the queued move is still running.
        """
        board, stage = self.board, self.stage
        if stage is not None:
            # The stop must reach the stage whatever else is lost: no look at the others now.
            stage.while_waiting = None
        if board is not None:
            with contextlib.suppress(Exception):
                board.stop()
        if stage is not None:
            with contextlib.suppress(Exception):
                # Short-circuit: with hold, no status query at all.
                if hold or stage.status().state.name in ("RUN", "JOG"):
                    stage.stop()
        if board is not None:
            with contextlib.suppress(Exception):
                board.close()
        if stage is not None:
            with contextlib.suppress(Exception):
                stage.close()
