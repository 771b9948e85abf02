"""Simulated worlds with injected truths, for the tests and for ``hil calibrate`` without a device.

- :class:`FirWorld`: a :class:`~hil.devices.audio.simulated.World` for
  :class:`~hil.devices.audio.SimulatedDuplex`: every input channel receives the output
  through its own FIR, an integer delay and white noise (loopback cable, transducer pair,
  hydrophones).
- :func:`resonant_transducer_fir`: a transducer pair with one resonance and a mounting
  reflection.
- :class:`MechanicalStage`: wraps a stage (the GRBL driver on the simulated controller) and
  adds a scale error and backlash (dead band) between motor and carriage.
- :class:`EchoTank`: a play/record device whose input is the exact echo of a target on the
  carriage (``sim_devices`` two-way path and band-limited echo synthesis), plus direct blast,
  latency and noise.
- :class:`SimTruth` and the ``sim_*`` factories: the default simulated bench of each
  calibration and a description of what it should find.

``sim_devices`` is only imported inside functions (the host never imports it at module level).
Unlike a real-time world, :class:`FirWorld` allocates per block (``lfilter`` state); the
simulated duplex runs on a manual clock, so no deadline is missed.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import signal as sp_signal

from hil.devices.stage import StageStatus
from hil.errors import ConfigError
from hil.experiments.calibration.device import (
    Float32Array,
    FloatArray,
    PlayRecordDevice,
    from_duplex,
)
from hil.experiments.calibration.level import ReferenceHydrophone, ReferenceSource
from hil.experiments.calibration.positions import PositioningStage


class FirWorld:
    """Input channel ``k`` = ``fir[:, k]`` applied to output ``source_channel``, delayed by
    ``delay_samples``, plus white noise of RMS ``noise_rms`` (full scale).

    ``fir`` has shape (taps,) (every input channel alike) or (taps, channels_in).

    Examples
    --------
    >>> w = FirWorld([0.0, 0.5], delay_samples=2)
    >>> out = np.zeros((4, 1), np.float32); out[0, 0] = 1.0
    >>> inp = np.empty((4, 1), np.float32)
    >>> w(out, 0, inp); inp[:, 0].tolist()
    [0.0, 0.0, 0.0, 0.5]
    """

    def __init__(
        self,
        fir: npt.ArrayLike,
        *,
        delay_samples: int = 0,
        noise_rms: float = 0.0,
        seed: int = 0,
        source_channel: int = 0,
    ) -> None:
        h = np.asarray(fir, dtype=np.float64)
        self.fir = h[:, None] if h.ndim == 1 else h
        if self.fir.ndim != 2 or self.fir.shape[0] < 1 or not np.all(np.isfinite(self.fir)):
            raise ConfigError("fir", h.shape, "finite taps of shape (taps,) or (taps, ch_in)")
        if isinstance(delay_samples, bool) or not isinstance(delay_samples, int):
            raise ConfigError("delay_samples", delay_samples, "an integer >= 0")
        if delay_samples < 0:
            raise ConfigError("delay_samples", delay_samples, "an integer >= 0")
        if not (math.isfinite(noise_rms) and noise_rms >= 0):
            raise ConfigError("noise_rms", noise_rms, ">= 0 (full scale)")
        self.delay_samples = delay_samples
        self.noise_rms = float(noise_rms)
        self.source_channel = source_channel
        self._rng = np.random.default_rng(seed)
        self.reset()

    def reset(self) -> None:
        """Silence before the first output sample (the noise stream goes on)."""
        taps, channels = self.fir.shape
        self._zi = np.zeros((channels, taps - 1))
        self._pending = np.zeros((self.delay_samples, channels))

    def __call__(
        self, output_block: Float32Array, sample_index: int, input_block: Float32Array
    ) -> None:
        x = output_block[:, self.source_channel].astype(np.float64)
        frames = x.size
        channels = self.fir.shape[1]
        y = np.empty((frames, channels))
        for k in range(channels):
            y[:, k], self._zi[k] = sp_signal.lfilter(self.fir[:, k], [1.0], x, zi=self._zi[k])
        queue = np.concatenate([self._pending, y])
        self._pending = queue[frames:]
        got = queue[:frames]
        if self.noise_rms:
            got = got + self.noise_rms * self._rng.standard_normal(got.shape)
        n = min(channels, input_block.shape[1])
        input_block[:, :n] = got[:, :n]
        input_block[:, n:] = 0.0


def resonant_transducer_fir(
    samplerate: float,
    resonance_hz: float,
    q: float,
    *,
    taps: int = 256,
    gain: float = 1.0,
    reflection_gain: float = 0.0,
    reflection_delay_s: float = 0.0,
) -> FloatArray:
    """Impulse response (taps,) of a transducer pair: a second-order resonance (peak gain
    ``gain`` at ``resonance_hz``, quality ``q``) plus a mounting reflection of relative gain
    ``reflection_gain`` arriving ``reflection_delay_s`` later (rounded to whole samples).

    >>> h = resonant_transducer_fir(48000, 9000, 2.5)
    >>> f = np.array([9000.0]); w = np.exp(-2j * np.pi * np.outer(f, np.arange(256)) / 48000)
    >>> round(float(abs(w @ h)[0]), 4)
    1.0
    """
    b, a = sp_signal.iirpeak(resonance_hz, q, samplerate)
    impulse = np.zeros(taps)
    impulse[0] = 1.0
    h = gain * sp_signal.lfilter(b, a, impulse)
    d = round(reflection_delay_s * samplerate)
    if reflection_gain and d < taps:
        h[d:] += reflection_gain * h[: taps - d]
    return np.asarray(h)


class MechanicalStage:
    """A stage whose carriage follows the motor through a scale error and backlash.

    The motor position is what the controller reports after each move. Between motor and
    carriage there is a dead band of width ``backlash_m``: the carriage is dragged along only
    once the motor has taken up the play. The carriage position is ``scale`` times the
    dragged point (m, machine frame). Every move goes through :meth:`move_to`, so the dead
    band sees every reversal.
    """

    def __init__(self, inner: PositioningStage, *, scale: float = 1.0, backlash_m: float = 0.0):
        self.inner = inner
        self.scale = float(scale)
        self.backlash_m = float(backlash_m)
        self._dragged: float | None = None

    @property
    def limits(self) -> tuple[float, float]:
        """The inner stage's soft limits, m."""
        return self.inner.limits

    def move_to(
        self, x: float, v: float, a: float | None = None, *, wait: bool = True
    ) -> StageStatus:
        """Move the motor (inner stage) and drag the carriage through the dead band."""
        status = self.inner.move_to(x, v, a, wait=wait)
        motor = status.position
        half = self.backlash_m / 2.0
        if self._dragged is None:
            self._dragged = motor
        elif motor - self._dragged > half:
            self._dragged = motor - half
        elif self._dragged - motor > half:
            self._dragged = motor + half
        return status

    @property
    def carriage_m(self) -> float:
        """True carriage position, m (the truth the calibration must find)."""
        if self._dragged is None:
            raise ConfigError("carriage", None, "a position after the first move", "move first")
        return self.scale * self._dragged


