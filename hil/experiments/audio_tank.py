"""The built-in simulated tank with the simulated audio interface (``sim://audio``) as the
run's DAC/ADC instead of the simulated board.

The host drives the interface as it drives a real one (:class:`~hil.devices.audio.daq.AudioDaq`
over a full-duplex backend); the backend is the simulated interface
(:class:`~hil.devices.audio.simulated.SimulatedDuplex`) whose *world* is the acoustic tank
(:func:`~hil.experiments.sim_tank.build_tank_world`): output 1 drives the transmitter, input 1
is the hydrophone, input 2 the DAC monitor, ``CONVERTER_DELAY_SAMPLES`` late, and the
interface adds its own ``2 * blocksize`` of buffering. The towed target follows the simulated
GRBL carriage: device sample ``n`` leaves the DAC at clock time
``start_time_s + (n + blocksize) / fs``, and the target is where the carriage was then.

Two ways to run, as for the simulated board:

- ``virtual=True``: stage and interface in this thread on one
  :class:`~hil.devices.clock.VirtualClock` (the interface's blocks run as a service of the
  clock): deterministic and as fast as the CPU allows;
- ``virtual=False``: real time, scaled by ``simulation.time_scale``: the stage on a pty
  served by a thread, the interface's own audio thread pacing its blocks, as a USB audio
  interface and a GRBL controller on a serial port are driven. The interface is a host-side
  device, so it runs in this process.

Everything from :mod:`sim_devices` is imported inside the functions (DESIGN: the host never
imports simulated devices at module level).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from hil.devices.clock import VirtualClock
from hil.devices.table import RING_S
from hil.errors import ConfigError
from hil.experiments.experiment import Experiment
from hil.experiments.sim_tank import (
    CONVERTER_DELAY_SAMPLES,
    ScaledClock,
    build_tank_world,
    tank_stage_config,
)

if TYPE_CHECKING:
    from hil.devices.audio.daq import AudioDaq
    from hil.devices.audio.simulated import SimulatedDuplex
    from hil.devices.clock import Clock
    from hil.devices.grbl import ByteLink
    from hil.experiments.live.stops import DeviceLostError

#: Spacing of the instants the interface's blocks are run on virtual time, s (as for the
#: simulated board: a block runs at most this late).
SERVICE_TICK_S = 0.001


class _TankInPlace:
    """The tank world (``world(dac_block, first) -> adc``, shapes (n, 1) -> (n, 2)) as the
    simulated interface's world (``world(output, index, input)``, input filled in place)."""

    def __init__(self, world: Any) -> None:
        self.world = world

    def reset(self) -> None:
        self.world.reset()

    def __call__(
        self, output_block: np.ndarray, sample_index: int, input_block: np.ndarray
    ) -> None:
        adc = self.world(output_block[:, :1], sample_index)
        k = min(adc.shape[1], input_block.shape[1])
        input_block[:, :k] = adc[:, :k]
        input_block[:, k:] = 0.0


