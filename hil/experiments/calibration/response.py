"""Frequency response of the output-to-input chain by exponential sine sweep, and its equaliser.

Excitation: Farina's exponential sine sweep (ESS), ``x(t) = A sin(2 pi f1 L (e^(t/L) - 1))``
with ``L = T / ln(f2 / f1)``, faded in and out over a few cycles. Deconvolution: regularised
spectral division ``H = Y X* / (|X|^2 + eps(f))`` over a linear (non-circular) FFT length, with
``eps`` tiny inside the sweep band and large outside it. As with Farina's time-reversed
inverse filter, the harmonic distortion products of a mildly non-linear chain land at
negative times (the end of the FFT buffer), so the causal window that keeps the linear
impulse response drops them.

The impulse response is cut from ``pre_samples`` before its peak (that start is reported as
``delay_samples``: the loop latency plus the transducer's bulk delay) over ``ir_length``
samples with half-Hann fades at both ends. Its spectrum is the reported response (magnitude
in dB re full scale per full scale, phase in degrees relative to ``delay_samples``).

Equaliser: a Kirkeby regularised inverse ``G = H* e^(-j w m) / (|H|^2 + beta(f))`` with
``beta = 10^(regularisation_db/10) max|H|^2`` in the band of interest and ``max|H|^2`` outside
it (raised-cosine transitions), a modelling delay ``m = equaliser_taps / 2`` and a Hann
window, scaled to 0 dB mean gain in band. The residual ripple is the peak-to-peak spread of
``20 log10 |H G|`` over the band of interest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import fft as sp_fft
from scipy import signal as sp_signal

from hil.errors import ConfigError
from hil.experiments.calibration.device import (
    CalibrationError,
    FloatArray,
    PlayRecordDevice,
    check_channel,
    check_positive_int,
)

KIND = "response"

#: The longest measuring sweep, s: its samples (and the recording's) are held in memory.
MAX_SWEEP_S = 60.0
#: The longest equaliser, taps: its FFTs are of the taps' length.
MAX_EQUALISER_TAPS = 1 << 16


def exponential_sweep(
    samplerate: float,
    f_start_hz: float,
    f_stop_hz: float,
    duration_s: float,
    amplitude: float = 0.5,
) -> FloatArray:
    """Farina's exponential sine sweep, float64, shape (round(duration_s * samplerate),).

    Starts at phase 0; half-Hann fades of 3 start-frequency periods (in) and 1 ms (out)
    limit the spectral splatter of the edges.

    Examples
    --------
    >>> x = exponential_sweep(48000, 100, 20000, 0.5)
    >>> x.shape, round(float(np.abs(x).max()), 3)
    ((24000,), 0.5)
    >>> exponential_sweep(48000, 100, 30000, 0.5)
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: f_stop_hz = 30000 is not allowed: must be in (f_start_hz = 100, \
24000] Hz (Nyquist); lower the stop frequency or raise the sample rate
    """
    if not 0 < f_start_hz < samplerate / 2:
        raise ConfigError("f_start_hz", f_start_hz, f"in (0, {samplerate / 2:g}) Hz")
    if not f_start_hz < f_stop_hz <= samplerate / 2:
        raise ConfigError(
            "f_stop_hz",
            f_stop_hz,
            f"in (f_start_hz = {f_start_hz:g}, {samplerate / 2:g}] Hz (Nyquist)",
            "lower the stop frequency or raise the sample rate",
        )
    if not (math.isfinite(duration_s) and duration_s <= MAX_SWEEP_S):
        raise ConfigError(
            "duration_s", duration_s, f"a finite duration <= {MAX_SWEEP_S:g} s",
            "a sweep of a few seconds measures the response; repeat the calibration to average",
        )  # fmt: skip
    n = round(duration_s * samplerate)
    fade_in = round(3 * samplerate / f_start_hz)
    fade_out = round(1e-3 * samplerate)
    if n < 4 * (fade_in + fade_out):
        raise ConfigError(
            "duration_s", duration_s, f">= {4 * (fade_in + fade_out) / samplerate:g} s",
            "lengthen the sweep (or raise its start frequency)",
        )  # fmt: skip
    if not 0 < amplitude <= 1:
        raise ConfigError("amplitude", amplitude, "in (0, 1] (full scale)")
    t = np.arange(n) / samplerate
    rate = duration_s / math.log(f_stop_hz / f_start_hz)
    x = amplitude * np.sin(2 * np.pi * f_start_hz * rate * np.expm1(t / rate))
    x[:fade_in] *= sp_signal.windows.hann(2 * fade_in)[:fade_in]
    x[n - fade_out :] *= sp_signal.windows.hann(2 * fade_out)[fade_out:]
    return x


def band_weight(freqs_hz: FloatArray, low_hz: float, high_hz: float, edge: float) -> FloatArray:
    """1 inside ``[low_hz, high_hz]``, 0 beyond ``low/edge`` and ``high*edge``, raised-cosine
    in log frequency in between (``edge`` > 1). Shape of ``freqs_hz``.

    >>> band_weight(np.array([50.0, 100.0, 1000.0, 4000.0]), 100.0, 1000.0, 2.0).round(3)
    array([0., 1., 1., 0.])
    """
    f = np.maximum(np.asarray(freqs_hz, dtype=np.float64), 1e-12)
    lo = np.clip(np.log(f / (low_hz / edge)) / math.log(edge), 0.0, 1.0)
    hi = np.clip(np.log(high_hz * edge / f) / math.log(edge), 0.0, 1.0)
    return np.asarray(0.25 * (1 - np.cos(np.pi * lo)) * (1 - np.cos(np.pi * hi)))


@dataclass(frozen=True)
class ResponseResult:
    """Measured frequency response and its equaliser.

    Attributes
    ----------
    samplerate:
        Hz.
    band_hz:
        (low, high) band of interest, Hz: where the equaliser flattens and ripple is reported.
    sweep_hz:
        (start, stop) of the exponential sweep, Hz.
    delay_samples:
        Start of the impulse-response window in the recording, samples (loop latency plus
        bulk delay minus ``pre_samples``); the phase is relative to it.
    impulse_response:
        The windowed impulse response, full scale per full scale, shape (ir_length,).
    freqs_hz, magnitude_db, phase_deg:
        The response on the rfft grid of the impulse response (ir_length // 2 + 1 points):
        dB re 1 (FS/FS) and degrees (unwrapped).
    equaliser:
        The inverse FIR, shape (equaliser_taps,); apply with its ``equaliser_delay_samples``.
    equaliser_delay_samples:
        Modelling delay of the equaliser, samples.
    regularisation_db:
        In-band regularisation, dB re the peak ``|H|^2``.
    ripple_db:
        Peak-to-peak of ``20 log10 |H G|`` over the band of interest, dB (before: see
        :attr:`raw_ripple_db`).
    raw_ripple_db:
        Peak-to-peak of ``20 log10 |H|`` over the band of interest, dB.
    output_channel, input_channel:
        The channels measured.
    """

    samplerate: float
    band_hz: tuple[float, float]
    sweep_hz: tuple[float, float]
    delay_samples: int
    impulse_response: FloatArray = field(repr=False)
    freqs_hz: FloatArray = field(repr=False)
    magnitude_db: FloatArray = field(repr=False)
    phase_deg: FloatArray = field(repr=False)
    equaliser: FloatArray = field(repr=False)
    equaliser_delay_samples: int
    regularisation_db: float
    ripple_db: float
    raw_ripple_db: float
    output_channel: int = 0
    input_channel: int = 0

    def response(self, freqs_hz: FloatArray) -> FloatArray:
        """Complex response (FS/FS, phase relative to ``delay_samples``) at ``freqs_hz``."""
        return _dtft(self.impulse_response, freqs_hz, self.samplerate)

    def equalised(self, freqs_hz: FloatArray) -> FloatArray:
        """Complex ``H G`` at ``freqs_hz``, with the equaliser's modelling delay removed."""
        f = np.asarray(freqs_hz, dtype=np.float64)
        g = _dtft(self.equaliser, f, self.samplerate)
        shift = np.exp(2j * np.pi * f * self.equaliser_delay_samples / self.samplerate)
        return np.asarray(self.response(f) * g * shift)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (see :meth:`from_json`)."""
        d: dict[str, Any] = {}
        for key, value in self.__dict__.items():
            d[key] = value.tolist() if isinstance(value, np.ndarray) else value
        d["band_hz"], d["sweep_hz"] = list(self.band_hz), list(self.sweep_hz)
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> ResponseResult:
        """Inverse of :meth:`to_json`."""
        arrays = ("impulse_response", "freqs_hz", "magnitude_db", "phase_deg", "equaliser")
        kw: dict[str, Any] = {
            k: np.asarray(v, dtype=np.float64) if k in arrays else v for k, v in d.items()
        }
        kw["band_hz"] = (float(d["band_hz"][0]), float(d["band_hz"][1]))
        kw["sweep_hz"] = (float(d["sweep_hz"][0]), float(d["sweep_hz"][1]))
        return cls(**kw)

    def summary(self) -> list[str]:
        """Human-readable lines for the command line."""
        lo, hi = self.band_hz
        inband = (self.freqs_hz >= lo) & (self.freqs_hz <= hi)
        mag = self.magnitude_db[inband]
        f_peak = float(self.freqs_hz[inband][np.argmax(mag)])
        lines = [
            f"response: sweep {self.sweep_hz[0]:g}-{self.sweep_hz[1]:g} Hz at "
            f"{self.samplerate:g} Hz, band of interest {lo:g}-{hi:g} Hz "
            f"(output {self.output_channel} -> input {self.input_channel})",
            f"impulse response starts at {self.delay_samples} samples; in band: "
            f"{mag.min():.2f} to {mag.max():.2f} dB re FS/FS (peak at {f_peak:g} Hz)",
            f"equaliser: {self.equaliser.size} taps, delay {self.equaliser_delay_samples} "
            f"samples, regularisation {self.regularisation_db:g} dB; ripple in band "
            f"{self.raw_ripple_db:.2f} dB -> {self.ripple_db:.2f} dB peak-to-peak",
            "   f (Hz)   |H| (dB)   phase (deg)",
        ]
        for f in np.geomspace(lo, hi, 7):
            h = complex(self.response(np.array([f]))[0])
            lines.append(
                f"{f:9.0f}   {20 * math.log10(abs(h)):8.2f}   {math.degrees(np.angle(h)):9.1f}"
            )
        return lines


def _dtft(h: FloatArray, freqs_hz: FloatArray, fs: float) -> FloatArray:
    """Complex DTFT of the FIR ``h`` (first tap at time 0) at ``freqs_hz``."""
    f = np.asarray(freqs_hz, dtype=np.float64)
    n = np.arange(h.size)
    return np.asarray(np.exp(-2j * np.pi * np.outer(f, n) / fs) @ h)


def _check_band(band_hz: tuple[float, float], sweep_hz: tuple[float, float], fs: float) -> None:
    lo, hi = band_hz
    if not (sweep_hz[0] < lo < hi < sweep_hz[1] <= fs / 2):
        raise ConfigError(
            "band_hz",
            band_hz,
            f"low < high strictly inside the sweep {sweep_hz[0]:g}-{sweep_hz[1]:g} Hz "
            f"(and the sweep within Nyquist, {fs / 2:g} Hz)",
            "widen the sweep or narrow the band of interest",
        )


def impulse_response(
    sweep: FloatArray, recording: FloatArray, sweep_hz: tuple[float, float], fs: float
) -> FloatArray:
    """Linear impulse response from a sweep and its recording by regularised division.

    ``sweep`` shape (n,), ``recording`` shape (m,) (m >= n), both full scale; returns shape
    (n + m rounded up to a fast FFT size,): index k is a delay of k samples, negative delays
    (harmonic distortion) wrap to the end.
    """
    nfft = sp_fft.next_fast_len(sweep.size + recording.size)
    spec_x = sp_fft.rfft(sweep, nfft)
    spec_y = sp_fft.rfft(recording, nfft)
    freqs = sp_fft.rfftfreq(nfft, 1.0 / fs)
    power = np.abs(spec_x) ** 2
    weight = band_weight(freqs, sweep_hz[0], sweep_hz[1], 1.05)
    eps = power.max() * (1e-6 + (1.0 - weight))
    return np.asarray(sp_fft.irfft(spec_y * np.conj(spec_x) / (power + eps), nfft))


def kirkeby_equaliser(
    h: FloatArray,
    fs: float,
    band_hz: tuple[float, float],
    taps: int,
    regularisation_db: float,
) -> FloatArray:
    """Regularised inverse FIR of ``h`` (shape (taps,), modelling delay taps // 2); see the
    module docstring. Scaled to a mean ``|H G|`` of 1 over the band of interest."""
    nfft = sp_fft.next_fast_len(8 * max(taps, h.size))
    freqs = sp_fft.rfftfreq(nfft, 1.0 / fs)
    spec_h = sp_fft.rfft(h, nfft)
    inband = (freqs >= band_hz[0]) & (freqs <= band_hz[1])
    peak = float(np.max(np.abs(spec_h[inband]) ** 2))
    weight = band_weight(freqs, band_hz[0], band_hz[1], 1.25)
    beta = peak * (10.0 ** (regularisation_db / 10.0) * weight + (1.0 - weight))
    delay = taps // 2
    shift = np.exp(-2j * np.pi * freqs * delay / fs)
    spec_g = np.conj(spec_h) / (np.abs(spec_h) ** 2 + beta) * shift
    g = sp_fft.irfft(spec_g, nfft)[:taps] * sp_signal.windows.hann(taps, sym=False)
    check = np.abs(sp_fft.rfft(h, nfft) * sp_fft.rfft(g, nfft))[inband]
    return np.asarray(g / check.mean())


def _ripple_db(values: FloatArray) -> float:
    db = 20.0 * np.log10(np.maximum(np.abs(values), 1e-300))
    return float(db.max() - db.min())


def calibrate_response(
    device: PlayRecordDevice,
    *,
    band_hz: tuple[float, float] | None = None,
    sweep_hz: tuple[float, float] | None = None,
    duration_s: float = 1.0,
    amplitude: float = 0.5,
    ir_length: int = 1024,
    pre_samples: int = 64,
    equaliser_taps: int = 1024,
    regularisation_db: float = -40.0,
    max_latency_frames: int | None = None,
    output_channel: int = 0,
    input_channel: int = 0,
    min_snr_db: float = 20.0,
) -> ResponseResult:
    """Measure the response from ``output_channel`` to ``input_channel`` and design its
    equaliser.

    Parameters
    ----------
    band_hz:
        Band of interest (Hz); default 5 % to 40 % of the sample rate.
    sweep_hz:
        Sweep range (Hz); default half the band's low edge to the lower of 1.15 x its high
        edge and 0.48 fs.
    duration_s, amplitude:
        Sweep length (s) and amplitude (full scale); longer sweeps raise the SNR.
    ir_length, pre_samples:
        Impulse-response window length and how much of it precedes the peak, samples.
    equaliser_taps, regularisation_db:
        Equaliser length and in-band regularisation (dB re the peak ``|H|^2``).
    max_latency_frames:
        Longest loop latency plus bulk delay searched, samples; default 0.1 s.
    min_snr_db:
        Refuse (:class:`CalibrationError`) when the impulse-response peak stands less than
        this above the noise of the response's tail (open loop, far too low a level).
    """
    fs = device.samplerate
    check_channel("output_channel", output_channel, device.channels_out)
    check_channel("input_channel", input_channel, device.channels_in)
    band = (0.05 * fs, 0.4 * fs) if band_hz is None else (float(band_hz[0]), float(band_hz[1]))
    if not (0 < band[0] < band[1] < fs / 2):
        raise ConfigError(
            "band_hz", f"{band[0]:g} {band[1]:g}",
            f"LOW HIGH in Hz with 0 < LOW < HIGH < Nyquist ({fs / 2:g} Hz)",
            f"give the lower edge first, e.g. --band {min(band):g} {max(band):g}"
            if band[0] > band[1] else "narrow the band or raise --samplerate",
        )  # fmt: skip
    if sweep_hz is None:
        sweep = (0.5 * band[0], min(1.15 * band[1], 0.48 * fs))
    else:
        sweep = (float(sweep_hz[0]), float(sweep_hz[1]))
    _check_band(band, sweep, fs)
    check_positive_int("ir_length", ir_length, 16)
    check_positive_int("equaliser_taps", equaliser_taps, 16)
    if equaliser_taps > MAX_EQUALISER_TAPS:
        raise ConfigError(
            "equaliser_taps", equaliser_taps, f"an integer in [16, {MAX_EQUALISER_TAPS}]",
            "a transducer's response needs a few thousand taps at most",
        )  # fmt: skip
    if not math.isfinite(regularisation_db):
        raise ConfigError(
            "regularisation_db", regularisation_db, "a finite number of dB re peak |H|^2",
            "e.g. -40 (deeper: a sharper, noisier inverse)",
        )  # fmt: skip
    if isinstance(pre_samples, bool) or not isinstance(pre_samples, int):
        raise ConfigError("pre_samples", pre_samples, f"an integer in [0, {ir_length // 2}]")
    if not 0 <= pre_samples <= ir_length // 2:
        raise ConfigError("pre_samples", pre_samples, f"an integer in [0, {ir_length // 2}]")
    max_lat = round(0.1 * fs) if max_latency_frames is None else max_latency_frames
    check_positive_int("max_latency_frames", max_lat, 0)
    x = exponential_sweep(fs, sweep[0], sweep[1], duration_s, amplitude)
    out = np.zeros((x.size, device.channels_out), dtype=np.float32)
    out[:, output_channel] = x
    rec = device.run(out, tail_frames=max_lat + ir_length).astype(np.float64)[:, input_channel]
    h_full = impulse_response(x, rec, sweep, fs)
    search = np.abs(h_full[: max_lat + pre_samples + 1])
    peak = int(np.argmax(search))
    start = max(peak - pre_samples, 0)
    tail = h_full[max_lat + 2 * ir_length : h_full.size - 2 * ir_length]
    noise = float(np.sqrt(np.mean(tail**2))) if tail.size else 0.0
    top = float(search[peak])
    if top == 0.0:
        snr_db = -math.inf  # a silent input: nothing came back at all
    else:
        snr_db = math.inf if noise == 0.0 else 20.0 * math.log10(top / noise)
    if not snr_db >= min_snr_db:
        raise CalibrationError(
            f"response: no clear impulse response on input {input_channel} (peak "
            f"{snr_db:.1f} dB above the noise, need >= {min_snr_db:g} dB): the loop looks "
            "open or the level is far too low; check wiring and gain, or lengthen the sweep"
        )
    h = h_full[start : start + ir_length].copy()
    fade_in, fade_out = max(pre_samples // 2, 1), ir_length // 8
    h[:fade_in] *= sp_signal.windows.hann(2 * fade_in)[:fade_in]
    h[ir_length - fade_out :] *= sp_signal.windows.hann(2 * fade_out)[fade_out:]
    spec = sp_fft.rfft(h)
    freqs = sp_fft.rfftfreq(ir_length, 1.0 / fs)
    g = kirkeby_equaliser(h, fs, band, equaliser_taps, regularisation_db)
    grid = np.geomspace(band[0], band[1], 400)
    raw = _dtft(h, grid, fs)
    eq = raw * _dtft(g, grid, fs)
    return ResponseResult(
        samplerate=float(fs),
        band_hz=band,
        sweep_hz=sweep,
        delay_samples=start,
        impulse_response=h,
        freqs_hz=freqs,
        magnitude_db=20.0 * np.log10(np.maximum(np.abs(spec), 1e-300)),
        phase_deg=np.degrees(np.unwrap(np.angle(spec))),
        equaliser=g,
        equaliser_delay_samples=equaliser_taps // 2,
        regularisation_db=float(regularisation_db),
        ripple_db=_ripple_db(eq),
        raw_ripple_db=_ripple_db(raw),
        output_channel=output_channel,
        input_channel=input_channel,
    )