class EchoTank:
    """A tank with a target on the carriage: a play/record device with the exact echo.

    The transducer sits at the origin looking along +x; the target is at range
    ``standoff_m + carriage`` (m). Input = latency-delayed (direct blast + echo of amplitude
    ``echo_amplitude`` at 1 m, spherical spreading ``1/R^2``) + white noise.
    """

    def __init__(
        self,
        stage: MechanicalStage,
        *,
        sound_speed_mps: float,
        samplerate: float = 96000.0,
        standoff_m: float = 1.5,
        latency_samples: int = 300,
        echo_amplitude: float = 0.2,
        direct_blast: float = 0.05,
        noise_rms: float = 1e-3,
        seed: int = 0,
    ) -> None:
        self.stage = stage
        self.sound_speed_mps = float(sound_speed_mps)
        self.samplerate = float(samplerate)
        self.standoff_m = float(standoff_m)
        self.latency_samples = int(latency_samples)
        self.echo_amplitude = float(echo_amplitude)
        self.direct_blast = float(direct_blast)
        self.noise_rms = float(noise_rms)
        self._rng = np.random.default_rng(seed)

    def range_m(self) -> float:
        """True range to the target now, m."""
        return self.standoff_m + self.stage.carriage_m

    def play_record(self, output: Float32Array) -> Float32Array:
        """The recording (n, 1) for ``output`` (n, channels_out) played now."""
        from sim_devices.acoustics.delay import TwoWayPath
        from sim_devices.acoustics.echo import sampled_echo
        from sim_devices.acoustics.trajectory import Fixed

        x = output[:, 0].astype(np.float64)
        n = x.size
        r = self.range_m()
        sonar = Fixed((0.0, 0.0, 0.0))
        path = TwoWayPath(sonar, Fixed((r, 0.0, 0.0)), sonar, self.sound_speed_mps)
        t = np.arange(n) / self.samplerate
        rx = sampled_echo(x, self.samplerate, path, t, amplitude=self.echo_amplitude / r**2)
        rx += self.direct_blast * x
        rec = np.zeros(n)
        d = self.latency_samples
        rec[d:] = rx[: n - d]
        rec += self.noise_rms * self._rng.standard_normal(n)
        return rec[:, None].astype(np.float32)

    def device(self) -> PlayRecordDevice:
        """This tank as a play/record device (one output, one input)."""
        return PlayRecordDevice(self.play_record, self.samplerate, 1, 1, "sim://tank")


