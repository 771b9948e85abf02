"""Ambiguity functions of the transmit signals (diagnostics).

All three are normalised so that a perfectly matched echo gives 1, and are computed on the
analytic signal ``exp(jΦ(t))`` of the schedule (so the carrier does not fold the result):

- :func:`narrowband_af`: ``|χ(τ, ν)|`` with a Doppler *shift* ν, the classical AF.
- :func:`wideband_af`: ``|χ(τ, α)|`` with a Doppler *time scale* α, the model that is right
  for these signals (SPEC §1: 2vBT/c ≫ 1); the echo is evaluated exactly at ``α(t − τ)``.
- :func:`periodic_af`: the AF of a continuous, periodic code over one period with cyclic
  delays: what a receiver correlating one period of a continuous transmission sees.

Arrays returned have shape ``(n_doppler, n_delay)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from hil.signals.schedule import FloatArray, HopSchedule


@dataclass(frozen=True)
class AmbiguitySurface:
    """``magnitude[i, j]`` = |χ| at Doppler ``doppler[i]`` and delay ``delay_s[j]``.

    ``doppler`` is in Hz (narrowband and periodic) or the dimensionless scale α (wideband);
    ``doppler_kind`` says which.
    """

    delay_s: FloatArray
    doppler: FloatArray
    magnitude: FloatArray
    doppler_kind: str

    def peak(self) -> tuple[float, float, float]:
        """(delay_s, doppler, |χ|) of the largest value."""
        i, j = np.unravel_index(int(np.argmax(self.magnitude)), self.magnitude.shape)
        return float(self.delay_s[j]), float(self.doppler[i]), float(self.magnitude[i, j])


def _check_fs(fs_hz: float) -> None:
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise ConfigError("fs_hz", fs_hz, "> 0 Hz")


def _xcorr_lags(
    a: NDArray[np.complex128], b: NDArray[np.complex128], lags: NDArray[np.int64]
) -> NDArray[np.complex128]:
    """``Σ_n a[n] · conj(b[n − k])`` for each lag k (rows of ``a`` are independent)."""
    n = a.shape[-1] + b.shape[-1]
    nfft = 1 << (n - 1).bit_length()
    spec = np.fft.fft(a, nfft, axis=-1) * np.conj(np.fft.fft(b, nfft))
    full = np.fft.ifft(spec, axis=-1)
    return full[..., np.mod(lags, nfft)]


def narrowband_af(
    schedule: HopSchedule,
    fs_hz: float,
    span_s: float,
    max_delay_s: float,
    dopplers_hz: ArrayLike,
    t_start_s: float = 0.0,
) -> AmbiguitySurface:
    """Narrowband AF over a window of the signal.

    ``χ(τ, ν) = Σ_n x[n] e^{j2πν t_n} x*[n − τ fs] / Σ_n |x[n]|²`` with ``x`` the analytic
    signal on ``[t_start_s, t_start_s + span_s)`` sampled at ``fs_hz``; delays on the sample
    grid in ``[−max_delay_s, max_delay_s]``.

    >>> from hil.signals.waveforms import WaveformSpec, build_schedule
    >>> af = narrowband_af(build_schedule(WaveformSpec()), 20000.0, 0.17, 0.005, [-100, 0, 100])
    >>> d, nu, peak = af.peak()
    >>> (d, nu, round(peak, 9))
    (0.0, 0.0, 1.0)
    """
    _check_fs(fs_hz)
    n = int(round(span_s * fs_hz))
    if n < 2:
        raise ConfigError("span_s", span_s, f">= 2 samples at fs = {fs_hz} Hz")
    t = t_start_s + np.arange(n) / fs_hz
    x = schedule.evaluate_analytic(t)
    nu = np.asarray(dopplers_hz, dtype=float).reshape(-1)
    k_max = int(round(max_delay_s * fs_hz))
    lags = np.arange(-k_max, k_max + 1, dtype=np.int64)
    shifted = x[None, :] * np.exp(2j * np.pi * nu[:, None] * (t - t_start_s)[None, :])
    corr = _xcorr_lags(shifted, x, lags)
    energy = float(np.sum(np.abs(x) ** 2))
    if energy == 0:
        raise ConfigError("t_start_s", t_start_s, "a window where the signal is on")
    return AmbiguitySurface(lags / fs_hz, nu, np.abs(corr) / energy, "shift_hz")


def wideband_af(
    schedule: HopSchedule,
    fs_hz: float,
    span_s: float,
    max_delay_s: float,
    scales: ArrayLike,
    t_start_s: float = 0.0,
) -> AmbiguitySurface:
    """Wideband (time-scale) AF.

    For each scale α the echo model ``e_α(t) = s(α (t − t_start) + t_start)`` is evaluated
    exactly on the sample grid and correlated with the reference window:
    ``χ(τ, α) = |Σ_n e_α[n] x*[n − τ fs]| / √(E_e E_x)``. At α = 1, τ = 0 it is 1.
    """
    _check_fs(fs_hz)
    n = int(round(span_s * fs_hz))
    if n < 2:
        raise ConfigError("span_s", span_s, f">= 2 samples at fs = {fs_hz} Hz")
    alpha = np.asarray(scales, dtype=float).reshape(-1)
    if np.any(alpha <= 0):
        raise ConfigError("scales", alpha.tolist(), "> 0 (time-scale factors)")
    rel = np.arange(n) / fs_hz
    x = schedule.evaluate_analytic(t_start_s + rel)
    echoes = schedule.evaluate_analytic(t_start_s + alpha[:, None] * rel[None, :])
    k_max = int(round(max_delay_s * fs_hz))
    lags = np.arange(-k_max, k_max + 1, dtype=np.int64)
    corr = _xcorr_lags(echoes, x, lags)
    ex = float(np.sum(np.abs(x) ** 2))
    ee = np.sum(np.abs(echoes) ** 2, axis=1)
    if ex == 0:
        raise ConfigError("t_start_s", t_start_s, "a window where the signal is on")
    return AmbiguitySurface(lags / fs_hz, alpha, np.abs(corr) / np.sqrt(ee * ex)[:, None], "scale")


def periodic_af(
    schedule: HopSchedule, fs_hz: float, dopplers_hz: ArrayLike | None = None
) -> AmbiguitySurface:
    """Periodic AF of a continuous code over one period, all cyclic delays.

    ``χ_p(k, ν) = |Σ_{n<N} x[n] e^{j2πν n/fs} x*[(n − k) mod N]| / Σ|x|²`` with ``N`` samples
    per period (the period must be a whole number of samples at ``fs_hz``). Default Doppler
    grid: the multiples of 1/period from −4 to 4.

    >>> from hil.signals.waveforms import WaveformSpec, build_schedule
    >>> af = periodic_af(build_schedule(WaveformSpec()), 20000.0)
    >>> af.magnitude.shape, af.peak()[2] > 0.999999
    ((9, 3400), True)
    """
    _check_fs(fs_hz)
    n_float = schedule.period_s * fs_hz
    n = int(round(n_float))
    if abs(n_float - n) > 1e-6 or n < 2:
        raise ConfigError(
            "fs_hz",
            fs_hz,
            f"a rate giving a whole number of samples per period ({schedule.period_s} s "
            f"gives {n_float:.6g})",
        )
    nu = (
        np.arange(-4, 5) / schedule.period_s
        if dopplers_hz is None
        else np.asarray(dopplers_hz, dtype=float).reshape(-1)
    )
    t = schedule.t0_s + np.arange(n) / fs_hz
    x = schedule.evaluate_analytic(t)
    shifted = x[None, :] * np.exp(2j * np.pi * nu[:, None] * (np.arange(n) / fs_hz)[None, :])
    corr = np.fft.ifft(np.fft.fft(shifted, axis=1) * np.conj(np.fft.fft(x)), axis=1)
    energy = float(np.sum(np.abs(x) ** 2))
    lags = np.arange(n)
    return AmbiguitySurface(lags / fs_hz, nu, np.abs(corr) / energy, "shift_hz")
