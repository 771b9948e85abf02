"""The hop schedule: a periodic, endless transmission described hop by hop.

Every waveform of the project (HFC-CW, FMCW, Costas, pulses) is a periodic sequence of
*hops*; hop ``n`` is the segment

    s(t) = a_n · cos(φ_n + 2π (f_n (t − t_n) + ½ k_n (t − t_n)²)),   t_n ≤ t < t_n + T_n,

with start time ``t_n`` (s), duration ``T_n`` (s), start frequency ``f_n`` (Hz), sweep rate
``k_n`` (Hz/s, zero for a tone), start phase ``φ_n`` (rad) and amplitude ``a_n`` (0 for a
silent gap). One period of hops is stored; hop ``n = q·P + r`` of the endless signal is hop
``r`` of the period shifted by ``q`` periods in time and by ``q·Φ`` in phase, where ``Φ`` is
the phase advance per period (``period_phase_rad``).

Receivers, simulators and tests all read the schedule as data, so it is the single source of
truth for what was transmitted.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError

TWO_PI = 2.0 * math.pi

# A time within this much of a hop boundary belongs to the hop that starts there. It absorbs
# the float rounding of computed start times (about 2e-16 relative: 10 ps covers a signal
# more than a day long) and is far below any sample period the project uses.
BOUNDARY_SNAP_S = 1e-11

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
_Derived = TypeVar("_Derived")


@dataclass(frozen=True)
class HopTable:
    """Hops ``[first, first + count)`` of the endless signal, as arrays of shape ``(count,)``.

    Attributes are the hop ``index`` (global), ``start_s`` (s), ``duration_s`` (s),
    ``tone_index`` (index into the schedule's ``tones_hz``; −1 for a silent gap),
    ``freq_hz`` (start frequency, Hz), ``chirp_hz_per_s`` (Hz/s), ``phase_rad`` (start phase in
    [0, 2π)) and ``amplitude`` (linear, 0 for silence).
    """

    index: IntArray
    start_s: FloatArray
    duration_s: FloatArray
    tone_index: IntArray
    freq_hz: FloatArray
    chirp_hz_per_s: FloatArray
    phase_rad: FloatArray
    amplitude: FloatArray

    def __len__(self) -> int:
        return int(self.index.shape[0])

    def to_records(self) -> list[dict[str, Any]]:
        """The hops as JSON-ready dictionaries, one per hop."""
        return [
            {
                "index": int(self.index[i]),
                "start_s": float(self.start_s[i]),
                "duration_s": float(self.duration_s[i]),
                "tone_index": int(self.tone_index[i]),
                "freq_hz": float(self.freq_hz[i]),
                "chirp_hz_per_s": float(self.chirp_hz_per_s[i]),
                "phase_rad": float(self.phase_rad[i]),
                "amplitude": float(self.amplitude[i]),
            }
            for i in range(len(self))
        ]


def _as_1d(name: str, values: ArrayLike, n: int | None, dtype: type) -> NDArray[Any]:
    kind = "integers" if dtype is int else "numbers"
    if isinstance(values, str | bytes | dict):
        raise ConfigError(name, values, f"a list of {kind}")
    try:
        arr: NDArray[Any] = np.asarray(values, dtype=dtype).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError(name, values, f"a list of {kind}") from None
    if n is not None and arr.shape[0] != n:
        raise ConfigError(name, f"{arr.shape[0]} values", f"{n} values (one per hop)")
    if dtype is float and not np.all(np.isfinite(arr)):
        raise ConfigError(name, arr.tolist(), "finite numbers", "check the waveform parameters")
    return arr


@dataclass(frozen=True)
class HopSchedule:
    """One period of a periodic transmission, hop by hop (see the module docstring).

    Build it with :meth:`from_segments` (which computes start times and phases) rather than by
    hand. All arrays have shape ``(P,)`` with ``P = period_hops``.

    Attributes
    ----------
    family:
        Waveform family name (``"random-cyclic"``, ``"three-state"``, ``"fmcw-saw"``, ...).
    tones_hz:
        The tone (or sub-band start) frequencies, Hz, shape ``(N_F,)``.
    code:
        Tone index of every hop of the period, shape ``(P,)``; −1 marks a silent gap.
    start_s, duration_s, freq_hz, chirp_hz_per_s, phase_rad, amplitude:
        Per-hop values within period 0 (see :class:`HopTable`); ``start_s[0] == 0`` and hops
        are contiguous.
    period_phase_rad:
        Phase added to every hop per period, rad in [0, 2π): zero for a signal whose phase
        restarts each period (pulses), the accumulated hop phase for continuous-phase signals.
    t0_s:
        Start time of hop 0, s.
    params:
        The design parameters the builder used (JSON-ready), kept for the schedule file.
    """

    family: str
    tones_hz: FloatArray
    code: IntArray
    start_s: FloatArray
    duration_s: FloatArray
    freq_hz: FloatArray
    chirp_hz_per_s: FloatArray
    phase_rad: FloatArray
    amplitude: FloatArray
    period_phase_rad: float = 0.0
    t0_s: float = 0.0
    params: dict[str, Any] = field(default_factory=dict, compare=False)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_segments(
        cls,
        family: str,
        tones_hz: ArrayLike,
        code: ArrayLike,
        duration_s: ArrayLike,
        *,
        freq_hz: ArrayLike | None = None,
        chirp_hz_per_s: ArrayLike | None = None,
        amplitude: ArrayLike | None = None,
        continuous_phase: bool = True,
        start_phase_rad: float = 0.0,
        t0_s: float = 0.0,
        params: dict[str, Any] | None = None,
    ) -> HopSchedule:
        """Build a schedule from one period of segments.

        Parameters
        ----------
        family:
            Family name stored with the schedule.
        tones_hz:
            Tone frequencies, Hz, shape ``(N_F,)``.
        code:
            Tone index per hop, shape ``(P,)``; −1 for a silent gap.
        duration_s:
            Hop durations, s, a scalar (all equal) or shape ``(P,)``; each must be > 0.
        freq_hz:
            Start frequency per hop, Hz; default ``tones_hz[code]`` (0 for gaps).
        chirp_hz_per_s:
            Sweep rate per hop, Hz/s; default 0 (pure tones).
        amplitude:
            Linear amplitude per hop; default 1 for tones and 0 for gaps.
        continuous_phase:
            If True the phase is continuous across hops and periods (CP-FSK:
            ``φ_{n+1} = φ_n + 2π (f_n T_n + ½ k_n T_n²)``); if False every hop starts at
            ``start_phase_rad`` (pulse trains).
        start_phase_rad:
            Phase of hop 0, rad.
        t0_s:
            Start time of hop 0, s.
        params:
            Design parameters kept with the schedule (JSON-ready values).

        Examples
        --------
        >>> s = HopSchedule.from_segments("demo", [1000.0, 2000.0], [0, 1], 0.001)
        >>> s.period_hops, s.period_s
        (2, 0.002)
        >>> np.round(s.phase_rad, 12).tolist()  # 1 kHz for 1 ms: a whole cycle
        [0.0, 0.0]
        """
        tones = _as_1d("tones_hz", tones_hz, None, float)
        codes = _as_1d("code", code, None, int).astype(np.int64)
        p = codes.shape[0]
        if p == 0:
            raise ConfigError("code", [], "at least one hop", "give a non-empty code")
        if np.any(codes >= tones.shape[0]) or np.any(codes < -1):
            raise ConfigError(
                "code",
                codes.tolist(),
                f"tone indices in 0..{tones.shape[0] - 1} (or -1 for a gap)",
                "the code and the tone list disagree",
            )
        dur = np.broadcast_to(np.asarray(duration_s, dtype=float), (p,)).astype(float)
        if not np.all(np.isfinite(dur)) or np.any(dur <= 0):
            bad = dur[~(np.isfinite(dur) & (dur > 0))][0]
            raise ConfigError("duration_s", float(bad), "> 0 s", "hop durations must be positive")
        gap = codes < 0
        if freq_hz is None:
            freq = np.where(gap, 0.0, tones[np.clip(codes, 0, None)])
        else:
            freq = np.broadcast_to(np.asarray(freq_hz, dtype=float), (p,)).astype(float)
        chirp = (
            np.zeros(p)
            if chirp_hz_per_s is None
            else np.broadcast_to(np.asarray(chirp_hz_per_s, dtype=float), (p,)).astype(float)
        )
        amp = (
            np.where(gap, 0.0, 1.0)
            if amplitude is None
            else np.broadcast_to(np.asarray(amplitude, dtype=float), (p,)).astype(float)
        )
        for name, arr in (("freq_hz", freq), ("chirp_hz_per_s", chirp), ("amplitude", amp)):
            if not np.all(np.isfinite(arr)):
                raise ConfigError(name, arr.tolist(), "finite numbers")
        starts = np.concatenate(([0.0], np.cumsum(dur)[:-1]))
        if continuous_phase:
            # Reduce each increment mod 2π before summing so that long periods keep precision.
            inc = np.mod(TWO_PI * (freq * dur + 0.5 * chirp * dur * dur), TWO_PI)
            cum = np.concatenate(([0.0], np.cumsum(inc)))
            phases = np.mod(start_phase_rad + cum[:-1], TWO_PI)
            period_phase = float(np.mod(cum[-1], TWO_PI))
        else:
            phases = np.full(p, float(np.mod(start_phase_rad, TWO_PI)))
            period_phase = 0.0
        return cls(
            family=family,
            tones_hz=tones,
            code=codes,
            start_s=starts,
            duration_s=dur,
            freq_hz=freq,
            chirp_hz_per_s=chirp,
            phase_rad=phases,
            amplitude=amp,
            period_phase_rad=period_phase,
            t0_s=float(t0_s),
            params=dict(params or {}),
        )

    # ------------------------------------------------------------------ derived values
    @property
    def period_hops(self) -> int:
        """Number of hops in one period, P."""
        return int(self.code.shape[0])

    @property
    def period_s(self) -> float:
        """Duration of one period, s."""
        return float(self.start_s[-1] + self.duration_s[-1])

    @property
    def n_tones(self) -> int:
        """Number of tones N_F."""
        return int(self.tones_hz.shape[0])

    @property
    def hop_s(self) -> float:
        """The hop duration T_h, s, when all hops have the same length.

        Raises
        ------
        ConfigError
            If the hops have different lengths (pulse trains, triangular FMCW with unequal
            legs); use ``duration_s`` then.
        """
        d = self.duration_s
        if not np.allclose(d, d[0], rtol=1e-12, atol=0.0):
            raise ConfigError(
                "hop_s", d.tolist(), "equal hop durations", "this family has unequal hops"
            )
        return float(d[0])

    def period_samples(self, fs_hz: float) -> int | None:
        """The code period in samples at ``fs_hz`` when it is a whole number of them (to
        1e-6 of a period), else None: what a canceller subtracting the period before needs.

        >>> HopSchedule.from_segments("demo", [1000.0, 1500.0], [0, 1], 0.001).period_samples(1e4)
        20
        """
        period = self.period_s * float(fs_hz)
        return int(round(period)) if abs(period - round(period)) <= 1e-6 * period else None

    def unambiguous_delay_s(self) -> float:
        """The longest delay that can be told apart from a shorter one: one period, s."""
        return self.period_s

    def unambiguous_range_m(self, sound_speed_mps: float) -> float:
        """Two-way unambiguous range ``c·period/2``, m, for sound speed ``c`` in m/s.

        >>> HopSchedule.from_segments("demo", [1e3], [0], 0.01).unambiguous_range_m(1500.0)
        7.5
        """
        if not sound_speed_mps > 0:
            raise ConfigError("sound_speed_mps", sound_speed_mps, "> 0 m/s")
        return sound_speed_mps * self.period_s / 2.0

    def max_frequency_hz(self) -> float:
        """Highest instantaneous frequency of any sounding hop, Hz."""
        on = self.amplitude != 0
        end = self.freq_hz + self.chirp_hz_per_s * self.duration_s
        return float(np.max(np.maximum(self.freq_hz, end)[on])) if np.any(on) else 0.0

    def min_frequency_hz(self) -> float:
        """Lowest instantaneous frequency of any sounding hop, Hz."""
        on = self.amplitude != 0
        end = self.freq_hz + self.chirp_hz_per_s * self.duration_s
        return float(np.min(np.minimum(self.freq_hz, end)[on])) if np.any(on) else 0.0

    def shifted(self, t0_s: float) -> HopSchedule:
        """The same signal with hop 0 starting at ``t0_s`` seconds."""
        return HopSchedule(
            self.family,
            self.tones_hz,
            self.code,
            self.start_s,
            self.duration_s,
            self.freq_hz,
            self.chirp_hz_per_s,
            self.phase_rad,
            self.amplitude,
            self.period_phase_rad,
            float(t0_s),
            dict(self.params),
        )

    # ------------------------------------------------------------------ values kept with it
    def derived(self, key: Hashable, make: Callable[[], _Derived]) -> _Derived:
        """The value ``make()`` derives from this schedule, made on the first call with ``key``
        and kept with the schedule for every later call: a schedule is immutable, so what is
        derived from it never goes stale, and every user of this schedule object shares one
        (the refinement's codeword windows, :class:`~hil.estimation.codewords.CodewordBook`).
        ``key`` names what is derived and the other inputs it is derived with (a class and
        its parameters). A copy, a pickle or :meth:`shifted` keeps none: each makes its own
        again.

        >>> s = HopSchedule.from_segments("demo", [1000.0, 2000.0], [0, 1], 0.001)
        >>> s.derived("energy", lambda: float(s.amplitude @ s.amplitude))
        2.0
        >>> s.derived("energy", lambda: -1.0)  # kept: not made again
        2.0
        """
        kept = self.__dict__.get("_derived")
        if kept is None:
            kept = {}
            object.__setattr__(self, "_derived", kept)
        if key not in kept:
            kept[key] = make()
        value: _Derived = kept[key]
        return value

    def __getstate__(self) -> dict[str, Any]:
        """The fields only (pickles and copies): :meth:`derived`'s values are made again where
        they are needed."""
        state = dict(self.__dict__)
        state.pop("_derived", None)
        return state

    # ------------------------------------------------------------------ hop look-up
    def hops(self, first: int, count: int) -> HopTable:
        """Hops ``first .. first+count-1`` of the endless signal (``first`` may be negative).

        >>> s = HopSchedule.from_segments("demo", [1000.0, 1500.0], [0, 1], 0.001)
        >>> h = s.hops(3, 2)
        >>> h.index.tolist(), h.tone_index.tolist(), h.start_s.tolist()
        ([3, 4], [1, 0], [0.003, 0.004])
        >>> round(float(h.phase_rad[0]), 9)  # after 1 ms of 1 kHz + 1 ms of 1.5 kHz: π
        3.141592654
        """
        if count < 0:
            raise ConfigError("count", count, ">= 0")
        idx = np.arange(first, first + count, dtype=np.int64)
        q, r = np.divmod(idx, self.period_hops)
        qf = q.astype(float)
        # Indexing by the array ``r`` gives new arrays: the table shares nothing with the
        # schedule.
        return HopTable(
            index=idx,
            start_s=self.t0_s + qf * self.period_s + self.start_s[r],
            duration_s=self.duration_s[r],
            tone_index=self.code[r],
            freq_hz=self.freq_hz[r],
            chirp_hz_per_s=self.chirp_hz_per_s[r],
            phase_rad=np.mod(self.phase_rad[r] + qf * self.period_phase_rad, TWO_PI),
            amplitude=self.amplitude[r],
        )

    def hops_in_span(self, t_start_s: float, t_stop_s: float) -> HopTable:
        """All hops that overlap the time span ``[t_start_s, t_stop_s)``, s."""
        if t_stop_s < t_start_s:
            raise ConfigError("t_stop_s", t_stop_s, f">= t_start_s = {t_start_s}")
        first = int(self.locate(np.array([t_start_s]))[0])
        if t_stop_s == t_start_s:
            return self.hops(first, 0)
        # A hop starting within the snap tolerance of t_stop does not overlap the span.
        probe = max(t_start_s, t_stop_s - 2 * BOUNDARY_SNAP_S)
        last = int(self.locate(np.array([probe]))[0])
        return self.hops(first, last - first + 1)

    def locate(self, t: ArrayLike) -> IntArray:
        """Global index of the hop sounding at each time ``t`` (s), same shape as ``t``.

        A time on a boundary (within :data:`BOUNDARY_SNAP_S`) belongs to the hop that starts
        there.
        """
        tt = np.asarray(t, dtype=float)
        q, r, _ = self._split(tt)
        return q * self.period_hops + r

    def _split(self, t: FloatArray) -> tuple[IntArray, IntArray, FloatArray]:
        """Period number q, hop-in-period r and time since the hop start (s) for times t."""
        rel = t - self.t0_s
        period = self.period_s
        q = np.floor(rel / period)
        tau = rel - q * period
        # Rounding can leave tau a hair outside [0, period), or just below a boundary that the
        # time really sits on: fold and snap consistently (dt may then be -BOUNDARY_SNAP_S).
        over = tau + BOUNDARY_SNAP_S >= period
        q = np.where(over, q + 1, q)
        tau = np.where(over, tau - period, tau)
        under = tau + BOUNDARY_SNAP_S < 0
        q = np.where(under, q - 1, q)
        tau = np.where(under, tau + period, tau)
        r = np.searchsorted(self.start_s, tau + BOUNDARY_SNAP_S, side="right") - 1
        r = np.clip(r, 0, self.period_hops - 1)
        return q.astype(np.int64), r.astype(np.int64), tau - self.start_s[r]

    # ------------------------------------------------------------------ evaluation
    def instantaneous_phase(self, t: ArrayLike) -> FloatArray:
        """Total phase Φ(t), rad (reduced mod 2π per hop), at arbitrary times t (s).

        Exact evaluation for any times, also fractional and non-uniform: the simulator uses it
        to compute ``s(α(t − τ))`` without interpolation.
        """
        tt = np.asarray(t, dtype=float)
        q, r, dt = self._split(tt)
        base = np.mod(self.phase_rad[r] + q.astype(float) * self.period_phase_rad, TWO_PI)
        return base + TWO_PI * (self.freq_hz[r] * dt + 0.5 * self.chirp_hz_per_s[r] * dt * dt)

    def evaluate(self, t: ArrayLike) -> FloatArray:
        """The transmit signal s(t) (unit amplitude, dimensionless) at times t (s).

        Shape of the result equals the shape of ``t``.

        >>> s = HopSchedule.from_segments("demo", [1000.0, 2000.0], [0, 1], 0.001)
        >>> np.round(s.evaluate([0.0, 0.00025, 0.001, 0.00125]), 12).tolist()
        [1.0, 0.0, 1.0, -1.0]
        """
        tt = np.asarray(t, dtype=float)
        _, r, _ = self._split(tt)
        return self.amplitude[r] * np.cos(self.instantaneous_phase(tt))

    def evaluate_analytic(self, t: ArrayLike) -> NDArray[np.complex128]:
        """The analytic signal a·exp(jΦ(t)) at times t (s); its real part is :meth:`evaluate`."""
        tt = np.asarray(t, dtype=float)
        _, r, _ = self._split(tt)
        return self.amplitude[r] * np.exp(1j * self.instantaneous_phase(tt))

    # ------------------------------------------------------------------ serialisation
    def period_dict(self) -> dict[str, Any]:
        """The period definition as JSON-ready data (enough to rebuild the schedule exactly)."""
        return {
            "family": self.family,
            "tones_hz": self.tones_hz.tolist(),
            "code": self.code.tolist(),
            "start_s": self.start_s.tolist(),
            "duration_s": self.duration_s.tolist(),
            "freq_hz": self.freq_hz.tolist(),
            "chirp_hz_per_s": self.chirp_hz_per_s.tolist(),
            "phase_rad": self.phase_rad.tolist(),
            "amplitude": self.amplitude.tolist(),
            "period_phase_rad": self.period_phase_rad,
            "t0_s": self.t0_s,
            "params": self.params,
        }

    @classmethod
    def from_period_dict(cls, data: dict[str, Any]) -> HopSchedule:
        """Inverse of :meth:`period_dict`; validates the arrays."""
        required = (
            "family",
            "tones_hz",
            "code",
            "start_s",
            "duration_s",
            "freq_hz",
            "chirp_hz_per_s",
            "phase_rad",
            "amplitude",
            "period_phase_rad",
        )
        missing = [k for k in required if k not in data]
        if missing:
            raise ConfigError(
                "period", f"missing {missing}", f"an object with keys {list(required)}"
            )
        code = _as_1d("code", data["code"], None, int).astype(np.int64)
        p = code.shape[0]
        dur = _as_1d("duration_s", data["duration_s"], p, float)
        start = _as_1d("start_s", data["start_s"], p, float)
        if np.any(dur <= 0):
            raise ConfigError("duration_s", dur.tolist(), "> 0 s for every hop")
        expect = np.concatenate(([0.0], np.cumsum(dur)[:-1]))
        if not np.allclose(start, expect, rtol=1e-12, atol=1e-15):
            raise ConfigError(
                "start_s", start.tolist(), "contiguous hops starting at 0 (cumsum of duration_s)"
            )
        return cls(
            family=str(data["family"]),
            tones_hz=_as_1d("tones_hz", data["tones_hz"], None, float),
            code=code,
            start_s=start,
            duration_s=dur,
            freq_hz=_as_1d("freq_hz", data["freq_hz"], p, float),
            chirp_hz_per_s=_as_1d("chirp_hz_per_s", data["chirp_hz_per_s"], p, float),
            phase_rad=_as_1d("phase_rad", data["phase_rad"], p, float),
            amplitude=_as_1d("amplitude", data["amplitude"], p, float),
            period_phase_rad=float(data["period_phase_rad"]),
            t0_s=float(data.get("t0_s", 0.0)),
            params=dict(data.get("params", {})),
        )


def tone_grid(center_hz: float, bandwidth_hz: float, n_tones: int) -> FloatArray:
    """Tone frequencies ``f_k = f_c + (k − (N_F − 1)/2)·Δf``, ``Δf = B_w/N_F``, Hz.

    The occupied bandwidth is ``B_w = N_F·Δf`` (SPEC §2, [R]).

    >>> tone_grid(30000.0, 4400.0, 4).tolist()
    [28350.0, 29450.0, 30550.0, 31650.0]
    """
    if n_tones < 1:
        raise ConfigError("n_tones", n_tones, ">= 1")
    if not bandwidth_hz > 0:
        raise ConfigError("bandwidth_hz", bandwidth_hz, "> 0 Hz")
    if not center_hz > 0:
        raise ConfigError("center_hz", center_hz, "> 0 Hz")
    df = bandwidth_hz / n_tones
    k = np.arange(n_tones, dtype=float)
    tones = center_hz + (k - (n_tones - 1) / 2.0) * df
    if tones[0] <= 0:
        raise ConfigError(
            "bandwidth_hz", bandwidth_hz, "< 2·f_c·N_F/(N_F−1) so that every tone is > 0 Hz"
        )
    return tones
