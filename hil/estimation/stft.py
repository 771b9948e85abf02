"""The STFT-based HFC-CW receiver (seed §6.1, N_s = 10 and 50 [C]; details [R]).

1. Short-time Fourier transform of the real input: Hann frames of ``segment`` samples every
   ``step`` samples, zero-padded to the power of two >= ``4·segment``, restricted to the
   Doppler-stretched band.
2. Peak tone per frame; the peak frequency is refined by a parabolic fit of the log power.
3. Tone-label track: a new label (a hop boundary) starts where the peak frequency jumps by more
   than half the smallest tone spacing and stays there for ``min_frames`` frames (so single
   noisy frames do not cut a hop). A frame takes the label of the tone holding most of its
   window, so the label changes when the boundary passes the window centre: the boundary is
   placed half a step before the centre of the first new frame. This time grid sets the error
   floor ``(c/2)(N_s/fs)/√12`` of the range.
4. Label sequence matched to the code: the mean peak frequencies ``g`` of the last ``W``
   segments (``W`` the shortest window length that is unique within the code period) are
   compared with ``α·f(code window)`` for every position of the period; ``α`` is the
   least-squares ratio ``Σ g f / Σ f²`` (Doppler from the peak-frequency ratio). The best
   position gives the hop index, provided every segment lies within a quarter tone spacing
   of its scaled tone.
5. Readout at each boundary: ``t_s`` the boundary time, ``t_tx`` the transmit end time of the
   hop before it (period ambiguity resolved against ``max_range_m``), ``R = c (t_s − t_tx)/2``,
   ``v`` from ``α``. An estimate is emitted when the segment after the boundary has ended (its
   frequency is part of the match), so the output lags the boundary by one hop.

``N_s`` reading [R]: by default ``n_s`` is the frame *step* in samples (``ns_reading="step"``);
with ``ns_reading="segment"`` it is the segment length and the step is ``step`` (default
``n_s // 4``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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
    positive_int,
    require_family,
    resolve_transmit_time,
    speed_of_alpha,
    unique_window,
)
from hil.estimation.base import Estimate
from hil.signals.schedule import HopSchedule
from hil.signals.waveforms import TONE_HOP_FAMILIES

FloatArray = NDArray[np.float64]

_OPTIONS = ("n_s", "segment", "ns_reading", "step", "min_frames")


@dataclass
class _Segment:
    """One label segment: frames ``[start, end)`` (segment-local frame indices)."""

    start: int
    end: int
    freq_hz: float
    power_db: float


class StftReceiver(EmitsOnAnyBlock, RegistryConstructor):
    """Streaming STFT receiver for tone-hopping schedules (see the module docstring).

    Parameters
    ----------
    schedule, fs_hz, sound_speed_mps, max_speed_mps, max_range_m, m_hops:
        The common options (``m_hops`` is not used: the match length is the code's unique
        window).
    n_s:
        N_s, samples (10 and 50 in the seed).
    segment:
        STFT segment length, samples (``ns_reading="step"``); default ``4·fs/Δf`` (at most
        half a hop), so neighbouring tones are resolved and a boundary frame is decided by
        the tone holding most of the window.
    ns_reading:
        ``"step"`` (N_s is the frame step) or ``"segment"`` (N_s is the segment length).
    step:
        Frame step when ``ns_reading="segment"``, samples (default ``max(1, n_s // 4)``).
    min_frames:
        Frames a new peak frequency must persist to start a new segment (default a quarter
        of the frames per hop, at least 2).
    """

    name = "stft"
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
        n_s: int = 10,
        segment: int | None = None,
        ns_reading: str = "step",
        step: int | None = None,
        min_frames: int | None = None,
    ) -> None:
        fs, c, vmax, rmax, _ = common_options(
            fs_hz, sound_speed_mps, max_speed_mps, max_range_m, m_hops
        )
        if not isinstance(schedule, HopSchedule):
            raise ConfigError("schedule", type(schedule).__name__, "a HopSchedule")
        require_family(schedule, TONE_HOP_FAMILIES, "stft")
        if schedule.n_tones < 2:
            raise ConfigError("schedule.n_tones", schedule.n_tones, ">= 2 tones")
        ns = positive_int("n_s", n_s)
        df = float(np.min(np.diff(np.sort(schedule.tones_hz))))
        hop_samples = float(np.min(schedule.duration_s)) * fs
        if ns_reading == "step":
            # 4 tone periods of the spacing resolve the tones and keep the leakage of the
            # other tone in a boundary frame low; at most half a hop.
            seg_default = max(2, min(int(round(4.0 * fs / df)), int(hop_samples // 2)))
            seg = seg_default if segment is None else positive_int("segment", segment, 2)
            stp = ns
        elif ns_reading == "segment":
            seg = positive_int("n_s", ns, 2)
            stp = max(1, ns // 4) if step is None else positive_int("step", step)
        else:
            raise ConfigError("ns_reading", ns_reading, "'step' or 'segment'")
        if seg >= hop_samples:
            raise ConfigError(
                "segment",
                seg,
                f"< one hop ({hop_samples:.0f} samples)",
                "shorten the STFT segment or lengthen the hop",
            )
        frames_per_hop = hop_samples / stp
        mf = max(2, int(frames_per_hop // 4)) if min_frames is None else min_frames
        self.min_frames = positive_int("min_frames", mf)
        if self.min_frames >= frames_per_hop:
            raise ConfigError(
                "min_frames", self.min_frames, f"< frames per hop = {frames_per_hop:.1f}"
            )
        r_unamb = schedule.unambiguous_range_m(c)
        if rmax > r_unamb:
            raise ConfigError(
                "max_range_m", max_range_m, f"<= the unambiguous range {r_unamb:.3f} m"
            )
        self.schedule = schedule
        self.fs_hz = fs
        self.sound_speed_mps = c
        self.segment = seg
        self.step = stp
        self._max_delay_s = 2.0 * rmax / c
        self._nfft = 1 << int(math.ceil(math.log2(4 * seg)))
        a_lo = float(alpha_of_speed(-vmax, c))
        a_hi = float(alpha_of_speed(vmax, c))
        self._alpha_range = (a_lo, a_hi)
        bin_hz = fs / self._nfft
        f_lo = schedule.min_frequency_hz() * a_lo - df
        f_hi = schedule.max_frequency_hz() * a_hi + df
        self._b_lo = max(1, int(math.floor(f_lo / bin_hz)))
        self._b_hi = min(self._nfft // 2, int(math.ceil(f_hi / bin_hz)) + 1)
        self._bin_hz = bin_hz
        self._window = np.hanning(seg)
        self._thr_hz = 0.5 * df * a_lo
        self._edge = int(math.ceil(seg / (2.0 * stp)))  # frames straddling a boundary
        self._code = schedule.code
        self._w = unique_window(schedule.code)
        period = schedule.period_hops
        idx = (np.arange(period)[:, None] + np.arange(-self._w + 1, 1)[None, :]) % period
        self._cand_tones = schedule.tones_hz[schedule.code[idx]]  # (P, W): window ending at p
        # Transmit end time (period 0) of every hop of the period.
        self._t_end = schedule.start_s + schedule.duration_s + schedule.t0_s
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget all state; the next sample is sample 0 again."""
        self._seen = 0
        self._restart(0)

    def _restart(self, origin: int) -> None:
        self._origin = origin
        self._buf = np.zeros(0)  # samples from the next frame start on
        self._next_frame = 0  # segment-local index of the next frame to compute
        self._pend_f = np.zeros(0)  # computed frames not yet tracked (look-ahead)
        self._pend_p = np.zeros(0)
        self._pend_first = 0  # frame index of _pend_f[0]
        self._cur: list[tuple[int, float, float]] | None = None  # (frame, freq, power_db)
        self._segments: list[_Segment] = []

    # ------------------------------------------------------------------ streaming
    def process(self, block: NDArray[np.floating], *, gap_before: int = 0) -> list[Estimate]:
        """Consume ``block`` (shape ``(n,)``, real samples) and return new estimates."""
        x = check_block(block, gap_before)
        out: list[Estimate] = []
        if gap_before:
            out.extend(self._finish())
            self._seen += int(gap_before)
            self._restart(self._seen)
        self._seen += x.shape[0]
        self._buf = np.concatenate((self._buf, x))
        self._frames()
        out.extend(self._track(final=False))
        return out

    def flush(self) -> list[Estimate]:
        """End of input: close the open segment and return its estimate."""
        out = self._finish()
        self._restart(self._seen)
        return out

    def _finish(self) -> list[Estimate]:
        out = self._track(final=True)
        if self._cur:
            out.extend(self._close_segment(self._cur[-1][0] + 1))
        self._cur = None
        return out

    def _frames(self) -> None:
        seg, stp = self.segment, self.step
        count = (self._buf.shape[0] - seg) // stp + 1 if self._buf.shape[0] >= seg else 0
        if count <= 0:
            return
        frames = sliding_window_view(self._buf[: (count - 1) * stp + seg], seg)[::stp]
        spec = np.fft.rfft(frames * self._window, self._nfft, axis=1)[:, self._b_lo : self._b_hi]
        power = spec.real**2 + spec.imag**2
        k = np.argmax(power, axis=1)
        rows = np.arange(count)
        logp = np.log(np.maximum(power, 1e-300))
        inner = (k > 0) & (k < power.shape[1] - 1)
        km, kp = np.clip(k - 1, 0, None), np.clip(k + 1, None, power.shape[1] - 1)
        ym, y0, yp = logp[rows, km], logp[rows, k], logp[rows, kp]
        den = ym - 2.0 * y0 + yp
        off = np.where(inner & (den < 0), 0.5 * (ym - yp) / np.where(den < 0, den, -1.0), 0.0)
        freq = (self._b_lo + k + np.clip(off, -0.5, 0.5)) * self._bin_hz
        # Peak-to-median power of the band, dB: a per-frame SNR proxy.
        pdb = 10.0 * np.log10(power[rows, k] / np.maximum(np.median(power, axis=1), 1e-300))
        self._pend_f = np.concatenate((self._pend_f, freq))
        self._pend_p = np.concatenate((self._pend_p, pdb))
        self._next_frame += count
        self._buf = self._buf[count * stp :]

    def _track(self, *, final: bool) -> list[Estimate]:
        """Run the label tracker over the pending frames (holding back the look-ahead)."""
        f, p = self._pend_f, self._pend_p
        look = self.min_frames
        usable = f.shape[0] if final else max(0, f.shape[0] - look + 1)
        out: list[Estimate] = []
        thr = self._thr_hz
        fl, pl = f.tolist(), p.tolist()
        for i in range(usable):
            frame = self._pend_first + i
            fi = fl[i]
            if self._cur is None:
                self._cur = [(frame, fi, pl[i])]
                continue
            ref = self._cur[0][1]
            if abs(fi - ref) <= thr:
                self._cur.append((frame, fi, pl[i]))
                continue
            ahead = f[i : i + look]
            if ahead.shape[0] == look and bool(np.all(np.abs(ahead - fi) <= thr)):
                out.extend(self._close_segment(frame))
                self._cur = [(frame, fi, pl[i])]
            # otherwise an outlier frame: ignored
        self._pend_f = f[usable:]
        self._pend_p = p[usable:]
        self._pend_first += usable
        return out

    def _close_segment(self, end_frame: int) -> list[Estimate]:
        assert self._cur is not None
        frames = self._cur
        e = self._edge
        inner = frames[e:-e] if len(frames) > 2 * e else frames
        seg = _Segment(
            start=frames[0][0],
            end=end_frame,
            freq_hz=float(np.mean([fr[1] for fr in inner])),
            power_db=float(np.mean([fr[2] for fr in inner])),
        )
        self._segments.append(seg)
        if len(self._segments) > self._w + 1:
            self._segments.pop(0)
        if len(self._segments) < max(self._w, 2):
            return []
        est = self._match()
        return [] if est is None else [est]

    def _match(self) -> Estimate | None:
        segs = self._segments[-self._w :]
        g = np.array([s.freq_hz for s in segs])
        cand = self._cand_tones  # (P, W)
        alpha = (cand @ g) / np.sum(cand * cand, axis=1)
        resid = np.max(np.abs(g[None, :] - alpha[:, None] * cand), axis=1)
        a_lo, a_hi = self._alpha_range
        ok = (alpha >= a_lo * 0.999) & (alpha <= a_hi * 1.001)
        resid = np.where(ok, resid, np.inf)
        p = int(np.argmin(resid))
        if not resid[p] <= 0.5 * self._thr_hz:
            return None
        a = float(alpha[p])
        last = segs[-1]
        # Boundary before the last segment: half a step before the centre of its first frame.
        b_sample = self._origin + last.start * self.step + 0.5 * self.segment - 0.5 * self.step
        t_rx = b_sample / self.fs_hz
        hop_in_period = (p - 1) % self.schedule.period_hops
        resolved = resolve_transmit_time(
            t_rx, float(self._t_end[hop_in_period]), self.schedule.period_s, self._max_delay_s
        )
        if resolved is None:
            return None
        t_tx, q = resolved
        c = self.sound_speed_mps
        return Estimate(
            t_s=t_rx,
            range_m=c * (t_rx - t_tx) / 2.0,
            speed_mps=float(speed_of_alpha(a, c)),
            hop_index=hop_in_period + q * self.schedule.period_hops,
            score=float(1.0 - resid[p] / self._thr_hz),
            snr_db=float(np.mean([s.power_db for s in segs])),
            alpha=a,
            t_tx_s=t_tx,
            codeword=hop_in_period,
            receiver=self.name,
        )
