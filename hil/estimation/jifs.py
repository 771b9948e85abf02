"""The earlier HFC-CW receiver (JIFS paper, doi 10.3233/JIFS-169858) [C names only; R details].

Pipeline, on the shared front end of :mod:`hil.estimation.baseband` (mix to complex baseband,
low-pass, decimate) and :mod:`hil.estimation.unit_correlators` (heterodyne + moving sum):

1. **Unit Doppler correlators**, one per tone ``k`` and Doppler hypothesis ``d``, of length
   ``N_u = corr_fraction · T_h / α_d`` [R: a fraction of the hop, so a tone's energy is a
   plateau with sharp edges rather than a triangle]. Tone energy
   ``E_k[n] = max_d |u_{k,d}[n]|² / N_u²``.
2. **Difference of moving averages** on each tone's energy,
   ``D_k[n] = MA(E_k)[n] − MA(E_k)[n − N_a]`` (``N_a = edge_fraction · T_h``): a positive
   peak where the tone starts, a negative one where it stops.
3. **Four thresholds** (all relative to the total tone energy ``S[n] = MA(Σ_k E_k)``, so they
   do not depend on the echo level):
   - tone present: ``E_k ≥ present_ratio · Σ_j E_j`` half a hop after the rise (the new tone)
     and before the fall (the old tone);
   - rising edge: a local maximum of ``D_k`` (±N_a) with ``D_k ≥ rise_ratio · S``;
   - falling edge: a local minimum with ``D_k ≤ −fall_ratio · S``;
   - coincidence: a fall of tone ``a`` and a rise of tone ``b`` within ``coincidence`` ·
     N_a samples (after removing the known filter delays), with ``a → b`` a legal transition
     of the code.
   The boundary time is the mean of the two edge times (parabolic sub-sample interpolation,
   filter delays computed from the noise-free model of the pipeline at start-up).
4. **Decoding**: consecutive boundaries one hop apart form the decoded tone sequence; once it
   holds ``W`` tones (``W`` the shortest window unique within the code period) it gives the
   position in the period, hence the hop index, and ``R = c (t_rx − t_tx)/2``.
5. **Doppler**: the energy of the hop that just ended, summed over its plateau, per Doppler
   hypothesis, with a parabolic fit across hypotheses.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation._baseline_common import (
    EmitsOnAnyBlock,
    RegistryConstructor,
    alpha_of_speed,
    check_block,
    common_options,
    parabolic_peak,
    positive,
    require_family,
    resolve_transmit_time,
    speed_of_alpha,
    unique_window,
)
from hil.estimation.base import Estimate
from hil.estimation.baseband import ComplexBaseband
from hil.estimation.doppler_grid import check_n_doppler
from hil.estimation.unit_correlators import UnitCorrelatorBank
from hil.signals.schedule import HopSchedule
from hil.signals.waveforms import HFCCW_FAMILIES

FloatArray = NDArray[np.float64]

_OPTIONS = (
    "n_doppler",
    "corr_fraction",
    "edge_fraction",
    "present_ratio",
    "rise_ratio",
    "fall_ratio",
    "coincidence",
)


def _moving_sum(x: FloatArray, n: int) -> FloatArray:
    """Trailing sums of ``n`` rows, one per full window (row-wise, chunk-invariant)."""
    return sliding_window_view(x, n, axis=0).sum(axis=-1)


class JifsReceiver(EmitsOnAnyBlock, RegistryConstructor):
    """Streaming edge-detecting HFC-CW receiver (see the module docstring).

    Parameters
    ----------
    schedule, fs_hz, sound_speed_mps, max_speed_mps, max_range_m, m_hops:
        The common options (``m_hops`` is not used).
    n_doppler:
        Doppler hypotheses over ±max_speed (odd keeps 0 on the grid).
    corr_fraction, edge_fraction:
        Unit-correlator and moving-average lengths as fractions of a hop.
    present_ratio, rise_ratio, fall_ratio:
        The tone-present, rising-edge and falling-edge thresholds (fractions of the total
        tone energy).
    coincidence:
        Largest rise/fall separation accepted, in units of N_a.
    """

    name = "jifs"
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
        n_doppler: int = 15,
        corr_fraction: float = 0.25,
        edge_fraction: float = 0.125,
        present_ratio: float = 0.5,
        rise_ratio: float = 0.3,
        fall_ratio: float = 0.3,
        coincidence: float = 0.5,
    ) -> None:
        fs, c, vmax, rmax, _ = common_options(
            fs_hz, sound_speed_mps, max_speed_mps, max_range_m, m_hops
        )
        if not isinstance(schedule, HopSchedule):
            raise ConfigError("schedule", type(schedule).__name__, "a HopSchedule")
        require_family(schedule, HFCCW_FAMILIES, "jifs")
        n_dop = check_n_doppler(n_doppler)
        fractions = {
            "corr_fraction": corr_fraction,
            "edge_fraction": edge_fraction,
            "present_ratio": present_ratio,
            "rise_ratio": rise_ratio,
            "fall_ratio": fall_ratio,
        }
        for key, val in fractions.items():
            if positive(key, val) >= 1.0:
                raise ConfigError(key, val, "0 < value < 1")
        self.coincidence = positive("coincidence", coincidence)
        r_unamb = schedule.unambiguous_range_m(c)
        if rmax > r_unamb:
            raise ConfigError(
                "max_range_m", max_range_m, f"<= the unambiguous range {r_unamb:.3f} m"
            )
        self.schedule = schedule
        self.fs_hz = fs
        self.sound_speed_mps = c
        self.present_ratio = float(present_ratio)
        self.rise_ratio = float(rise_ratio)
        self.fall_ratio = float(fall_ratio)
        self._max_delay_s = 2.0 * rmax / c
        tones = schedule.tones_hz
        hop = schedule.hop_s
        self.hop_s = hop
        speeds = np.zeros(1) if n_dop == 1 else np.linspace(-vmax, vmax, n_dop)
        self.alphas: FloatArray = np.asarray(alpha_of_speed(speeds, c), dtype=float)
        # Front end: baseband covering the tones, a tone spacing and the Doppler span.
        f_c = 0.5 * (float(tones.min()) + float(tones.max()))
        df = float(np.min(np.diff(np.sort(tones)))) if tones.shape[0] > 1 else 1.0 / hop
        shift = (float(self.alphas.max()) - 1.0) * float(tones.max())
        passband = 0.5 * (float(tones.max()) - float(tones.min())) + df + shift
        dec = max(1, int(fs / (2.5 * passband)))
        self._bb = ComplexBaseband(fs, f_c, decimation=dec, passband_hz=passband)
        fs_b = self._bb.fs_out_hz
        self._fs_b = fs_b
        n_u = np.maximum(2, np.rint(float(corr_fraction) * hop * fs_b / self.alphas))
        nu = self.alphas[:, None] * tones[None, :] - f_c
        self._bank = UnitCorrelatorBank(fs_b, nu, n_u.astype(np.int64))
        self._n_u = n_u
        self._n_a = max(2, int(round(float(edge_fraction) * hop * fs_b)))
        self._hop_b = hop * fs_b  # samples per hop at baseband
        self._off_rise, self._off_fall = self._edge_offsets(float(np.median(n_u)))
        self._tol = self.coincidence * self._n_a  # largest rise/fall separation, samples
        # Pairing delay: the edge filters delay detections by up to max(offsets) + N_a, a
        # partner may come tol later, the tone-present check looks half a hop ahead.
        self._margin = (
            2 * self._tol + max(self._off_rise, self._off_fall) + self._n_a + 0.5 * self._hop_b + 2
        )
        self._w = unique_window(schedule.code)
        code = schedule.code
        p = schedule.period_hops
        self._legal = {(int(code[i]), int(code[(i + 1) % p])) for i in range(p)}
        idx = (np.arange(p)[:, None] + np.arange(-self._w + 1, 1)[None, :]) % p
        self._windows = {tuple(int(v) for v in code[idx[i]]): i for i in range(p)}
        self._t_end = schedule.start_s + schedule.duration_s + schedule.t0_s
        self.reset()

    def _edge_offsets(self, n_u: float) -> tuple[float, float]:
        """Delay (baseband samples) from a boundary to the DMA peak (rise) and trough (fall),
        from the noise-free model of the correlator ramp and the two moving averages."""
        n_a = self._n_a
        span = int(4 * (n_u + 2 * n_a)) + 8
        n = np.arange(-span, span, dtype=float)
        rise = np.clip((n + 0.5) / n_u, 0.0, 1.0) ** 2
        fall = np.clip(1.0 - (n + 0.5) / n_u, 0.0, 1.0) ** 2
        out = []
        for e, sign in ((rise, 1.0), (fall, -1.0)):
            ma = _moving_sum(e, n_a) / n_a  # ma[i] ends at sample i + n_a − 1
            d = sign * (ma[n_a:] - ma[:-n_a])  # ends at i + 2 n_a − 1
            i = int(np.argmax(d))
            off, _ = parabolic_peak(float(d[i - 1]), float(d[i]), float(d[i + 1]))
            out.append(float(n[0] + i + 2 * n_a - 1 + off))
        return out[0], out[1]

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget all state; the next sample is sample 0 again."""
        self._seen = 0
        self._restart(0)

    def _restart(self, origin: int) -> None:
        self._bb.reset(origin)
        first = self._bb.next_output_index
        self._bank.reset(first)
        self._origin_b = first
        k = self.schedule.n_tones
        d = self.alphas.shape[0]
        self._u = np.zeros((0, d, k))  # |u|²/N_u² history
        self._u0 = first  # baseband index of self._u[0]
        self._decided = first  # first baseband index whose edges are not yet decided
        self._events: list[tuple[float, int, int]] = []  # (time in samples, tone, ±1)
        self._seq: list[tuple[float, int, int]] = []  # decoded boundaries (t, from, to)

    # ------------------------------------------------------------------ streaming
    def process(self, block: NDArray[np.floating], *, gap_before: int = 0) -> list[Estimate]:
        """Consume ``block`` (shape ``(n,)``, real samples) and return new estimates."""
        x = check_block(block, gap_before)
        out: list[Estimate] = []
        if gap_before:
            out.extend(self._run(final=True))
            self._seen += int(gap_before)
            self._restart(self._seen)
        self._seen += x.shape[0]
        z = self._bb.process(x)
        if z.shape[0]:
            u = self._bank.process(z)
            power = (u.real.astype(np.float64) ** 2 + u.imag.astype(np.float64) ** 2) / (
                self._n_u[None, :, None] ** 2
            )
            self._u = np.concatenate((self._u, power))
        out.extend(self._run(final=False))
        return out

    def flush(self) -> list[Estimate]:
        """End of input: decide the remaining edges."""
        out = self._run(final=True)
        self._restart(self._seen)
        return out

    def _run(self, *, final: bool) -> list[Estimate]:
        n_a = self._n_a
        u = self._u
        end = self._u0 + u.shape[0]
        if u.shape[0] < 2 * n_a + 2:
            return []
        energy = u.max(axis=1)  # (n, K)
        ma = _moving_sum(energy, n_a) / n_a  # row i ends at u0 + i + n_a − 1
        dma = ma[n_a:] - ma[:-n_a]  # row i ends at u0 + i + 2 n_a − 1
        total = ma[n_a:].sum(axis=1)
        base = self._u0 + 2 * n_a - 1  # baseband index of dma[0]
        lo = max(self._decided, base + n_a)
        hi = end - n_a if not final else end - 1
        if hi <= lo:
            return []
        for sign, ratio in ((1.0, self.rise_ratio), (-1.0, self.fall_ratio)):
            s = sign * dma
            win = sliding_window_view(s, 2 * n_a + 1, axis=0)  # centre at row i + n_a
            first = lo - base - n_a
            last = min(hi - base - n_a, win.shape[0])
            w = win[first:last]
            centre = w[:, :, n_a]
            peak = (
                (centre >= w.max(axis=-1))
                & (centre > w[:, :, :n_a].max(axis=-1))
                & (centre >= ratio * total[first + n_a : last + n_a, None])
            )
            for i, k in zip(*np.nonzero(peak), strict=True):
                row = first + n_a + int(i)
                off, _ = parabolic_peak(
                    float(s[row - 1, k]), float(s[row, k]), float(s[row + 1, k])
                )
                t = base + row + off - (self._off_rise if sign > 0 else self._off_fall)
                self._events.append((t, int(k), int(sign)))
        self._decided = hi
        out = self._pair(hi if not final else math.inf, energy)
        # History still needed: the edge filters of the next undecided centre (3 N_a back)
        # and, for the boundaries still to pair (after ``hi − margin − tol``), the Doppler sum
        # (a hop back) and the tone-present check. Trimming never changes a result.
        keep = math.floor(
            min(hi - 3 * self._hop_b, hi - self._margin - 2 * self._tol - self._hop_b - 2)
        )
        keep = min(keep, hi - 3 * n_a)
        if keep > self._u0:
            self._u = self._u[keep - self._u0 :]
            self._u0 = keep
        return out

    def _pair(self, decided: float, energy: FloatArray) -> list[Estimate]:
        """Pair each ready rise (in time order) with the nearest unused legal fall.

        A rise is ready once every partner it could have is detected and the tone-present
        check after it has data (``t <= decided − margin``). A fall is kept, even when ready,
        while a rise not yet ready could still claim it (``t > decided − margin − tol``; kept
        with a 2·tol guard, extra ones are harmless): dropping it earlier made the result
        depend on where the input was cut.
        """
        tol = self._tol
        margin = self._margin
        self._events.sort()
        ready = [e for e in self._events if e[0] <= decided - margin]
        rest = [e for e in self._events if e[0] > decided - margin]
        out: list[Estimate] = []
        used: set[int] = set()
        for i, (t, k, sign) in enumerate(ready):
            if i in used or sign < 0:
                continue
            best = None
            for j, (t2, k2, s2) in enumerate(ready + rest):
                if j in used or s2 > 0 or k2 == k or abs(t2 - t) > tol:
                    continue
                if (k2, k) in self._legal and (best is None or abs(t2 - t) < abs(best[1] - t)):
                    best = (j, t2, k2)
            if best is None:
                continue
            j, t2, k2 = best
            used.update((i, j))
            boundary = 0.5 * (t + t2)
            if self._present(boundary, k2, k, energy):
                est = self._decode(boundary, k2, k)
                if est is not None:
                    out.append(est)
        pool = ready + rest
        horizon = decided - margin
        self._events = [
            e
            for j, e in enumerate(pool)
            if j not in used and (e[0] > horizon or (e[2] < 0 and e[0] > horizon - 2 * tol))
        ]
        return out

    def _present(self, boundary: float, old: int, new: int, energy: FloatArray) -> bool:
        """Tone-present threshold: ``old`` before and ``new`` after the boundary."""
        half = 0.5 * self._hop_b
        rows = []
        for tone, when in ((old, boundary - 0.5 * half), (new, boundary + half)):
            r = int(round(when)) - self._u0
            if not 0 <= r < energy.shape[0]:
                return True  # outside the history: do not veto
            rows.append(energy[r, tone] >= self.present_ratio * float(energy[r].sum()))
        return all(rows)

    def _decode(self, boundary: float, old: int, new: int) -> Estimate | None:
        if self._seq:
            t_prev, _, to_prev = self._seq[-1]
            gap = boundary - t_prev
            if to_prev != old or not 0.5 * self._hop_b < gap < 1.5 * self._hop_b:
                self._seq = []
        self._seq.append((boundary, old, new))
        self._seq = self._seq[-self._w :]
        if len(self._seq) + 1 < self._w:
            return None
        tones = [s[1] for s in self._seq] + [self._seq[-1][2]]
        pos = self._windows.get(tuple(tones[-self._w :]))
        if pos is None:
            return None
        hop_in_period = (pos - 1) % self.schedule.period_hops
        t_rx = float(self._bb.time_of(np.array([boundary]))[0])
        resolved = resolve_transmit_time(
            t_rx, float(self._t_end[hop_in_period]), self.schedule.period_s, self._max_delay_s
        )
        if resolved is None:
            return None
        t_tx, q = resolved
        alpha = self._doppler(boundary, old)
        c = self.sound_speed_mps
        return Estimate(
            t_s=t_rx,
            range_m=c * (t_rx - t_tx) / 2.0,
            speed_mps=float(speed_of_alpha(alpha, c)),
            hop_index=hop_in_period + q * self.schedule.period_hops,
            score=1.0,
            snr_db=math.nan,
            alpha=alpha,
            t_tx_s=t_tx,
            codeword=hop_in_period,
            receiver=self.name,
        )

    def _doppler(self, boundary: float, tone: int) -> float:
        """α from the energy of the hop that ended at ``boundary``, across hypotheses."""
        a = int(round(boundary - self._hop_b + float(np.max(self._n_u)))) - self._u0
        b = int(round(boundary)) - self._u0
        a, b = max(a, 0), min(b, self._u.shape[0])
        if b - a < 1 or self.alphas.shape[0] < 3:
            return float(self.alphas[self.alphas.shape[0] // 2])
        prof = self._u[a:b, :, tone].sum(axis=0)
        d = int(np.argmax(prof))
        d = min(max(d, 1), prof.shape[0] - 2)
        off, _ = parabolic_peak(float(prof[d - 1]), float(prof[d]), float(prof[d + 1]))
        step = float(self.alphas[d + 1] - self.alphas[d - 1]) / 2.0
        return float(self.alphas[d]) + off * step