@dataclass(frozen=True)
class SimTruth:
    """The truths injected into the default simulated bench (printed by ``hil calibrate``)."""

    samplerate: float = 48000.0
    blocksize: int = 256
    io_delay_samples: int = 512
    cable_delay_samples: int = 37
    cable_gain: float = 0.35
    noise_rms: float = 1e-4
    resonance_hz: float = 9000.0
    resonance_q: float = 2.5
    reflection_gain: float = 0.3
    reflection_delay_s: float = 0.4e-3
    source_level_db: float = 180.0
    distance_m: float = 1.0
    sensitivity_db: float = -203.5
    input_gain_db: float = 20.0
    reference_sensitivity_db: float = -211.0
    reference_gain_db: float = 26.0
    adc_full_scale_v: float = 2.0
    temperature_c: float = 18.3
    tank_samplerate: float = 96000.0
    tank_latency_samples: int = 300
    standoff_m: float = 1.5
    stage_scale: float = 1.0015
    backlash_m: float = 150e-6
    seed: int = 1

    @property
    def latency_samples(self) -> int:
        """Loopback latency of the simulated cable, samples."""
        return self.io_delay_samples + self.cable_delay_samples

    @property
    def sound_speed_mps(self) -> float:
        """c of the simulated tank water (Marczak at ``temperature_c``), m/s."""
        from sim_devices.acoustics.sound_speed import tank_sound_speed

        return float(tank_sound_speed(self.temperature_c))

    def hydrophone_gains(self) -> tuple[float, float]:
        """Full scale received per full-scale drive on (measured, reference) hydrophones."""
        from sim_devices.acoustics.channel import Receiver, source_amplitude

        p_peak = source_amplitude(self.source_level_db) / self.distance_m  # µPa per FS
        gains = []
        for m, g in (
            (self.sensitivity_db, self.input_gain_db),
            (self.reference_sensitivity_db, self.reference_gain_db),
        ):
            rx = Receiver(m, g, self.adc_full_scale_v)
            gains.append(float(rx.to_counts(np.array([p_peak]))[0]))
        return gains[0], gains[1]

    def transducer_fir(self) -> FloatArray:
        """The simulated transducer pair's impulse response."""
        return resonant_transducer_fir(
            self.samplerate, self.resonance_hz, self.resonance_q,
            reflection_gain=self.reflection_gain, reflection_delay_s=self.reflection_delay_s,
        )  # fmt: skip


def _duplex(truth: SimTruth, world: FirWorld, channels_in: int) -> PlayRecordDevice:
    from hil.devices.audio import AudioSettings, SimulatedDuplex

    settings = AudioSettings(
        samplerate=truth.samplerate, channels_in=channels_in, blocksize=truth.blocksize
    )
    sim = SimulatedDuplex(settings, world, io_delay_samples=truth.io_delay_samples)
    return from_duplex(sim, "sim://audio")


def sim_loopback(truth: SimTruth) -> tuple[PlayRecordDevice, list[str]]:
    """A cable with gain and delay, and what a latency calibration should find."""
    world = FirWorld(
        [truth.cable_gain], delay_samples=truth.cable_delay_samples,
        noise_rms=truth.noise_rms, seed=truth.seed,
    )  # fmt: skip
    return _duplex(truth, world, 1), [
        f"simulated loopback at {truth.samplerate:g} Hz: I/O delay {truth.io_delay_samples} + "
        f"cable {truth.cable_delay_samples} samples -> expect latency "
        f"{truth.latency_samples} samples; cable gain {truth.cable_gain:g} "
        f"({20 * math.log10(truth.cable_gain):.3f} dB), noise {truth.noise_rms:g} FS RMS"
    ]


