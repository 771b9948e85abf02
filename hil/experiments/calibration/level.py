"""Level and gain: DAC full scale to received level, and hydrophone sensitivity.

A steady tone of known amplitude (full scale) is played; the received amplitude on each
input is a least-squares sine fit at the known frequency (cosine, sine and offset terms,
IEEE 1057 three-parameter fit) over a window that starts after the longest latency plus a
settling time, so it holds the steady state only. The gain is received over sent amplitude
(full scale per full scale, and dB); with the ADC full-scale voltage and the input gain the
received level is also given in volts.

Hydrophone sensitivity ``M`` (dB re 1 V/µPa) from a reference, two ways:

- :class:`ReferenceHydrophone`: a hydrophone of known sensitivity at the same point in the
  same field, recorded on another input: ``M = M_ref + 20 log10(V / V_ref)``;
- :class:`ReferenceSource`: a projector of known source level at a known distance:
  ``M = 20 log10(V_rms) - (SL + 20 log10(A) - 20 log10(r) - alpha r / 1000)``, with ``SL``
  the RMS source level (dB re 1 µPa @ 1 m) for a full-scale sine and ``A`` the drive
  amplitude (full scale); spherical spreading and absorption alpha (dB/km) over ``r`` (m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.errors import ConfigError
from hil.experiments.calibration.device import (
    CalibrationError,
    FloatArray,
    PlayRecordDevice,
    check_channel,
    check_positive_int,
)

KIND = "level"


def sine_fit(x: FloatArray, frequency_hz: float, samplerate: float) -> tuple[float, float]:
    """Amplitude (units of ``x``) and RMS residual of ``x`` (shape (n,)) fitted with
    ``a cos(w t) + b sin(w t) + c`` at the known frequency (least squares).

    >>> t = np.arange(4800) / 48000
    >>> amp, res = sine_fit(0.3 * np.sin(2 * np.pi * 1234.5 * t + 1.0) + 0.01, 1234.5, 48000)
    >>> round(amp, 9), res < 1e-12
    (0.3, True)
    """
    w = 2.0 * np.pi * frequency_hz * np.arange(x.size) / samplerate
    basis = np.stack([np.cos(w), np.sin(w), np.ones_like(w)], axis=1)
    coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
    residual = x - basis @ coef
    return float(math.hypot(coef[0], coef[1])), float(np.sqrt(np.mean(residual**2)))


@dataclass(frozen=True)
class ReferenceHydrophone:
    """A reference hydrophone on input ``channel`` with sensitivity ``sensitivity_db``
    (dB re 1 V/µPa) behind an input gain of ``gain_db`` (dB)."""

    channel: int
    sensitivity_db: float
    gain_db: float = 0.0


@dataclass(frozen=True)
class ReferenceSource:
    """A projector of known RMS source level at full-scale drive ``source_level_db``
    (dB re 1 µPa @ 1 m) at ``distance_m`` (m) from the hydrophone, with absorption
    ``absorption_db_per_km`` (dB/km) on the path."""

    source_level_db: float
    distance_m: float
    absorption_db_per_km: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.distance_m) and self.distance_m > 0):
            raise ConfigError("distance_m", self.distance_m, "a distance > 0 m")


@dataclass(frozen=True)
class LevelResult:
    """Gain of the output-to-input chain at one frequency, and optionally the sensitivity.

    Attributes
    ----------
    frequency_hz, drive_fs:
        The tone: frequency (Hz) and amplitude (full scale).
    received_fs:
        Received amplitude on the measured input, full scale.
    gain_fs_per_fs, gain_db:
        ``received_fs / drive_fs`` and ``20 log10`` of it.
    snr_db:
        Tone over fit residual, dB.
    adc_full_scale_v, input_gain_db:
        Volts at ADC full scale and the input's gain (dB) used to convert to volts.
    received_v:
        Received amplitude in volts at the hydrophone (before the input gain).
    sensitivity_db:
        Hydrophone sensitivity, dB re 1 V/µPa, or ``None`` without a reference.
    reference:
        How the sensitivity was found (``"none"``, ``"hydrophone"``, ``"source"``) and its
        parameters.
    """

    frequency_hz: float
    drive_fs: float
    received_fs: float
    gain_fs_per_fs: float
    gain_db: float
    snr_db: float
    adc_full_scale_v: float
    input_gain_db: float
    received_v: float
    sensitivity_db: float | None
    reference: dict[str, Any] = field(default_factory=lambda: {"method": "none"})
    output_channel: int = 0
    input_channel: int = 0

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (see :meth:`from_json`)."""
        return dict(self.__dict__)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> LevelResult:
        """Inverse of :meth:`to_json`."""
        return cls(**d)

    def summary(self) -> list[str]:
        """Human-readable lines for the command line."""
        lines = [
            f"level: tone {self.frequency_hz:g} Hz at {self.drive_fs:g} FS on output "
            f"{self.output_channel} -> {self.received_fs:.6g} FS on input {self.input_channel}",
            f"gain: {self.gain_fs_per_fs:.6g} FS/FS = {self.gain_db:.3f} dB "
            f"(SNR {self.snr_db:.1f} dB); received {self.received_v:.6g} V peak at the "
            f"sensor ({self.adc_full_scale_v:g} V full scale, input gain "
            f"{self.input_gain_db:g} dB)",
        ]
        if self.sensitivity_db is not None:
            lines.append(
                f"hydrophone sensitivity: {self.sensitivity_db:.2f} dB re 1 V/µPa "
                f"(from the reference {self.reference['method']})"
            )
        return lines


