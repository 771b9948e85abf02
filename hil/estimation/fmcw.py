"""FMCW sonar receiver for sawtooth and triangular sweeps (seed §3.2; SPEC §4).

Per transmitted sweep ``i`` (one hop of an ``fmcw-saw`` or ``fmcw-tri`` schedule, duration
T, swept band B, rate ``k = ±B/T``):

1. **Dechirp** [D]: ``z = x · conj(s_i)``, with ``s_i`` the analytic sweep ``i`` continued
   analytically past both of its ends. The echo of sweep ``i`` then gives one beat tone from its
   arrival to its end; every other sweep's echo lands far away in frequency. Beat frequency
   ``f_b = f_t − f_r`` on an up-sweep, ``f_r − f_t`` on a down-sweep, so that
   ``f_bu ≈ kτ − f_d`` and ``f_bd ≈ kτ + f_d`` (``f_d`` the Doppler shift, > 0 closing).
2. **Edges** (the group's FMCW paper [C]; detection details [R]): in sonar the beat does not
   keep a constant duration (the echo sweep lasts ``T/α``). The beat is demodulated by its
   coarse frequency and smoothed by two cascaded ``4/B``-s moving averages; its rising and
   falling edges are the half-plateau crossings: the arrival of the echo's sweep start and end.
3. **Beat frequency** over the interval between the edges: the beat is itself a slow chirp in
   sonar (time scaling), so it is the slope at the interval centre of a quadratic fit to the
   unwrapped phase of the smoothed beat (an FFT peak of a chirp is ill defined).
4. **Readout**
   - sawtooth: ``R = c T f_bu / (2B)``, from the up-beat only, so biased by the Doppler
     (``−c T f_d /(2B)``: about −5 m at 10 m/s closing, B = 10 kHz, T = 0.1 s, 50 kHz).
     Speed [R]: from the edges, ``α = T / (t_fall − t_rise)``; ``speed_mode="none"`` reports 0.
   - triangular: every down-sweep is paired with the up-sweep before it:
     ``R = c T (f_bu + f_bd)/(4B)``, ``v = λ0 (f_bd − f_bu)/4`` with ``λ0 = c/f0``, ``f0`` the
     centre of the band. This classical pair formula ignores that the range changes between
     the two sweeps (``k·Δτ = −2vB/c``), which scales the speed by ``1 − B/(2 f0)``; it is
     kept as the reference method.

Estimate fields: ``t_s`` is the receive time at the centre of the beat interval (the mean of
the two centres for a pair), ``t_tx_s = t_s − 2R/c``, ``hop_index`` the (last) sweep used,
``codeword`` its index in the period, ``score`` the plateau-to-noise amplitude ratio of the
beat envelope and ``snr_db`` the beat's E/N0 estimate.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation._baseline_common import (
    EmitsOnAnyBlock,
    RegistryConstructor,
    alpha_of_speed,
    check_block,
    common_options,
    positive,
    require_family,
    speed_of_alpha,
)
from hil.estimation.base import Estimate
from hil.signals.schedule import TWO_PI, HopSchedule

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

FAMILIES = ("fmcw-saw", "fmcw-tri")
_OPTIONS = ("speed_mode", "edge_fraction")


class FmcwReceiver(EmitsOnAnyBlock, RegistryConstructor):
    """Streaming FMCW receiver (see the module docstring).

    Parameters
    ----------
    schedule:
        An ``fmcw-saw`` or ``fmcw-tri`` schedule.
    fs_hz, sound_speed_mps, max_speed_mps, max_range_m, m_hops:
        The common options (``m_hops`` is not used). ``2·max_range/c`` must be below the
        sweep duration.
    speed_mode:
        Sawtooth speed: ``"edges"`` (from the echo sweep length) or ``"none"`` (report 0).
    edge_fraction:
        Fraction of the beat plateau at which an edge is placed (0 < f < 1, default 0.5).
    """

    name = "fmcw"
    OPTIONS = _OPTIONS

    def __init__(
        self,
        schedule: HopSchedule,
        fs_hz: float,
        *,
        sound_speed_mps: float,
        max_speed_mps: float,
        max_range_m: float,
        m_hops: int = 1,
        speed_mode: str = "edges",
        edge_fraction: float = 0.5,
    ) -> None:
        fs, c, vmax, rmax, _ = common_options(
            fs_hz, sound_speed_mps, max_speed_mps, max_range_m, m_hops
        )
        if not isinstance(schedule, HopSchedule):
            raise ConfigError("schedule", type(schedule).__name__, "a HopSchedule")
        require_family(schedule, FAMILIES, "fmcw")
        if speed_mode not in ("edges", "none"):
            raise ConfigError("speed_mode", speed_mode, "'edges' or 'none'")
        frac = positive("edge_fraction", edge_fraction)
        if frac >= 1.0:
            raise ConfigError("edge_fraction", edge_fraction, "0 < edge_fraction < 1")
        sweep = float(schedule.duration_s[0])
        band = abs(float(schedule.chirp_hz_per_s[0])) * sweep
        max_delay = 2.0 * rmax / c
        if max_delay >= 0.5 * sweep:
            raise ConfigError(
                "max_range_m",
                max_range_m,
                f"< c·T/4 = {c * sweep / 4:.3f} m (the delay must leave half the sweep "
                "for the beat)",
                "lengthen the sweep or lower max_range_m",
            )
        self.schedule = schedule
        self.fs_hz = fs
        self.sound_speed_mps = c
        self.speed_mode = speed_mode
        self.edge_fraction = frac
        self.sweep_s = sweep
        self.band_hz = band
        self.f0_hz = 0.5 * (schedule.min_frequency_hz() + schedule.max_frequency_hz())
        self._max_delay = max_delay
        self._doppler_max = (float(alpha_of_speed(vmax, c)) - 1.0) * schedule.max_frequency_hz()
        self._smooth = max(3, int(round(4.0 * fs / band)))  # envelope smoothing, samples
        self._margin = 2 * self._smooth
        self._tri = schedule.family == "fmcw-tri"
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget all state; the next sample is sample 0 again."""
        self._seen = 0
        self._restart(0)

    def _restart(self, origin: int) -> None:
        self._x = np.zeros(0)
        self._x0 = origin  # global index of self._x[0]
        # First sweep whose analysis window starts inside this segment.
        t_first = (origin + self._margin) / self.fs_hz
        self._next_sweep = int(self.schedule.locate(np.array([t_first]))[0]) + 1
        self._pending_up: tuple[int, float, float, float] | None = None

    # ------------------------------------------------------------------ streaming
    def process(self, block: NDArray[np.floating], *, gap_before: int = 0) -> list[Estimate]:
        """Consume ``block`` (shape ``(n,)``, real samples) and return new estimates."""
        x = check_block(block, gap_before)
        out: list[Estimate] = []
        if gap_before:
            self._seen += int(gap_before)
            self._restart(self._seen)
        self._x = np.concatenate((self._x, x))
        self._seen += x.shape[0]
        while True:
            span = self._window(self._next_sweep)
            if span[1] > self._seen:
                break
            est = self._analyse(self._next_sweep, span)
            if est is not None:
                out.append(est)
            self._next_sweep += 1
            keep = self._window(self._next_sweep)[0]
            if keep > self._x0:
                self._x = self._x[keep - self._x0 :]
                self._x0 = keep
        return out

    def flush(self) -> list[Estimate]:
        """End of input: sweeps whose echo is not complete are not analysed."""
        self._restart(self._seen)
        return []

    # ------------------------------------------------------------------ analysis
    def _window(self, sweep: int) -> tuple[int, int]:
        """Global sample span ``[a, b)`` analysed for sweep ``sweep``."""
        hop = self.schedule.hops(sweep, 1)
        t0 = float(hop.start_s[0])
        t1 = t0 + float(hop.duration_s[0]) + self._max_delay
        a = math.ceil(t0 * self.fs_hz) - self._margin
        b = math.ceil(t1 * self.fs_hz) + self._margin
        return a, b

    def _beat(self, sweep: int, span: tuple[int, int]) -> tuple[float, float, float, float] | None:
        """``(f_b Hz, t_rise s, t_fall s, snr)`` of one sweep, or None without a clear beat."""
        hop = self.schedule.hops(sweep, 1)
        t_start = float(hop.start_s[0])
        f_start = float(hop.freq_hz[0])
        rate = float(hop.chirp_hz_per_s[0])
        phase0 = float(hop.phase_rad[0])
        a, b = span
        k = np.arange(a, b)
        u = k / self.fs_hz - t_start
        # Sweep i continued analytically beyond its ends: exp(jφ_i(t)).
        ref = np.exp(1j * (phase0 + TWO_PI * (f_start * u + 0.5 * rate * u * u)))
        x = self._x[a - self._x0 : b - self._x0]
        z = x * np.conj(ref)
        sign = -1.0 if rate > 0 else 1.0  # beat = sign · frequency of z
        # Coarse beat: FFT peak within the possible beat band.
        nfft = 1 << int(math.ceil(math.log2(4 * z.shape[0])))
        spec = np.abs(np.fft.fft(z, nfft))
        freqs = np.fft.fftfreq(nfft, 1.0 / self.fs_hz)
        beat = sign * freqs
        lo = -self._doppler_max - 4.0 / self.sweep_s
        hi = abs(rate) * self._max_delay + self._doppler_max + 4.0 / self.sweep_s
        inband = (beat >= lo) & (beat <= hi)
        if not np.any(inband):
            return None
        idx = np.flatnonzero(inband)
        i_pk = int(idx[np.argmax(spec[idx])])
        f_z = float(freqs[i_pk])
        # Envelope of the beat tone: demodulate and smooth (centred moving average).
        y = z * np.exp(-1j * TWO_PI * f_z * k / self.fs_hz)
        m = self._smooth
        # Two cascaded moving averages (a triangle of 2m − 1 samples): the other sweeps'
        # components, about B away, are suppressed to well below 1 %.
        cs = np.concatenate(([0.0], np.cumsum(y)))
        ma1 = (cs[m:] - cs[:-m]) / m
        cs = np.concatenate(([0.0], np.cumsum(ma1)))
        ma = (cs[m:] - cs[:-m]) / m  # ma[i] covers samples i .. i + 2m − 2
        env: FloatArray = np.abs(ma).astype(np.float64)
        centre: FloatArray = np.arange(env.shape[0], dtype=np.float64) + (m - 1.0)
        plateau = float(np.median(env[env >= 0.5 * env.max()]))
        noise = float(np.median(env[env < 0.25 * plateau])) if np.any(env < 0.25 * plateau) else 0.0
        level = self.edge_fraction * plateau
        above = np.flatnonzero(env >= level)
        if above.shape[0] < 2 or plateau <= 3.0 * noise:
            return None
        first, last = int(above[0]), int(above[-1])
        if first == 0 or last == env.shape[0] - 1:
            return None  # an edge outside the window: not this sweep's echo
        rise = _crossing(centre, env, first - 1, level)
        fall = _crossing(centre, env, last, level)
        # Beat frequency over the plateau between the edges (guarded by the smoothing). In
        # sonar the beat is itself a slow chirp (rate ≈ −2(α − 1)k), whose spectrum is flat
        # over its span, so an FFT peak is ill defined: the frequency at the interval centre
        # is the slope of a quadratic fit to the unwrapped phase of the smoothed beat.
        g0 = int(math.ceil(rise))
        g1 = int(math.floor(fall - 2 * m + 2))
        if g1 - g0 < 8:
            return None
        ph = np.unwrap(np.angle(ma[g0:g1]))
        tt = (centre[g0:g1] - 0.5 * (rise + fall)) / self.fs_hz
        scale = max(float(np.max(np.abs(tt))), 1.0 / self.fs_hz)
        coef = np.polynomial.polynomial.polyfit(tt / scale, ph, 2)
        f_fine = f_z + float(coef[1]) / (TWO_PI * scale)
        snr = plateau / noise if noise > 0 else math.inf
        return sign * f_fine, (a + rise) / self.fs_hz, (a + fall) / self.fs_hz, snr

    def _analyse(self, sweep: int, span: tuple[int, int]) -> Estimate | None:
        res = self._beat(sweep, span)
        if res is None:
            return None
        f_b, t_rise, t_fall, snr = res
        c, band, sweep_s = self.sound_speed_mps, self.band_hz, self.sweep_s
        up = float(self.schedule.hops(sweep, 1).chirp_hz_per_s[0]) > 0
        t_mid = 0.5 * (t_rise + t_fall)
        if not self._tri:
            rng = c * sweep_s * f_b / (2.0 * band)
            alpha = sweep_s / (t_fall - t_rise) if self.speed_mode == "edges" else 1.0
            return self._estimate(sweep, t_mid, rng, float(speed_of_alpha(alpha, c)), snr)
        if up:
            self._pending_up = (sweep, f_b, t_mid, snr)
            return None
        pend, self._pending_up = self._pending_up, None
        if pend is None or pend[0] != sweep - 1:
            return None
        _, f_bu, t_mid_u, snr_u = pend
        rng = c * sweep_s * (f_bu + f_b) / (4.0 * band)
        speed = (c / self.f0_hz) * (f_b - f_bu) / 4.0
        return self._estimate(sweep, 0.5 * (t_mid + t_mid_u), rng, speed, min(snr, snr_u))

    def _estimate(self, sweep: int, t_s: float, rng: float, speed: float, snr: float) -> Estimate:
        c = self.sound_speed_mps
        alpha = float(alpha_of_speed(speed, c)) if abs(speed) < c else math.nan
        snr_db = 20.0 * math.log10(snr) if math.isfinite(snr) and snr > 0 else math.inf
        return Estimate(
            t_s=t_s,
            range_m=rng,
            speed_mps=speed,
            hop_index=sweep,
            score=snr,
            snr_db=snr_db,
            alpha=alpha,
            t_tx_s=t_s - 2.0 * rng / c,
            codeword=sweep % self.schedule.period_hops,
            receiver=self.name,
        )


def _crossing(centre: FloatArray, env: FloatArray, i: int, level: float) -> float:
    """Position (samples) where ``env`` crosses ``level`` between ``i`` and ``i + 1``."""
    y0, y1 = float(env[i]), float(env[i + 1])
    frac = 0.5 if y1 == y0 else (level - y0) / (y1 - y0)
    return float(centre[i] + min(1.0, max(0.0, frac)) * (centre[i + 1] - centre[i]))