def sim_transducer(truth: SimTruth) -> tuple[PlayRecordDevice, list[str]]:
    """The resonant transducer pair, and what a response calibration should find."""
    world = FirWorld(
        truth.transducer_fir(), delay_samples=truth.cable_delay_samples,
        noise_rms=truth.noise_rms, seed=truth.seed,
    )  # fmt: skip
    return _duplex(truth, world, 1), [
        f"simulated transducer pair at {truth.samplerate:g} Hz: resonance "
        f"{truth.resonance_hz:g} Hz (Q {truth.resonance_q:g}, 0 dB peak), mounting reflection "
        f"{truth.reflection_gain:g} at {1e3 * truth.reflection_delay_s:g} ms, latency "
        f"{truth.latency_samples} samples, noise {truth.noise_rms:g} FS RMS"
    ]


def sim_hydrophones(truth: SimTruth) -> tuple[PlayRecordDevice, list[str]]:
    """Projector and two hydrophones (measured on input 0, reference on input 1)."""
    g_dut, g_ref = truth.hydrophone_gains()
    world = FirWorld(
        [[g_dut, g_ref]], delay_samples=truth.cable_delay_samples,
        noise_rms=truth.noise_rms, seed=truth.seed,
    )  # fmt: skip
    return _duplex(truth, world, 2), [
        f"simulated projector: {truth.source_level_db:g} dB re 1 µPa @ 1 m at full scale, "
        f"hydrophones at {truth.distance_m:g} m; input 0: {truth.sensitivity_db:g} dB re "
        f"1 V/µPa behind {truth.input_gain_db:g} dB -> expect gain {20 * math.log10(g_dut):.3f}"
        f" dB; input 1 (reference): {truth.reference_sensitivity_db:g} dB re 1 V/µPa behind "
        f"{truth.reference_gain_db:g} dB; ADC full scale {truth.adc_full_scale_v:g} V"
    ]


def default_references(truth: SimTruth) -> tuple[ReferenceHydrophone, ReferenceSource]:
    """The references matching :func:`sim_hydrophones`."""
    return (
        ReferenceHydrophone(1, truth.reference_sensitivity_db, truth.reference_gain_db),
        ReferenceSource(truth.source_level_db, truth.distance_m),
    )


@contextlib.contextmanager
def sim_tank(truth: SimTruth) -> Iterator[tuple[MechanicalStage, EchoTank, list[str]]]:
    """The GRBL driver on the simulated controller (in memory, manual clock) with the injected
    scale and backlash, and the echo tank around it; closed on exit.

    The controller powers up locked, as a GRBL with homing enabled does (``$22=1``), 5 mm
    from its homing switch: the stage is made ready (homed) as ``hil tank-run`` does."""
    from hil.devices.table import open_stage
    from sim_devices.stage import GrblSimConfig, ManualClock

    clock = ManualClock(0.0)
    config = GrblSimConfig(
        homing=True, soft_limits=False, hard_limits=False, power_up_position_mm=-5.0,
        max_rate_mm_min=6000.0, acceleration_mm_s2=500.0, steps_per_mm=80.0,
        max_travel_mm=500.0, status_mask=3,
        # The driver steps this manual clock by 0.5 s while it waits: a 2.4 ms reply would
        # cost it a whole step per line, so the lines are answered at once.
        line_latency_s=0.0,
    )  # fmt: skip
    # In memory, in this thread: the controller answers at once on the manual clock, so no
    # wait depends on how fast another thread is scheduled.
    with open_stage(
        "sim://stage?via=memory",
        clock=clock,
        wait_step=0.5,
        soft_limits=(-0.45, 0.0),
        transport_options={"config": config},
    ) as grbl:
        steps: list[str] = []
        grbl.make_ready(steps.append)
        stage = MechanicalStage(grbl, scale=truth.stage_scale, backlash_m=truth.backlash_m)
        tank = EchoTank(
            stage, sound_speed_mps=truth.sound_speed_mps, samplerate=truth.tank_samplerate,
            standoff_m=truth.standoff_m, latency_samples=truth.tank_latency_samples,
            seed=truth.seed,
        )  # fmt: skip
        lines = [
            f"simulated tank: fresh water at {truth.temperature_c:g} °C -> c = "
            f"{truth.sound_speed_mps:.3f} m/s (Marczak); target {truth.standoff_m:g} m + "
            f"carriage position from the transducer; stage scale {truth.stage_scale:g}, "
            f"backlash {1e6 * truth.backlash_m:g} µm; latency {truth.tank_latency_samples} "
            f"samples at {truth.tank_samplerate:g} Hz (GRBL simulated in memory)",
            *(f"simulated stage powered up locked ($22=1): {step}" for step in steps),
        ]
        yield stage, tank, lines