def calibrate_level(
    device: PlayRecordDevice,
    *,
    frequency_hz: float = 1000.0,
    amplitude: float = 0.25,
    duration_s: float = 0.5,
    settle_s: float = 0.02,
    max_latency_frames: int | None = None,
    output_channel: int = 0,
    input_channel: int = 0,
    adc_full_scale_v: float = 1.0,
    input_gain_db: float = 0.0,
    reference: ReferenceHydrophone | ReferenceSource | None = None,
    min_snr_db: float = 20.0,
) -> LevelResult:
    """Measure the chain's gain at ``frequency_hz`` and, with a reference, the sensitivity.

    Parameters
    ----------
    frequency_hz, amplitude, duration_s:
        The tone (Hz, full scale, s).
    settle_s:
        Time after the longest latency left out of the fit (transducer ring-up), s.
    max_latency_frames:
        Longest loop latency, samples; default 0.1 s.
    adc_full_scale_v, input_gain_db:
        Volts at ADC full scale and the measured input's gain in dB (to report volts).
    reference:
        A :class:`ReferenceHydrophone` or :class:`ReferenceSource` for the sensitivity.
    min_snr_db:
        Refuse (:class:`CalibrationError`) below this tone-to-residual ratio.

    Examples
    --------
    >>> from hil.devices.audio import AudioSettings, DigitalLoopbackWorld, SimulatedDuplex
    >>> from hil.experiments.calibration.device import from_duplex
    >>> sim = SimulatedDuplex(AudioSettings(48000), DigitalLoopbackWorld(5, gain=0.5))
    >>> r = calibrate_level(from_duplex(sim))
    >>> round(r.gain_fs_per_fs, 6), round(r.gain_db, 3)
    (0.5, -6.021)
    """
    fs = device.samplerate
    check_channel("output_channel", output_channel, device.channels_out)
    check_channel("input_channel", input_channel, device.channels_in)
    if not 0 < frequency_hz < fs / 2:
        raise ConfigError("frequency_hz", frequency_hz, f"in (0, {fs / 2:g}) Hz (Nyquist)")
    if not 0 < amplitude <= 1:
        raise ConfigError("amplitude", amplitude, "in (0, 1] (full scale)")
    if not (math.isfinite(adc_full_scale_v) and adc_full_scale_v > 0):
        raise ConfigError("adc_full_scale_v", adc_full_scale_v, "a voltage > 0 V")
    if not math.isfinite(input_gain_db):
        raise ConfigError("input_gain_db", input_gain_db, "a finite gain, dB")
    max_lat = round(0.1 * fs) if max_latency_frames is None else max_latency_frames
    check_positive_int("max_latency_frames", max_lat, 0)
    n = round(duration_s * fs)
    first = max_lat + round(settle_s * fs)
    if n - first < round(10 * fs / frequency_hz):
        raise ConfigError(
            "duration_s", duration_s,
            f">= {(first + 10 * fs / frequency_hz) / fs:.3g} s (latency + settling + 10 cycles)",
            "lengthen the tone",
        )  # fmt: skip
    channels = [input_channel]
    if isinstance(reference, ReferenceHydrophone):
        check_channel("reference.channel", reference.channel, device.channels_in)
        channels.append(reference.channel)
    t = np.arange(n) / fs
    out = np.zeros((n, device.channels_out), dtype=np.float32)
    out[:, output_channel] = amplitude * np.sin(2.0 * np.pi * frequency_hz * t)
    rec = device.run(out, tail_frames=max_lat)
    amps, snrs = [], []
    for c in channels:
        x = rec[first:n, c].astype(np.float64)
        if np.max(np.abs(x)) >= 0.999:
            raise CalibrationError(
                f"level: input {c} clips (peak {np.max(np.abs(x)):.4f} FS); lower the drive "
                f"amplitude ({amplitude:g} FS) or the input gain"
            )
        amp, res = sine_fit(x, frequency_hz, fs)
        snr = -math.inf if amp == 0 else (math.inf if res == 0 else 20 * math.log10(amp / res))
        if not snr >= min_snr_db:
            raise CalibrationError(
                f"level: the {frequency_hz:g} Hz tone did not come back on input {c} (tone "
                f"{snr:.1f} dB above the residual, need >= {min_snr_db:g} dB): the loop looks "
                "open or the level is far too low; check wiring, mute and gain"
            )
        amps.append(amp)
        snrs.append(snr)
    volts = amps[0] * adc_full_scale_v / 10.0 ** (input_gain_db / 20.0)
    sensitivity, ref_info = _sensitivity(reference, volts, amps, adc_full_scale_v, amplitude)
    return LevelResult(
        frequency_hz=float(frequency_hz),
        drive_fs=float(amplitude),
        received_fs=amps[0],
        gain_fs_per_fs=amps[0] / amplitude,
        gain_db=20.0 * math.log10(amps[0] / amplitude),
        snr_db=min(snrs),
        adc_full_scale_v=float(adc_full_scale_v),
        input_gain_db=float(input_gain_db),
        received_v=volts,
        sensitivity_db=sensitivity,
        reference=ref_info,
        output_channel=output_channel,
        input_channel=input_channel,
    )


def _sensitivity(
    reference: ReferenceHydrophone | ReferenceSource | None,
    volts: float,
    amps: list[float],
    adc_full_scale_v: float,
    drive: float,
) -> tuple[float | None, dict[str, Any]]:
    """Sensitivity (dB re 1 V/µPa) of the measured hydrophone from its reference."""
    if reference is None:
        return None, {"method": "none"}
    if isinstance(reference, ReferenceHydrophone):
        ref_volts = amps[1] * adc_full_scale_v / 10.0 ** (reference.gain_db / 20.0)
        m = reference.sensitivity_db + 20.0 * math.log10(volts / ref_volts)
        return m, {"method": "hydrophone", **reference.__dict__}
    r = reference.distance_m
    received_spl = (
        reference.source_level_db
        + 20.0 * math.log10(drive)
        - 20.0 * math.log10(r)
        - reference.absorption_db_per_km * r / 1000.0
    )
    v_rms = volts / math.sqrt(2.0)
    return 20.0 * math.log10(v_rms) - received_spl, {"method": "source", **reference.__dict__}
