"""Loopback latency measured with a reference chirp, at every run.

The driver's latency report is a claim; the loopback latency (DAC out to ADC in, in samples)
is measured instead: an LFM chirp is played, the recording is matched-filtered with it (FFT
cross-correlation), and the integer-sample lag of the correlation peak is the latency. The
peak-to-sidelobe ratio of the correlation envelope says how clean the measurement is.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import fft as sp_fft
from scipy import signal as sp_signal

from hil.devices.audio.contract import DuplexBackend, FloatArray, StatusFlags
from hil.devices.audio.playrec import as_output_frames, play_record
from hil.errors import ConfigError


class LatencyMeasurementError(RuntimeError):
    """The reference chirp was not found cleanly in the recording."""


def lfm_chirp(
    samplerate: float,
    f_start_hz: float,
    f_stop_hz: float,
    duration_s: float,
    *,
    amplitude: float = 0.5,
    taper_fraction: float = 0.1,
) -> FloatArray:
    """Linear-FM chirp with Tukey-tapered edges, float32, shape (round(duration * fs),).

    ``x[n] = amplitude * w[n] * sin(2 pi (f0 t + (f1 - f0) t^2 / (2 T)))`` with
    ``t = n / fs``; ``w`` is a Tukey window whose tapers cover ``taper_fraction`` of it.

    Examples
    --------
    >>> x = lfm_chirp(48000, 1000, 20000, 0.01)
    >>> x.shape, x.dtype, float(abs(x).max()) <= 0.5
    ((480,), dtype('float32'), True)
    >>> lfm_chirp(48000, 1000, 30000, 0.01)
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: f_stop_hz = 30000 is not allowed: must be in (0, 24000] Hz \
(Nyquist); lower the chirp's stop frequency
    """
    nyquist = samplerate / 2.0
    for name, f in (("f_start_hz", f_start_hz), ("f_stop_hz", f_stop_hz)):
        if not 0.0 < f <= nyquist:
            raise ConfigError(
                name, f, f"in (0, {nyquist:g}] Hz (Nyquist)", "lower the chirp's stop frequency"
            )
    n = round(duration_s * samplerate)
    if n < 16:
        raise ConfigError(
            "duration_s", duration_s, f">= {16 / samplerate:g} s (16 samples)", "lengthen it"
        )
    if not 0.0 < amplitude <= 1.0:
        raise ConfigError("amplitude", amplitude, "in (0, 1] (full scale)")
    t = np.arange(n) / samplerate
    sweep = (f_stop_hz - f_start_hz) / (n / samplerate)
    phase = 2.0 * np.pi * (f_start_hz * t + 0.5 * sweep * t * t)
    window = sp_signal.windows.tukey(n, taper_fraction)
    return (amplitude * window * np.sin(phase)).astype(np.float32)


def reference_chirp(samplerate: float) -> FloatArray:
    """The default reference: 20 ms, 5 % to 40 % of the sample rate, amplitude 0.5, Hann window.

    The full (Hann) taper keeps the matched-filter sidelobes low (about 48 dB below the peak
    at 192 kHz) at the cost of a main lobe a few samples wider; the integer peak is unchanged.

    >>> reference_chirp(192000).shape
    (3840,)
    """
    return lfm_chirp(samplerate, 0.05 * samplerate, 0.4 * samplerate, 0.02, taper_fraction=1.0)


@dataclass(frozen=True)
class LatencyMeasurement:
    """One measured delay of the reference in a recording.

    Attributes
    ----------
    samples:
        Integer-sample delay of the correlation peak.
    seconds:
        ``samples / samplerate``.
    peak_to_sidelobe_db:
        Correlation envelope peak over its highest sidelobe (outside the main lobe), dB.
    gain:
        Matched-filter peak over the reference energy: the loop gain (1.0 for an exact
        digital loopback, negative for an inverting one).
    """

    samples: int
    seconds: float
    peak_to_sidelobe_db: float
    gain: float


def mainlobe_halfwidth(reference: npt.ArrayLike) -> int:
    """Half width of the reference's autocorrelation main lobe: lag of the envelope's first dip.

    >>> mainlobe_halfwidth(lfm_chirp(48000, 2400, 19200, 0.02))
    3
    """
    ref = np.asarray(reference, dtype=np.float64)
    nfft = sp_fft.next_fast_len(2 * ref.size)
    spec = sp_fft.fft(sp_signal.hilbert(ref), nfft)
    envelope = np.abs(sp_fft.ifft(spec * np.conj(spec)))[: ref.size]
    rising = np.flatnonzero(np.diff(envelope) > 0)
    return int(rising[0]) if rising.size else ref.size


def matched_filter_delay(
    received: npt.ArrayLike, reference: npt.ArrayLike, samplerate: float
) -> LatencyMeasurement:
    """Delay (integer samples) of ``reference`` in ``received``, by FFT cross-correlation.

    Only lags where the whole reference fits in ``received`` are searched (0 to
    ``len(received) - len(reference)``). The peak is the largest ``|correlation|``; the
    peak-to-sidelobe ratio compares the correlation envelope (analytic reference) at the
    peak with its largest value outside +-:func:`mainlobe_halfwidth` of it.

    Examples
    --------
    >>> ref = reference_chirp(48000)
    >>> rx = np.zeros(5000, dtype=np.float32); rx[700:700 + ref.size] = 0.25 * ref
    >>> m = matched_filter_delay(rx, ref, 48000)
    >>> m.samples, round(m.gain, 6), m.peak_to_sidelobe_db > 10
    (700, 0.25, True)
    """
    rx = np.asarray(received, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if rx.ndim != 1 or ref.ndim != 1 or rx.size < ref.size:
        raise ConfigError(
            "received",
            rx.shape,
            f"1-D and at least as long as the reference ({ref.size} samples)",
            "record longer",
        )
    n_lags = rx.size - ref.size + 1
    nfft = sp_fft.next_fast_len(rx.size + ref.size)
    corr = sp_fft.ifft(sp_fft.fft(rx, nfft) * np.conj(sp_fft.fft(sp_signal.hilbert(ref), nfft)))
    corr = corr[:n_lags]
    peak = int(np.argmax(np.abs(corr.real)))
    envelope = np.abs(corr)
    half = mainlobe_halfwidth(ref)
    sidelobes = np.concatenate([envelope[: max(peak - half, 0)], envelope[peak + half + 1 :]])
    side = float(sidelobes.max()) if sidelobes.size else 0.0
    top = float(envelope[peak])
    if top <= 0.0:
        psl_db = -math.inf  # nothing correlates: no reference in the recording
    elif side == 0.0:
        psl_db = math.inf
    else:
        psl_db = 20.0 * math.log10(top / side)
    energy = float(ref @ ref)
    return LatencyMeasurement(
        samples=peak,
        seconds=peak / samplerate,
        peak_to_sidelobe_db=psl_db,
        gain=float(corr.real[peak]) / energy if energy else 0.0,
    )


@dataclass(frozen=True)
class LoopbackCalibration:
    """Result of :func:`measure_loopback_latency`.

    Attributes
    ----------
    latencies:
        One measurement per input channel checked, in the order asked.
    input_channels:
        The input channels measured.
    xruns:
        Xrun log of the calibration run, ``(sample_index, flags)``.
    recording:
        The raw recording (frames, channels_in), float32.
    """

    latencies: tuple[LatencyMeasurement, ...]
    input_channels: tuple[int, ...]
    xruns: list[tuple[int, StatusFlags]]
    recording: FloatArray


def _measure_channels(
    recording: FloatArray,
    chirp_start: int,
    ref: FloatArray,
    max_lat: int,
    channels: tuple[int, ...],
    fs: float,
    min_psl_db: float,
) -> tuple[LatencyMeasurement, ...]:
    """Latency of the chirp sent at ``chirp_start`` in each input channel, quality-checked."""
    latencies = []
    for c in channels:
        window = recording[chirp_start : chirp_start + ref.size + max_lat, c]
        m = matched_filter_delay(window, ref, fs)
        if not m.peak_to_sidelobe_db >= min_psl_db:
            raise LatencyMeasurementError(
                f"input channel {c}: the reference chirp was not found cleanly (peak-to-"
                f"sidelobe {m.peak_to_sidelobe_db:.1f} dB < {min_psl_db:g} dB, best lag "
                f"{m.samples} samples, gain {m.gain:.3g}); check the loopback wiring and "
                f"levels, or raise max_latency_frames ({max_lat})"
            )
        latencies.append(m)
    return tuple(latencies)


def measure_loopback_latency(
    backend: DuplexBackend,
    *,
    reference: npt.ArrayLike | None = None,
    lead_in_frames: int | None = None,
    max_latency_frames: int | None = None,
    input_channels: Sequence[int] | None = None,
    min_peak_to_sidelobe_db: float = 20.0,
    after_open: Callable[[], object] | None = None,
) -> LoopbackCalibration:
    """Play the reference chirp on every output channel and measure each input's latency.

    Parameters
    ----------
    backend:
        A closed full-duplex backend (opened, run and closed here).
    reference:
        The chirp, 1-D float within +-1; default :func:`reference_chirp` at the backend rate.
    lead_in_frames:
        Silence before the chirp (frames), default one block.
    max_latency_frames:
        Longest latency searched (frames), default ``max(16 * blocksize, 0.1 s)``.
    input_channels:
        Input channels to measure; default those with a matching output channel.
    min_peak_to_sidelobe_db:
        Below this peak-to-sidelobe ratio the measurement is refused
        (:class:`LatencyMeasurementError`): the loop is open, noisy or saturated.
    after_open:
        Passed to :func:`~hil.devices.audio.playrec.play_record` (e.g. JACK wiring).
    """
    fs = backend.samplerate
    ref = reference_chirp(fs) if reference is None else np.asarray(reference, np.float32)
    lead = backend.blocksize if lead_in_frames is None else lead_in_frames
    window = max(16 * backend.blocksize, round(0.1 * fs))
    max_lat = window if max_latency_frames is None else max_latency_frames
    for name, value in (("lead_in_frames", lead), ("max_latency_frames", max_lat)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ConfigError(name, value, "an integer >= 0 (frames)")
    default_channels = range(min(backend.channels_in, backend.channels_out))
    channels = tuple(default_channels if input_channels is None else input_channels)
    bad = [c for c in channels if not 0 <= c < backend.channels_in]
    if bad or not channels:
        raise ConfigError(
            "input_channels", channels, f"a non-empty list of indices in [0, {backend.channels_in})"
        )
    output = np.concatenate([np.zeros(lead, dtype=np.float32), ref])
    run = play_record(backend, output, extra_frames=max_lat, after_open=after_open)
    latencies = _measure_channels(
        run.recording, lead, ref, max_lat, channels, fs, min_peak_to_sidelobe_db
    )
    return LoopbackCalibration(
        latencies=latencies,
        input_channels=channels,
        xruns=run.xruns,
        recording=run.recording,
    )


@dataclass(frozen=True)
class CalibratedRecording:
    """Result of :func:`play_record_calibrated`.

    Attributes
    ----------
    recording:
        Input aligned to the output, shape (frames of the signal, channels measured),
        float32: row ``n`` holds what came back of output sample ``n``.
    calibration:
        The latency measured in this same run, per input channel.
    """

    recording: FloatArray
    calibration: LoopbackCalibration


def play_record_calibrated(
    backend: DuplexBackend,
    output: npt.ArrayLike,
    *,
    max_latency_frames: int | None = None,
    min_peak_to_sidelobe_db: float = 20.0,
    after_open: Callable[[], object] | None = None,
) -> CalibratedRecording:
    """Play the reference chirp then ``output`` in one stream; return the aligned recording.

    The stream plays one block of silence, the reference chirp, ``max_latency_frames`` of
    silence (so the chirp's return cannot overlap the signal's) and the signal. The latency
    measured on the chirp aligns each input channel: the latency is measured at every run
    instead of trusted from the driver.

    Examples
    --------
    >>> from hil.devices.audio import AudioSettings, DigitalLoopbackWorld, SimulatedDuplex
    >>> sim = SimulatedDuplex(AudioSettings(samplerate=48000, blocksize=64),
    ...                       DigitalLoopbackWorld(7), io_delay_samples=64)
    >>> sig = np.linspace(-0.5, 0.5, 1000, dtype=np.float32)
    >>> run = play_record_calibrated(sim, sig, max_latency_frames=1024)
    >>> run.calibration.latencies[0].samples, bool(np.array_equal(run.recording[:, 0], sig))
    (71, True)
    """
    fs = backend.samplerate
    ref = reference_chirp(fs)
    lead = backend.blocksize
    max_lat = max(16 * backend.blocksize, round(0.1 * fs))
    if max_latency_frames is not None:
        max_lat = max_latency_frames
    if isinstance(max_lat, bool) or not isinstance(max_lat, int) or max_lat < 0:
        raise ConfigError("max_latency_frames", max_lat, "an integer >= 0 (frames)")
    signal = as_output_frames(output, backend.channels_out)
    prefix = np.zeros((lead + ref.size + max_lat, backend.channels_out), dtype=np.float32)
    prefix[lead : lead + ref.size] = ref[:, None]
    run = play_record(
        backend,
        np.concatenate([prefix, signal]),
        extra_frames=max_lat,
        after_open=after_open,
    )
    channels = tuple(range(min(backend.channels_in, backend.channels_out)))
    latencies = _measure_channels(
        run.recording, lead, ref, max_lat, channels, fs, min_peak_to_sidelobe_db
    )
    start = prefix.shape[0]
    n = signal.shape[0]
    aligned = np.stack(
        [
            run.recording[start + m.samples : start + m.samples + n, c]
            for c, m in zip(channels, latencies, strict=True)
        ],
        axis=1,
    )
    calibration = LoopbackCalibration(
        latencies=latencies,
        input_channels=channels,
        xruns=run.xruns,
        recording=run.recording,
    )
    return CalibratedRecording(recording=aligned, calibration=calibration)
