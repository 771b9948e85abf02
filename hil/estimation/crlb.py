"""Cramér–Rao bounds for delay (range) and Doppler (speed) from the actual waveform [D].

Stein's bounds (SPEC §4; REFERENCE-VALUES "Estimation bounds")::

    σ_τ = 1 / (π √8 · B_rms · √(E/N0)),    σ_f = 1 / (π √8 · T_rms · √(E/N0)),
    σ_R = c σ_τ / 2,                          σ_v = c σ_f / (2 f0).

Convention (the one that reproduces the published example): ``B_rms`` is the rms bandwidth
*about the mean frequency* (the square root of the second central moment of the normalised
energy spectrum |S(f)|², one-sided for a real signal), and ``T_rms`` the rms duration about
the energy centroid of |s(t)|². A flat band of width B gives ``B_rms = B/√12`` and a
rectangular envelope of length T gives ``T_rms = T/√12``; with B = 10 kHz, T = 0.1 s,
f0 = 50 kHz, E/N0 = 20 dB and c = 1500 m/s this yields σ_R = 2.92 mm and σ_v = 5.85 mm/s.

Using the moment about the mean frequency (not about 0 Hz) is the bound for an estimator that
does not exploit the carrier phase, which is what every receiver of this project does.

Validity: these are small-error (local) bounds. Below about 10 dB *output* SNR (E/N0) the
estimators leave the main lobe (threshold effect) and the errors are far larger than the bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from hil.errors import ConfigError
from hil.signals.schedule import HopSchedule

_STEIN = math.pi * math.sqrt(8.0)

#: Output SNR (E/N0, dB) below which the bounds are not attainable (threshold region).
VALID_ABOVE_DB = 10.0


def _pos(field: str, value: float, unit: str) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ConfigError(field, value, f"a finite number > 0 {unit}")
    return v


def db_to_linear(db: float) -> float:
    """Power ratio from dB: ``10^(db/10)``.

    >>> db_to_linear(20.0)
    100.0
    """
    if not math.isfinite(db):
        raise ConfigError("snr_db", db, "a finite number of dB")
    return float(10.0 ** (db / 10.0))


def e_over_n0(snr_db: float, noise_bandwidth_hz: float, integration_s: float) -> float:
    """E/N0 (linear) from an SNR measured in a noise bandwidth, over an integration time.

    ``snr_db`` is the signal power over the noise power in ``noise_bandwidth_hz`` (Hz, the
    one-sided bandwidth in which the noise power was measured); the signal is observed for
    ``integration_s`` seconds. ``E/N0 = SNR · B_noise · T``. For real samples at rate fs with
    per-sample SNR (``A²/2 / σ²``) the noise bandwidth is ``fs/2``.

    >>> e_over_n0(0.0, 50_000.0, 0.01)
    500.0
    """
    b = _pos("noise_bandwidth_hz", noise_bandwidth_hz, "Hz")
    t = _pos("integration_s", integration_s, "s")
    return db_to_linear(snr_db) * b * t


def e_over_n0_db(snr_db: float, noise_bandwidth_hz: float, integration_s: float) -> float:
    """:func:`e_over_n0` in dB.

    >>> round(e_over_n0_db(-10.0, 50_000.0, 0.05), 3)
    23.979
    """
    return 10.0 * math.log10(e_over_n0(snr_db, noise_bandwidth_hz, integration_s))


def sampled_e_over_n0(amplitude: float, noise_std: float, fs_hz: float, duration_s: float) -> float:
    """E/N0 of a real sinusoid-like signal of ``amplitude`` in white noise of std ``noise_std``.

    Real samples at ``fs_hz``: ``E = A² T / 2`` and ``N0 = 2 σ² / fs`` (two-sided density
    σ²/fs), so ``E/N0 = A² T fs / (4 σ²)``. Dimensionless.

    >>> sampled_e_over_n0(1.0, 1.0, 100_000.0, 0.01)
    250.0
    """
    a = _pos("amplitude", amplitude, "")
    s = _pos("noise_std", noise_std, "")
    return a * a * _pos("duration_s", duration_s, "s") * _pos("fs_hz", fs_hz, "Hz") / (4 * s * s)


def rms_bandwidth(samples: ArrayLike, fs_hz: float) -> tuple[float, float]:
    """``(B_rms, f_mean)`` in Hz of a sampled signal (real or complex, shape ``(n,)``).

    The spectrum is |FFT|² of the samples (zero-padded 4×); a real signal uses its positive
    frequencies only. B_rms is the rms spread about the energy-weighted mean frequency.
    """
    x = np.asarray(samples)
    fs = _pos("fs_hz", fs_hz, "Hz")
    if x.ndim != 1 or x.shape[0] < 2:
        raise ConfigError("samples", f"shape {x.shape}", "a 1-D array of at least 2 samples")
    if not np.all(np.isfinite(x)):
        raise ConfigError("samples", "NaN/inf", "finite samples")
    nfft = 1 << int(math.ceil(math.log2(4 * x.shape[0])))
    if np.iscomplexobj(x):
        spec = np.abs(np.fft.fft(x, nfft)) ** 2
        f = np.fft.fftfreq(nfft, 1.0 / fs)
    else:
        spec = np.abs(np.fft.rfft(x, nfft)) ** 2
        f = np.fft.rfftfreq(nfft, 1.0 / fs)
    total = float(np.sum(spec))
    if total <= 0:
        raise ConfigError("samples", "all zero", "a signal with energy")
    f_mean = float(np.sum(f * spec) / total)
    b2 = float(np.sum((f - f_mean) ** 2 * spec) / total)
    return math.sqrt(b2), f_mean


def rms_duration(samples: ArrayLike, fs_hz: float) -> float:
    """rms duration (s) of the energy envelope |x|² about its centroid, shape ``(n,)`` input.

    Each sample stands for an interval 1/fs, so a rectangular envelope of n samples gives
    ``T/√12`` with ``T = n/fs`` (the continuous value, including the within-sample spread).
    """
    x = np.asarray(samples)
    fs = _pos("fs_hz", fs_hz, "Hz")
    if x.ndim != 1 or x.shape[0] < 1:
        raise ConfigError("samples", f"shape {x.shape}", "a 1-D array of samples")
    e = np.abs(x) ** 2
    total = float(np.sum(e))
    if total <= 0:
        raise ConfigError("samples", "all zero", "a signal with energy")
    t = (np.arange(x.shape[0]) + 0.5) / fs
    t_mean = float(np.sum(t * e) / total)
    t2 = float(np.sum((t - t_mean) ** 2 * e) / total) + 1.0 / (12.0 * fs * fs)
    return math.sqrt(t2)


@dataclass(frozen=True)
class Crlb:
    """Cramér–Rao standard deviations.

    Attributes: ``sigma_tau_s`` (s), ``sigma_f_hz`` (Hz), ``sigma_range_m`` (m),
    ``sigma_speed_mps`` (m/s), and the inputs ``b_rms_hz``, ``t_rms_s``, ``f0_hz``,
    ``e_over_n0_db``; ``valid`` is False below :data:`VALID_ABOVE_DB`.
    """

    sigma_tau_s: float
    sigma_f_hz: float
    sigma_range_m: float
    sigma_speed_mps: float
    b_rms_hz: float
    t_rms_s: float
    f0_hz: float
    e_over_n0_db: float
    valid: bool


def crlb(
    b_rms_hz: float, t_rms_s: float, f0_hz: float, e_over_n0_db: float, sound_speed_mps: float
) -> Crlb:
    """Stein's bounds from rms bandwidth (Hz), rms duration (s), carrier (Hz), E/N0 (dB), c.

    >>> b = crlb(10_000 / math.sqrt(12), 0.1 / math.sqrt(12), 50_000.0, 20.0, 1500.0)
    >>> round(b.sigma_range_m * 1e3, 2), round(b.sigma_speed_mps * 1e3, 2)
    (2.92, 5.85)
    """
    b = _pos("b_rms_hz", b_rms_hz, "Hz")
    t = _pos("t_rms_s", t_rms_s, "s")
    f0 = _pos("f0_hz", f0_hz, "Hz")
    c = _pos("sound_speed_mps", sound_speed_mps, "m/s")
    root = math.sqrt(db_to_linear(e_over_n0_db))
    s_tau = 1.0 / (_STEIN * b * root)
    s_f = 1.0 / (_STEIN * t * root)
    return Crlb(
        sigma_tau_s=s_tau,
        sigma_f_hz=s_f,
        sigma_range_m=c * s_tau / 2.0,
        sigma_speed_mps=c * s_f / (2.0 * f0),
        b_rms_hz=b,
        t_rms_s=t,
        f0_hz=f0,
        e_over_n0_db=float(e_over_n0_db),
        valid=e_over_n0_db >= VALID_ABOVE_DB,
    )


def crlb_from_samples(
    samples: ArrayLike, fs_hz: float, e_over_n0_db: float, sound_speed_mps: float
) -> Crlb:
    """Bounds for the waveform ``samples`` (shape ``(n,)``, real or analytic) at ``fs_hz``.

    B_rms, the mean frequency f0 and T_rms are measured from the samples themselves.
    """
    b, f_mean = rms_bandwidth(samples, fs_hz)
    t = rms_duration(samples, fs_hz)
    return crlb(b, t, abs(f_mean), e_over_n0_db, sound_speed_mps)


def schedule_crlb(
    schedule: HopSchedule,
    fs_hz: float,
    t_start_s: float,
    duration_s: float,
    e_over_n0_db: float,
    sound_speed_mps: float,
) -> Crlb:
    """Bounds for the window ``[t_start_s, t_start_s + duration_s)`` of a transmit schedule.

    The window is evaluated exactly (analytic signal) at ``fs_hz``; for an M-hop codeword use
    the M hops' span. ``e_over_n0_db`` is the E/N0 collected over that window.
    """
    fs = _pos("fs_hz", fs_hz, "Hz")
    n = int(round(_pos("duration_s", duration_s, "s") * fs))
    if n < 2:
        raise ConfigError("duration_s", duration_s, f">= 2 samples at fs = {fs} Hz")
    t = float(t_start_s) + np.arange(n) / fs
    return crlb_from_samples(schedule.evaluate_analytic(t), fs, e_over_n0_db, sound_speed_mps)
