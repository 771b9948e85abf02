"""A streaming, seeded generator of noise with a prescribed spectrum level (pressure in µPa).

Any spectrum model (``frequency_hz -> dB re 1 µPa²/Hz``; ambient, self-noise, radiated noise)
becomes a real time series at sample rate ``fs_hz``: seeded white noise is filtered by a
linear-phase FIR whose magnitude response is ``sqrt(P(f) fs / 2)``, so the output's
one-sided power spectral density is ``P(f) = 10**(L(f)/10)`` µPa²/Hz inside ``band_hz`` and
(near) zero outside.

Streaming and determinism. The white driving noise is cut into fixed blocks of
``block_size`` samples; block ``k`` is drawn from its own generator seeded with
``SeedSequence(seed, spawn_key=(k,))``. Each block is convolved with the filter by FFT and
overlap-added to the tail of the previous one. The samples therefore depend only on
``(seed, spectrum, fs, band, n_taps, block_size, alpha)``, never on how calls to
:meth:`ShapedNoiseGenerator.generate` chunk the stream: any chunking returns bit-identical
samples. One block is generated and discarded at start so the output is stationary from
sample 0 (no filter start-up transient).

Impulsive noise. With ``alpha`` set, the driving noise is symmetric alpha-stable
(:mod:`sim_devices.acoustics.alpha_stable`) with dispersion ``1/sqrt(2)``, so that
``alpha = 2`` gives unit-variance Gaussian driving noise and the same spectrum level as the
default; for ``alpha < 2`` the variance is infinite and the level describes the dispersion.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike
from scipy import fft as sp_fft
from scipy.signal import windows

from hil.errors import ConfigError
from sim_devices.acoustics._physics_inputs import FloatArray, as_float_array
from sim_devices.acoustics.alpha_stable import check_alpha, symmetric_alpha_stable
from sim_devices.acoustics.frame_stream import FrameStream

#: A spectrum model: frequencies (Hz, array) -> spectrum level (dB re 1 µPa²/Hz, same shape).
SpectrumLevel = Callable[[FloatArray], ArrayLike]

_KAISER_BETA = 8.6  # about -90 dB side lobes: strong low-frequency noise must not leak upward


def _check_fs(fs_hz: float) -> float:
    fs = float(fs_hz)
    if not (np.isfinite(fs) and fs > 0.0):
        raise ConfigError("fs_hz", fs_hz, "> 0 Hz", "give the sample rate in Hz, e.g. 96000")
    return fs


def _check_band(band_hz: tuple[float, float], fs: float) -> tuple[float, float]:
    band = as_float_array("band_hz", band_hz)
    if band.shape != (2,) or not 0.0 <= band[0] < band[1] <= fs / 2.0:
        raise ConfigError(
            "band_hz",
            tuple(np.atleast_1d(band).tolist()),
            f"(low, high) with 0 <= low < high <= fs/2 = {fs / 2.0:g} Hz",
            "the band is where the output follows the spectrum model",
        )
    return float(band[0]), float(band[1])


def design_shaping_filter(
    spectrum_level_db: SpectrumLevel, fs_hz: float, band_hz: tuple[float, float], n_taps: int
) -> FloatArray:
    """FIR taps, shape ``(n_taps,)``, turning unit-variance white noise into the spectrum.

    Frequency sampling on a grid of at least ``8 n_taps`` points, zero phase, then a Kaiser
    window (centre value 1, so smooth parts of the response keep their level). Band edges
    are abrupt in the target and spread over about ``6 fs / n_taps`` Hz in the result.

    Parameters
    ----------
    spectrum_level_db:
        Spectrum model, called with in-band frequencies in Hz (all > 0 unless the band
        starts at 0), returning dB re 1 µPa²/Hz.
    fs_hz:
        Sample rate, Hz.
    band_hz:
        ``(low, high)``, Hz, within ``[0, fs/2]``.
    n_taps:
        Filter length, odd, >= 3.
    """
    fs = _check_fs(fs_hz)
    low, high = _check_band(band_hz, fs)
    if isinstance(n_taps, bool) or not isinstance(n_taps, int) or n_taps < 3 or n_taps % 2 == 0:
        raise ConfigError("n_taps", n_taps, "an odd integer >= 3", "e.g. 1025")
    n_grid = int(2 ** np.ceil(np.log2(max(8 * n_taps, 4096))))
    freqs = sp_fft.rfftfreq(n_grid, 1.0 / fs)
    in_band = (freqs >= low) & (freqs <= high)
    power = np.zeros_like(freqs)
    levels = as_float_array("spectrum level", spectrum_level_db(freqs[in_band]))
    power[in_band] = 10.0 ** (levels / 10.0)
    amplitude = np.sqrt(power * fs / 2.0)
    impulse = sp_fft.irfft(amplitude, n_grid)
    centred = np.roll(impulse, n_taps // 2)[:n_taps]
    return np.asarray(centred * windows.kaiser(n_taps, _KAISER_BETA), dtype=np.float64)


def filter_level_db(taps: ArrayLike, fs_hz: float, frequency_hz: ArrayLike) -> FloatArray:
    """Spectrum level the taps give unit-variance white noise, dB re 1 µPa²/Hz (one-sided).

    ``10 log10(2 |H(f)|² / fs)`` at the requested frequencies (Hz).
    """
    fs = _check_fs(fs_hz)
    h = as_float_array("taps", taps)
    f = as_float_array("frequency_hz", frequency_hz)
    n = np.arange(h.shape[0])
    response = np.exp(-2j * np.pi * np.outer(f.reshape(-1), n) / fs) @ h
    level = 10.0 * np.log10(2.0 * np.abs(response) ** 2 / fs + 1e-300)
    return np.asarray(level.reshape(f.shape), dtype=np.float64)


class ShapedNoiseGenerator:
    """Endless noise in µPa with a model's spectrum level, any chunking giving the same samples.

    Parameters
    ----------
    spectrum_level_db:
        Spectrum model: Hz -> dB re 1 µPa²/Hz (e.g. an
        :class:`~sim_devices.acoustics.ambient_noise.AmbientNoiseModel`).
    fs_hz:
        Sample rate, Hz (> 0).
    band_hz:
        ``(low, high)`` in Hz where the output follows the model; zero outside.
    seed:
        Non-negative integer; the whole stream is a function of it.
    n_taps:
        Shaping-filter length (odd); the band-edge transition is about ``6 fs / n_taps`` Hz.
    block_size:
        Driving-noise block length, samples (>= n_taps). Part of the stream's identity.
    alpha:
        ``None`` for Gaussian noise, else the alpha-stable exponent (0, 2] of impulsive noise.

    Examples
    --------
    >>> from sim_devices.acoustics.ambient_noise import AmbientNoiseModel
    >>> gen = ShapedNoiseGenerator(AmbientNoiseModel(5.0), 96000.0, (1000.0, 40000.0), seed=7)
    >>> whole = ShapedNoiseGenerator(AmbientNoiseModel(5.0), 96000.0, (1000.0, 40000.0), seed=7)
    >>> parts = np.concatenate([gen.generate(n) for n in (1, 999, 20000, 3)])
    >>> bool(np.array_equal(parts, whole.generate(21003)))
    True
    """

    def __init__(
        self,
        spectrum_level_db: SpectrumLevel,
        fs_hz: float,
        band_hz: tuple[float, float],
        *,
        seed: int = 0,
        n_taps: int = 1025,
        block_size: int = 16384,
        alpha: float | None = None,
    ) -> None:
        self.fs_hz = _check_fs(fs_hz)
        self.band_hz = _check_band(band_hz, self.fs_hz)
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
            raise ConfigError("seed", seed, "an integer >= 0", "every simulated run is seeded")
        if (
            isinstance(block_size, bool)
            or not isinstance(block_size, int)
            or block_size < max(n_taps, 16)
        ):
            raise ConfigError(
                "block_size", block_size, f">= n_taps = {n_taps} (and >= 16)", "e.g. 16384"
            )
        self.seed = int(seed)
        self.alpha = None if alpha is None else check_alpha(alpha)
        self.block_size = block_size
        self.taps = design_shaping_filter(spectrum_level_db, self.fs_hz, self.band_hz, n_taps)
        self._nfft = sp_fft.next_fast_len(block_size + n_taps - 1, real=True)
        self._taps_fft = sp_fft.rfft(self.taps, self._nfft)
        self.reset()

    @property
    def n_taps(self) -> int:
        """Shaping-filter length, samples."""
        return int(self.taps.shape[0])

    @property
    def samples_generated(self) -> int:
        """Samples handed out since construction or :meth:`reset`."""
        return self._handed_out

    def reset(self) -> None:
        """Restart the stream from sample 0 (same seed, same samples)."""
        self._next_index = 0
        self._tail = np.zeros(self.n_taps - 1)
        self._stream = FrameStream(self._next_block)
        self._handed_out = 0
        self._next_block()  # prime the filter memory; block 0 itself is never output

    def _driving_noise(self, index: int) -> FloatArray:
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(index,)))
        if self.alpha is None:
            return rng.standard_normal(self.block_size)
        return symmetric_alpha_stable(self.alpha, self.block_size, rng, scale=np.sqrt(0.5))

    def _next_block(self) -> FloatArray:
        spectrum = sp_fft.rfft(self._driving_noise(self._next_index), self._nfft)
        full = sp_fft.irfft(spectrum * self._taps_fft, self._nfft)
        overlap = self.n_taps - 1
        out = full[: self.block_size].copy()
        out[:overlap] += self._tail
        self._tail = full[self.block_size : self.block_size + overlap].copy()
        self._next_index += 1
        return out

    def generate(self, n_samples: int) -> FloatArray:
        """The next ``n_samples`` of the stream, µPa, shape ``(n_samples,)``."""
        if isinstance(n_samples, bool) or not isinstance(n_samples, int | np.integer):
            raise ConfigError("n_samples", n_samples, "an integer >= 0", "a sample count")
        if n_samples < 0:
            raise ConfigError("n_samples", n_samples, "an integer >= 0", "a sample count")
        self._handed_out += int(n_samples)
        return self._stream.take(int(n_samples))
