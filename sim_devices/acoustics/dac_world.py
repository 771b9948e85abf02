"""The acoustic world behind a simulated DAC/ADC device: what the hydrophone hears of what
the DAC actually emits.

:class:`AcousticWorld` follows the simulated board's world contract
(``world(dac_block, first_sample) -> adc_block``, see :mod:`sim_devices.board.worlds`);
:class:`InPlaceWorld` adapts it to the simulated audio interface's in-place contract
(:class:`hil.devices.audio.simulated.World`). Unlike
:class:`~sim_devices.acoustics.channel.Channel`, which evaluates the known transmit schedule
analytically, this world echoes the *sampled* DAC output, through the band-limited
fractional-delay path (:class:`~sim_devices.acoustics.echo.SampledEcho`): whatever the host
plays (HFC-CW, a calibration sweep, silence) is what comes back, off the target, its tank
images and, with ``tank_echoes``, the tank's own boundaries (:class:`StreamConvolver`).

Time base: sample ``n`` of the device is at ``t = n / fs`` seconds of the world (the device's
sample clock; a Live target trajectory is a function of that time). The converters add
``converter_delay_samples`` of latency (DAC reconstruction plus ADC anti-alias group delay,
real converters have tens of samples): ADC sample ``n`` holds the pressure at
``t = (n − converter_delay_samples) / fs``. That latency also keeps the world causal: an echo
never needs DAC samples later than those already emitted, even for the direct blast.

ADC channels: channel 0 is the hydrophone, in full-scale units through the
:class:`~sim_devices.acoustics.channel.Receiver` and *not clipped*: the device (simulated
board, simulated audio interface) converts it as its ADC does, clipping beyond full scale
and counting the clipped samples; further channels monitor the DAC drive
(channel ``k`` = DAC channel ``k − 1``, delayed by the converter latency), the reference a lab
records next to the hydrophone for latency and level calibration.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt
from scipy.signal import oaconvolve

from hil.errors import ConfigError
from sim_devices.acoustics.channel import (
    Channel,
    DirectBlast,
    Receiver,
    Target,
    _EchoGain,
    source_amplitude,
)
from sim_devices.acoustics.delay import OneWayPath, TwoWayPath
from sim_devices.acoustics.directivity import Transducer
from sim_devices.acoustics.echo import SampledEcho, TransmitHistory, history_capacity
from sim_devices.acoustics.noise_generator import ShapedNoiseGenerator
from sim_devices.acoustics.tank import Offset, Tank, echo_paths
from sim_devices.acoustics.tank_response import TankEchoSettings, tank_impulse_response
from sim_devices.acoustics.trajectory import FloatArray, Trajectory

# Interpolator half-length of SampledEcho's default Kaiser-sinc kernel (32 taps).
_HALF_TAPS = 16


class AcousticWorld:
    """DAC samples in, ADC samples out, through the tank (see the module docstring).

    Parameters
    ----------
    fs_hz:
        Device sample rate, Hz.
    sonar:
        Trajectory of the monostatic transducer (m).
    targets:
        Targets (trajectory + target strength); a Live trajectory follows a stage.
    sound_speed_mps:
        c, m/s.
    source_level_db:
        Source level of a full-scale DAC cosine, dB re 1 µPa @ 1 m (RMS).
    receiver:
        Hydrophone sensitivity, gain and ADC full scale.
    max_range_m:
        Longest echo path considered (sets the transmit history kept), m.
    tank, image_order:
        Tank walls/bottom/surface image paths, to ``image_order`` reflections per round trip
        (:mod:`~sim_devices.acoustics.tank`).
    tank_echoes:
        The tank's own echoes and late tail (transmitter → boundaries → hydrophone, no
        target), or None: the same impulse response as the analytic channel's
        (:func:`~sim_devices.acoustics.tank_response.tank_impulse_response`, with the beams
        and absorption), convolved with the DAC samples emitted so far
        (:class:`StreamConvolver`; the converter latency keeps it causal). Needs ``tank`` and
        a sonar at rest. The DAC was silent before the first block, so the tail builds up
        over the response's length instead of starting in the steady state.
    tx_beam, rx_beam:
        Projector and hydrophone directivity per path direction, or None (omni).
    absorption_db_per_km:
        Absorption applied on each leg, dB/km.
    direct_blast:
        Transmitter-to-hydrophone leakage, or None.
    noise:
        Ambient/self noise in µPa (seeded, chunk-invariant), or None.
    converter_delay_samples:
        Converter latency, samples (>= 17 so the interpolator stays causal).
    adc_channels:
        Number of ADC channels to produce (hydrophone + DAC monitors).
    max_block_samples:
        Longest block the device hands over (sizes the transmit history), samples.

    ``extra_pressure``, when set, is called as ``extra_pressure(first_sample, n)`` for more
    pressure (µPa) at the hydrophone, e.g. reverberation and noise from a target-free
    :class:`~sim_devices.acoustics.channel.Channel`.
    """

    def __init__(
        self,
        fs_hz: float,
        sonar: Trajectory,
        targets: Sequence[Target],
        *,
        sound_speed_mps: float,
        source_level_db: float,
        receiver: Receiver | None = None,
        max_range_m: float = 30.0,
        tank: Tank | None = None,
        image_order: int = 0,
        tank_echoes: TankEchoSettings | None = None,
        tx_beam: Transducer | None = None,
        rx_beam: Transducer | None = None,
        absorption_db_per_km: float = 0.0,
        direct_blast: DirectBlast | None = None,
        noise: ShapedNoiseGenerator | None = None,
        converter_delay_samples: int = 64,
        adc_channels: int = 1,
        max_block_samples: int = 1 << 18,
    ) -> None:
        if not (math.isfinite(fs_hz) and fs_hz > 0):
            raise ConfigError("fs_hz", fs_hz, "> 0 Hz")
        if not (math.isfinite(sound_speed_mps) and sound_speed_mps > 0):
            raise ConfigError("sound_speed_mps", sound_speed_mps, "> 0 m/s")
        if not (math.isfinite(max_range_m) and max_range_m > 0):
            raise ConfigError("max_range_m", max_range_m, "> 0 m")
        if int(converter_delay_samples) != converter_delay_samples or not (
            converter_delay_samples > _HALF_TAPS
        ):
            raise ConfigError(
                "converter_delay_samples",
                converter_delay_samples,
                f"an integer > {_HALF_TAPS} (the interpolator must not need future DAC samples)",
            )
        if int(adc_channels) != adc_channels or adc_channels < 1:
            raise ConfigError("adc_channels", adc_channels, "an integer >= 1")
        self.fs_hz = float(fs_hz)
        self.receiver = receiver or Receiver()
        self.noise = noise
        self.converter_delay = int(converter_delay_samples)
        self.adc_channels = int(adc_channels)
        self.max_delay_s = 2.0 * max_range_m / sound_speed_mps
        if int(max_block_samples) != max_block_samples or max_block_samples < 1:
            raise ConfigError("max_block_samples", max_block_samples, "an integer >= 1")
        self._block_capacity = int(max_block_samples)
        self._history = TransmitHistory(self.fs_hz, self._capacity(self._block_capacity))
        self.extra_pressure: Callable[[int, int], FloatArray] | None = None
        self._expected_first: int | None = None
        self._origin = 0
        amp = source_amplitude(source_level_db)
        self._echoes: list[SampledEcho] = []
        for tgt in targets:
            a = amp * 10.0 ** (tgt.target_strength_db / 20.0)
            for path in echo_paths(sonar, tgt.trajectory, tank, image_order):
                gain = _EchoGain(a * path.gain, path, tx_beam, rx_beam, absorption_db_per_km)
                solved = TwoWayPath(path.tx, path.target, path.rx, sound_speed_mps)
                self._echoes.append(SampledEcho(self._history, solved, self.fs_hz, gain=gain))
        if direct_blast is not None:
            tx = Offset(sonar, (0.0, 0.0, direct_blast.separation_m))
            a = amp * 10.0 ** (direct_blast.coupling_db / 20.0) / direct_blast.separation_m
            one_way = OneWayPath(tx, sonar, sound_speed_mps)
            self._echoes.append(SampledEcho(self._history, one_way, self.fs_hz, amplitude=a))
        self._tank_echoes: StreamConvolver | None = None
        if tank_echoes is not None:
            if tank is None:
                raise ConfigError(
                    "tank_echoes", tank_echoes, "a tank to echo in", "give the world a tank"
                )
            if sonar.max_speed_mps != 0.0:
                raise ConfigError(
                    "tank_echoes",
                    tank_echoes,
                    "a sonar at rest (its tank response is one fixed impulse response)",
                    "use a Fixed sonar trajectory or leave tank_echoes out",
                )
            at = sonar.position(np.zeros(1))[0]
            h = tank_impulse_response(
                tank, at, at, sound_speed_mps, self.fs_hz, tank_echoes,
                tx=tx_beam, rx=rx_beam, absorption_db_per_km=absorption_db_per_km,
            )  # fmt: skip
            # ADC sample n holds the pressure at (n - d) / fs: the response, d samples later.
            delayed = np.concatenate([np.zeros(self.converter_delay), amp * h])
            self._tank_echoes = StreamConvolver(delayed)

    def _capacity(self, block: int) -> int:
        return history_capacity(self.max_delay_s, block / self.fs_hz, self.fs_hz, _HALF_TAPS) + (
            self.converter_delay
        )

    def reset(self) -> None:
        """Forget the transmit history; the next block may start at any sample index."""
        self._expected_first = None

    def _start(self, first_sample: int) -> None:
        # The DAC was silent before the first block: history sample 0 is device sample
        # ``first_sample``, at t = first_sample / fs.
        self._history = TransmitHistory(
            self.fs_hz, self._capacity(self._block_capacity), t_start_s=first_sample / self.fs_hz
        )
        for e in self._echoes:
            e.history = self._history
        if self._tank_echoes is not None:
            self._tank_echoes.reset()

    def __call__(self, dac_block: npt.NDArray[np.floating], first_sample: int, /) -> FloatArray:
        """ADC samples ``first_sample …`` (shape ``(n, adc_channels)``) for the DAC block at
        the same indices (shape ``(n, dac_channels)`` or ``(n,)``), in sample order."""
        dac = np.asarray(dac_block, dtype=np.float64)
        if dac.ndim == 1:
            dac = dac[:, None]
        n = dac.shape[0]
        if self._expected_first is None:
            self._start(first_sample)
            self._origin = first_sample
        elif first_sample != self._expected_first:
            raise ConfigError(
                "first_sample",
                first_sample,
                f"{self._expected_first} (blocks arrive in sample order)",
                "reset() the world when a new stream starts",
            )
        if n > self._block_capacity:
            raise ConfigError(
                "dac_block",
                f"{n} samples",
                f"<= max_block_samples = {self._block_capacity}",
                "build the world with a larger max_block_samples",
            )
        self._history.push(dac[:, 0])
        self._expected_first = first_sample + n
        out = np.zeros((n, self.adc_channels))
        t = (np.arange(first_sample, first_sample + n) - self.converter_delay) / self.fs_hz
        pressure = np.zeros(n)
        for e in self._echoes:
            pressure += e.at_times(t)
        if self._tank_echoes is not None:
            pressure += self._tank_echoes.push(dac[:, 0])
        if self.noise is not None:
            pressure += self.noise.generate(n)
        if self.extra_pressure is not None:
            pressure += self.extra_pressure(first_sample, n)
        # The converter's input, not clipped: the device's ADC clips and counts it.
        out[:, 0] = self.receiver.to_full_scale(pressure)
        if self.adc_channels > 1:
            # DAC monitor channels: the drive, delayed by the converter latency.
            idx = np.arange(n) + (first_sample - self._origin) - self.converter_delay
            monitor = self._history.read(idx)
            for k in range(1, self.adc_channels):
                out[:, k] = monitor if k - 1 == 0 else 0.0
        return out


class StreamConvolver:
    """``y = h * x`` on a stream: each block of ``x`` (shape ``(n,)``) gives the next ``n``
    samples of the convolution, silence before the first block; any block split gives the
    same output (overlap-add: the part of each block's convolution past its end is carried).

    >>> c = StreamConvolver(np.array([1.0, 0.5]))
    >>> c.push(np.array([1.0, 0.0])).tolist(), c.push(np.array([2.0])).tolist()
    ([1.0, 0.5], [2.0])
    """

    def __init__(self, h: npt.ArrayLike) -> None:
        self.h = np.asarray(h, dtype=np.float64).reshape(-1)
        if self.h.size < 1 or not np.all(np.isfinite(self.h)):
            raise ConfigError("h", self.h.shape, "at least one finite tap")
        self._carry = np.zeros(self.h.size - 1)

    def reset(self) -> None:
        """Silence before the next block."""
        self._carry[:] = 0.0

    def push(self, x: npt.ArrayLike) -> FloatArray:
        """The next ``len(x)`` output samples."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        n, m = x.size, self.h.size
        total = np.zeros(n + m - 1)
        total[: m - 1] += self._carry
        if n:
            total += oaconvolve(x, self.h)
        self._carry = total[n:].copy()
        return total[:n]


class InPlaceWorld:
    """Adapter to the simulated audio interface's world contract:
    ``world(output_block, sample_index, input_block)`` fills ``input_block`` in place."""

    def __init__(self, world: AcousticWorld) -> None:
        self.world = world

    def reset(self) -> None:
        """Forget state (the audio backend calls this when a stream opens)."""
        self.world.reset()

    def __call__(
        self,
        output_block: npt.NDArray[np.floating],
        sample_index: int,
        input_block: npt.NDArray[np.floating],
        /,
    ) -> None:
        adc = self.world(output_block, sample_index)
        channels = min(adc.shape[1], input_block.shape[1])
        input_block[:, :channels] = adc[:, :channels]
        input_block[:, channels:] = 0.0


class ScheduleWorld:
    """A faster world for a device that transmits a known schedule from its first sample:
    the hydrophone channel comes from the analytic :class:`Channel` (exact echoes of the
    schedule, tank images, direct blast, reverberation, noise), the DAC monitor channels from
    the actual DAC samples. Same contract and converter latency as :class:`AcousticWorld`.

    The channel's time 0 is the device sample of the first block after :meth:`reset`; build
    it with the schedule shifted by the converter latency (``schedule.shifted(d / fs)``) so
    that ADC sample ``n`` holds the pressure at ``(n − d) / fs`` as for the sampled world.
    Use it when the DAC plays that schedule from the first sample (the tank run); use
    :class:`AcousticWorld` when the DAC may play anything.
    """

    def __init__(
        self,
        channel: Channel,
        *,
        converter_delay_samples: int = 64,
        adc_channels: int = 2,
    ) -> None:
        if int(converter_delay_samples) != converter_delay_samples or converter_delay_samples < 0:
            raise ConfigError("converter_delay_samples", converter_delay_samples, "an integer >= 0")
        if int(adc_channels) != adc_channels or adc_channels < 1:
            raise ConfigError("adc_channels", adc_channels, "an integer >= 1")
        self.channel = channel
        self.converter_delay = int(converter_delay_samples)
        self.adc_channels = int(adc_channels)
        self._expected_first: int | None = None
        self._monitor_tail = np.zeros(self.converter_delay)
        self.origin_index: int | None = None
        """Device sample of the channel's time 0 (the first block's index)."""

    def reset(self) -> None:
        """The next block may start at any index (the channel keeps its own position)."""
        self._expected_first = None

    def __call__(self, dac_block: npt.NDArray[np.floating], first_sample: int, /) -> FloatArray:
        """ADC samples for the DAC block at the same indices (see the class docstring)."""
        dac = np.asarray(dac_block, dtype=np.float64)
        if dac.ndim == 1:
            dac = dac[:, None]
        n = dac.shape[0]
        if self.origin_index is None:
            self.origin_index = int(first_sample)
        if self._expected_first is not None and first_sample != self._expected_first:
            raise ConfigError(
                "first_sample", first_sample, f"{self._expected_first} (blocks in sample order)"
            )
        self._expected_first = first_sample + n
        out = np.zeros((n, self.adc_channels))
        # The converter's input, not clipped: the device's ADC clips and counts it.
        out[:, 0] = self.channel.read_components(n, clip=False)["input_fs"]
        if self.adc_channels > 1:
            drive = np.concatenate([self._monitor_tail, dac[:, 0]])
            out[:, 1] = drive[:n]
            self._monitor_tail = drive[n:]
        return out