class AudioTank:
    """The simulated stage of ``exp`` and the simulated audio interface in the tank (see the
    module docstring); a :class:`~hil.experiments.sim_tank.TankSimulation`."""

    def __init__(self, exp: Experiment, *, virtual: bool, tick_s: float = SERVICE_TICK_S) -> None:
        from hil.devices.audio.daq import parse_audio_url

        spec = parse_audio_url(exp.board_url)
        if spec.delay_samples:
            raise ConfigError(
                "devices.board delay",
                spec.delay_samples,
                "absent with sim://stage (the tank, not a cable, is between output and input)",
                f"remove it: the tank's converters delay the monitor by "
                f"{CONVERTER_DELAY_SAMPLES} samples",
            )
        self.exp = exp
        self._stage_sim: Any = None
        self._grbl: Any
        self.clock: Clock
        self.virtual_time: VirtualClock | None
        self.stage_target: str | ByteLink
        if virtual:
            from hil.transports.sim import MemoryStageLink
            from sim_devices.stage import SimulatedGrbl

            clock = VirtualClock(tick_s)
            self.clock = self.virtual_time = clock
            self._grbl = SimulatedGrbl(tank_stage_config(), clock=clock)
            self.stage_target = MemoryStageLink(
                self._grbl, timeout=0.0, url="sim://stage (in process, virtual time)"
            )
        else:
            from sim_devices.stage.on_pty import SimulatedGrblOnPty

            scaled = ScaledClock(exp.simulation.time_scale)
            self.clock, self.virtual_time = scaled, None
            self._scaled = scaled
            self._stage_sim = SimulatedGrblOnPty(tank_stage_config(), clock=scaled).start()
            self._grbl = self._stage_sim.grbl
            self.stage_target = self._stage_sim.port_name
        self._world = build_tank_world(exp, self._carriage)
        self.daq: AudioDaq | None = None
        self._backend: SimulatedDuplex | None = None

    def open_daq(self, fs: float) -> AudioDaq:
        """The simulated interface in the tank, opened and configured at ``fs`` Hz."""
        from hil.devices.audio.daq import AudioDaq, audio_settings
        from sim_devices.audio.simulated import SimulatedDuplex

        _, settings = audio_settings(self.exp.board_url, int(fs))
        world = _TankInPlace(self._world)
        if self.virtual_time is not None:
            backend = SimulatedDuplex(settings, world, virtual_time=self.virtual_time)
        else:
            backend = SimulatedDuplex(settings, world, clock=self._scaled)
        self._backend = backend
        daq = AudioDaq(
            backend,
            ring_seconds=RING_S,
            host_clock=self.clock.now,
            virtual_time=self.virtual_time,
            url=self.exp.board_url,
        )
        self.daq = daq.open()
        daq.configure()
        return daq

    def _carriage(self, world_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = self.stage_time(world_t)
        if self._stage_sim is not None:
            return self._stage_sim.call(lambda g: g.carriage_motion(t))
        self._grbl.tick()  # every alarm and hold up to now applied before the plan is read
        return self._grbl.carriage_motion(t)

    def align(self, rate_hz: float) -> None:
        """Nothing to do: the stream's start ties world time to the clock."""

    def stage_time(self, world_t: np.ndarray) -> np.ndarray:
        """Clock time (s) of world times (s: device sample / rate): when that sample left the
        interface's DAC."""
        backend = self._backend
        if backend is None:
            raise RuntimeError("the simulated interface is not open: call open_daq first")
        lead = backend.start_time_s + backend.blocksize / backend.samplerate
        return np.asarray(world_t, dtype=np.float64) + lead

    def true_stage_position(self, clock_t: np.ndarray) -> np.ndarray:
        """The simulated carriage's true position (m) at clock times (s)."""
        return np.asarray(self._grbl.true_position(np.asarray(clock_t, dtype=np.float64)))

    @property
    def dac_underruns(self) -> int:
        """Output xruns the simulated interface reported."""
        return 0 if self.daq is None else self.daq.last_status.dac_underruns

    @property
    def adc_overruns(self) -> int:
        """Input xruns the simulated interface reported."""
        return 0 if self.daq is None else self.daq.last_status.adc_overruns

    @property
    def adc_clipped_samples(self) -> int | None:
        """Input values the simulated interface clipped at ±1.0 (None before it opened)."""
        return None if self._backend is None else self._backend.adc_clipped_samples

    def unplug_interface(self) -> None:
        """Fault injection: the simulated interface pulled out mid-run (its stream ends)."""
        if self._backend is None:
            raise RuntimeError("the simulated interface is not open: call open_daq first")
        self._backend.unplug()

    def lost(self, grace_s: float = 0.0) -> DeviceLostError | None:
        """Never: the simulation is this process."""
        return None

    def close(self) -> None:
        """Stop serving the stage's pty (real time); the driver closed the interface."""
        if self._stage_sim is not None:
            self._stage_sim.close()
