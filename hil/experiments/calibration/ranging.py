"""Echo ranging: the two-way time of flight to a target, to a small fraction of a sample.

A ping (Hann-windowed LFM chirp) is played; the recording is correlated with the ping's
analytic signal (FFT), the envelope's integer peak is searched inside a time-of-flight gate
(which keeps out the direct blast and late wall echoes), and the peak is refined by
band-limited interpolation of the correlation (its spectrum summed at fractional lags on a
1/32-sample grid around the integer peak) and a parabola through the three best grid points.
The envelope of a correlation is symmetric about the true delay, so the refinement is
unbiased for a pure delay. The loop latency (samples) is subtracted when known.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import fft as sp_fft
from scipy import signal as sp_signal

from hil.devices.audio.latency import lfm_chirp, mainlobe_halfwidth
from hil.errors import ConfigError
from hil.experiments.calibration.device import (
    CalibrationError,
    FloatArray,
    PlayRecordDevice,
    check_channel,
    check_positive_int,
)

#: Fractional-lag grid of the peak refinement, samples.
_FINE_STEP = 1.0 / 32.0


def default_ping(samplerate: float) -> FloatArray:
    """5 ms Hann-windowed LFM from 5 % to 35 % of the sample rate, amplitude 0.5, float64.

    >>> default_ping(96000).shape
    (480,)
    """
    chirp = lfm_chirp(samplerate, 0.05 * samplerate, 0.35 * samplerate, 0.005, taper_fraction=1.0)
    return chirp.astype(np.float64)


def refine_peak(spectrum: FloatArray, nfft: int, lag: int) -> tuple[float, float]:
    """Fractional lag (samples) and envelope value of the peak of the complex correlation
    whose full FFT is ``spectrum`` (shape (nfft,)), near the integer lag ``lag``."""
    keep = np.flatnonzero(np.abs(spectrum) > 1e-9 * np.abs(spectrum).max())
    taus = lag + np.arange(-32, 33) * _FINE_STEP
    kernel = np.exp(2j * np.pi * np.outer(taus, keep) / nfft)
    env = np.abs(kernel @ spectrum[keep]) / nfft
    i = int(np.clip(np.argmax(env), 1, env.size - 2))
    y0, y1, y2 = env[i - 1], env[i], env[i + 1]
    denom = y0 - 2.0 * y1 + y2
    shift = 0.0 if denom == 0 else 0.5 * (y0 - y2) / denom
    return float(taus[i] + shift * _FINE_STEP), float(y1)


@dataclass(frozen=True)
class EchoMeasurement:
    """One ping's echo.

    Attributes
    ----------
    lag_samples:
        Fractional lag of the echo in the recording (latency included), samples.
    time_of_flight_s:
        Two-way time of flight, latency removed, s.
    peak_to_sidelobe_db:
        Echo envelope peak over the largest other envelope value in the gate, dB.
    amplitude:
        Echo amplitude relative to the ping (full scale per full scale).
    """

    lag_samples: float
    time_of_flight_s: float
    peak_to_sidelobe_db: float
    amplitude: float


class EchoRanger:
    """Pings through a :class:`PlayRecordDevice` and times the echo inside a gate.

    Parameters
    ----------
    device:
        The play/record device (transducer on ``output_channel``, hydrophone on
        ``input_channel``).
    gate_s:
        (earliest, latest) two-way time of flight searched, s (latency excluded).
    latency_samples:
        Loop latency to subtract, samples (from a latency calibration; 0 if unknown: it
        then shows up as a constant offset).
    ping:
        The ping, shape (n,), full scale; default :func:`default_ping`.
    min_peak_to_sidelobe_db:
        Refuse (:class:`CalibrationError`) an echo that stands out less than this.
    averages:
        Pings per :meth:`measure`, averaged (the time-of-flight noise falls as 1/sqrt).
    """

    def __init__(
        self,
        device: PlayRecordDevice,
        gate_s: tuple[float, float],
        *,
        latency_samples: int = 0,
        ping: FloatArray | None = None,
        output_channel: int = 0,
        input_channel: int = 0,
        min_peak_to_sidelobe_db: float = 10.0,
        averages: int = 4,
    ) -> None:
        fs = device.samplerate
        if not (len(gate_s) == 2 and 0 <= gate_s[0] < gate_s[1] and math.isfinite(gate_s[1])):
            raise ConfigError(
                "gate_s", gate_s, "(earliest, latest) times of flight in s, 0 <= earliest < latest"
            )
        if isinstance(latency_samples, bool) or not isinstance(latency_samples, int):
            raise ConfigError("latency_samples", latency_samples, "an integer >= 0 (samples)")
        if latency_samples < 0:
            raise ConfigError("latency_samples", latency_samples, "an integer >= 0 (samples)")
        self.device = device
        self.gate_s = (float(gate_s[0]), float(gate_s[1]))
        self.latency_samples = latency_samples
        self.ping = default_ping(fs) if ping is None else np.asarray(ping, dtype=np.float64)
        self.output_channel = check_channel("output_channel", output_channel, device.channels_out)
        self.input_channel = check_channel("input_channel", input_channel, device.channels_in)
        self.min_peak_to_sidelobe_db = float(min_peak_to_sidelobe_db)
        self.averages = check_positive_int("averages", averages)
        self._first = latency_samples + math.floor(self.gate_s[0] * fs)
        self._last = latency_samples + math.ceil(self.gate_s[1] * fs)
        nfft = sp_fft.next_fast_len(self._last + 2 * self.ping.size)
        self._nfft = nfft
        self._ref_spec = np.conj(sp_fft.fft(sp_signal.hilbert(self.ping), nfft))
        self._halfwidth = mainlobe_halfwidth(self.ping)

    def measure(self) -> EchoMeasurement:
        """Ping ``averages`` times; the mean lag and amplitude, the worst peak-to-sidelobe."""
        pings = [self.ping_once() for _ in range(self.averages)]
        lag = float(np.mean([p.lag_samples for p in pings]))
        return EchoMeasurement(
            lag_samples=lag,
            time_of_flight_s=(lag - self.latency_samples) / self.device.samplerate,
            peak_to_sidelobe_db=min(p.peak_to_sidelobe_db for p in pings),
            amplitude=float(np.mean([p.amplitude for p in pings])),
        )

    def ping_once(self) -> EchoMeasurement:
        """Ping once and time the echo (see the module docstring)."""
        fs = self.device.samplerate
        out = np.zeros((self.ping.size, self.device.channels_out), dtype=np.float32)
        out[:, self.output_channel] = self.ping
        rec = self.device.run(out, tail_frames=self._last + self.ping.size)
        x = rec[:, self.input_channel].astype(np.float64)
        spectrum = sp_fft.fft(x, self._nfft) * self._ref_spec
        envelope = np.abs(sp_fft.ifft(spectrum))[self._first : self._last + 1]
        lag = self._first + int(np.argmax(envelope))
        peak = float(envelope[lag - self._first])
        i = lag - self._first
        others = np.concatenate(
            [envelope[: max(i - self._halfwidth, 0)], envelope[i + self._halfwidth + 1 :]]
        )
        side = float(others.max()) if others.size else 0.0
        if peak == 0.0:
            psl = -math.inf
        else:
            psl = math.inf if side == 0.0 else 20.0 * math.log10(peak / side)
        if not psl >= self.min_peak_to_sidelobe_db:
            raise CalibrationError(
                f"echo ranging: no clear echo in the gate {1e3 * self.gate_s[0]:.3f}-"
                f"{1e3 * self.gate_s[1]:.3f} ms on input {self.input_channel} (peak-to-"
                f"sidelobe {psl:.1f} dB, need >= {self.min_peak_to_sidelobe_db:g} dB); check "
                "that the target is in the beam and inside the gate, and the levels"
            )
        fine, value = refine_peak(spectrum, self._nfft, lag)
        energy = float(self.ping @ self.ping)
        return EchoMeasurement(
            lag_samples=fine,
            time_of_flight_s=(fine - self.latency_samples) / fs,
            peak_to_sidelobe_db=psl,
            amplitude=value / energy,
        )
