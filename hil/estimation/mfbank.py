"""The full matched-filter bank: the accuracy reference and the cost anchor (SPEC §4).

Every M-hop codeword of the code period (``J = P`` of them: the window of M hops ending at hop
``j``) is correlated at every Doppler hypothesis ``α_d`` (``D`` of them, speeds evenly spaced
over ±max_speed) against the input. The replica is exact: the analytic transmit signal read at
the time-scaled emission times,

    h_{j,d}[i] = s_a(t_end_j + α_d (i − L_{j,d}) / fs),    i = 0 … L_{j,d} − 1,

with ``t_end_j`` the transmit end time of hop ``j`` and ``L_{j,d} = round(T_w fs / α_d)`` the
received length of the ``T_w``-long window. Correlating the *real* input ``x`` with the
*analytic* replica keeps only the positive-frequency half of the input, so ``|c|`` is the
envelope of the matched-filter output (no carrier ripple):

    c(n) = Σ_i x[n + i] · conj(h_{j,d}[i]),    n the input sample where the replica starts.

Implementation: a baseband overlap-save bank, the way a sonar receiver is built.

- **Front end, once for all replicas**: the real input is mixed by the centre ``f_c`` of the
  Doppler-stretched band (by absolute sample index), low-passed and decimated by ``R`` to a
  complex baseband ``z`` at ``fs_b = fs/R`` that holds the band
  (:class:`~hil.estimation.baseband.ComplexBaseband`, sample ``k`` at time
  ``t_k = (kR − δ)/fs``, ``δ`` the low-pass group delay in input samples). With
  ``z(t) = ½ x_a(t) e^{−j2πf_c t}`` and the replica envelope
  ``g_{j,d}(τ) = h_{j,d}(τ) e^{−j2πf_c τ}`` (``τ`` from the replica start),
  ``|c(qR)| ≈ R |Σ_m z[q + m0 + m] conj(g_{j,d}(τ_m))|`` with ``τ_m = ((m0 + m)R − δ)/fs`` and
  ``m0 = ⌈δ/R⌉``: the correlation at every ``R``-th input lag (the lag grid), exact up to the
  band-limiting of the input and the sampling of the window edges (relative error ~R/L).
- **Correlators**: fixed frames of ``N_b`` baseband samples (the power of two >= twice the
  longest baseband replica, at least 4096) advancing by ``S_b = N_b − L_b,max + 1`` lags; one
  FFT of the frame, products with the precomputed conjugate replica spectra (complex64,
  scaled by ``R/‖h‖``) and batched inverse FFTs (:func:`scipy.fft.ifft`, ``fft_workers``
  threads) over all ``J·D`` correlators; a compiled pass keeps the best Doppler per codeword
  and lag. The frame grid is fixed by absolute sample index, so the arithmetic does not depend
  on how the caller cuts the input: chunks and one whole block give bit-identical estimates.
- **Detection score**: the normalised correlation ``ρ = √2 |c| / (‖h‖ ‖x_window‖)`` (1 for a
  noise-free exact match, about √(2/L) for noise), with ``‖x_window‖²`` the energy of the
  full-rate real input over the replica's ``L_{j,d}`` samples (a running sum of ``x²``). A hop
  boundary is declared where the best ``ρ`` over all ``(j, d)`` is a local maximum over ±half
  a hop and at least ``threshold``.
- **Refinement** (``refine=True``, default), on the full-rate input: the exact correlation
  ``c(t_c, α)`` is evaluated directly around the detection (``t_c`` the receive time of the
  window centre, which decouples delay and Doppler): a sweep of ``α`` across the Doppler cell
  at the coherent resolution ``1/(f0 T_w)``, then alternating parabolic fits in time and
  ``α``. This reaches the Cramér–Rao bound at high SNR; it is not counted in
  :mod:`hil.estimation.cost`.

Readout: ``t_s`` is the receive time of the END boundary of the codeword's last hop,
``hop_index`` the global index of that hop, the transmit time is resolved with the code period
so that the delay is in ``[0, 2 R_max / c]`` (detections beyond ``max_range_m`` are dropped),
``range_m = c (t_s − t_tx)/2``, ``speed_mps`` from ``α``. ``score`` is ``ρ`` at the reported
``(t_s, α)``: the exact full-rate value when refined, the bank's grid value otherwise; ``snr_db``
is the E/N0 it implies, ``10 log10(ρ²/(1 − ρ²) · L/2)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import scipy.fft
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray
from scipy.signal import correlate

from hil.errors import ConfigError
from hil.estimation._baseline_common import (
    EmitsOnAnyBlock,
    RegistryConstructor,
    alpha_of_speed,
    check_block,
    common_options,
    parabolic_peak,
    positive,
    positive_int,
    resolve_transmit_time,
    speed_of_alpha,
)
from hil.estimation.base import Estimate
from hil.estimation.baseband import ComplexBaseband
from hil.estimation.cost import fft_mults
from hil.estimation.doppler_grid import check_n_doppler
from hil.signals.schedule import HopSchedule

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

_OPTIONS = ("n_doppler", "threshold", "refine", "n_candidates", "fft_workers")
# Doppler-grid chunk per batched inverse FFT (bounds the working memory to J·chunk·N_b values).
_D_CHUNK = 16
# Shortest baseband frame: the frame is the power of two >= twice the longest baseband replica
# and at least this long. Shorter frames spend most of each inverse FFT on the overlap; longer
# ones push the J·D replica spectra (8·N_b bytes each) out of the cache.
_MIN_FRAME = 4096
# Band kept around the Doppler-stretched tones: this many hop main-lobe half-widths (1/T_h).
_BAND_MARGIN_HOPS = 4.0
# Baseband rate >= this factor times the two-sided passband: room for the low-pass transition.
_TRANSITION_FACTOR = 1.3
# Parabolic refinement rounds (each halves the steps).
_REFINE_ROUNDS = 3
# Runner-up codewords are refined only when their grid score is this close to the best.
_CANDIDATE_RATIO = 0.75


@numba.njit(cache=True, nogil=True)
def _best_over_doppler(corr: Any, inv: Any, d0: int, best: Any, best_d: Any) -> None:
    """Fold a chunk of correlators into the best ρ² over Doppler, in place.

    ``corr`` (shape ``(J_g, D_c, N_b)``, complex) holds the correlations of Doppler indices
    ``d0 … d0 + D_c − 1``; lag ``k < S`` of ``(j, d)`` scores ``|corr|² · inv[d0 + d, k]``
    (``inv`` shape ``(D, S)``). ``best`` (shape ``(J_g, S)``) and ``best_d`` (its Doppler
    index) are raised where a hypothesis beats them (ties keep the lower index).
    """
    jg, dc, _ = corr.shape
    s = best.shape[1]
    for j in range(jg):
        for d in range(dc):
            for k in range(s):
                v = corr[j, d, k]
                p = (v.real * v.real + v.imag * v.imag) * inv[d0 + d, k]
                if p > best[j, k]:
                    best[j, k] = p
                    best_d[j, k] = d0 + d


@dataclass(frozen=True)
class _LengthGroup:
    """Codewords sharing one replica length per Doppler (one window duration ``T_w``).

    ``first`` .. ``first + count`` index the codewords in group order; ``full`` (shape
    ``(D,)``) are the full-rate lengths ``L_d``; ``spectra`` (shape ``(count, D, N_b)``,
    complex64) the conjugate baseband replica spectra scaled by ``R/‖h‖``.
    """

    first: int
    count: int
    full: NDArray[np.int64]
    spectra: NDArray[np.complex64]


class MatchedFilterBank(EmitsOnAnyBlock, RegistryConstructor):
    """Streaming baseband overlap-save matched-filter bank over all codewords and Dopplers.

    Parameters
    ----------
    schedule:
        Transmit schedule (any family; the first input sample is at the schedule's t = 0).
    fs_hz:
        Input sample rate, Hz.
    sound_speed_mps, max_speed_mps, max_range_m:
        c (m/s), Doppler span ±v_max (m/s), largest range reported (m, at most the
        unambiguous range ``c·period/2``).
    m_hops:
        Codeword length M, hops.
    n_doppler:
        Number of Doppler hypotheses D, speeds evenly spaced over ±max_speed (1 → speed 0).
    threshold:
        Minimum normalised correlation ρ (0 < ρ <= 1) for a detection.
    refine:
        Refine each detection with the exact local correlation (see module docstring).
    n_candidates:
        Codewords refined per detection (the strongest on the grid); the best refined one
        is reported.
    fft_workers:
        Threads of each batched FFT (:mod:`scipy.fft` ``workers``); 1 keeps the bank on one
        core.
    """

    name = "mfbank"
    OPTIONS = _OPTIONS

    def __init__(
        self,
        schedule: HopSchedule,
        fs_hz: float,
        *,
        sound_speed_mps: float,
        max_speed_mps: float,
        max_range_m: float,
        m_hops: int = 10,
        n_doppler: int = 64,
        threshold: float = 0.2,
        refine: bool = True,
        n_candidates: int = 3,
        fft_workers: int = 1,
    ) -> None:
        fs, c, vmax, rmax, m = common_options(
            fs_hz, sound_speed_mps, max_speed_mps, max_range_m, m_hops
        )
        if not isinstance(schedule, HopSchedule):
            raise ConfigError("schedule", type(schedule).__name__, "a HopSchedule")
        n_dop = check_n_doppler(n_doppler)
        thr = positive("threshold", threshold)
        if thr > 1.0:
            raise ConfigError("threshold", threshold, "0 < threshold <= 1 (normalised correlation)")
        if not isinstance(refine, bool):
            raise ConfigError("refine", refine, "True or False")
        r_unamb = schedule.unambiguous_range_m(c)
        if rmax > r_unamb:
            raise ConfigError(
                "max_range_m",
                max_range_m,
                f"<= the unambiguous range c·period/2 = {r_unamb:.3f} m",
                "lower max_range_m or use a longer code",
            )
        self.schedule = schedule
        self.fs_hz = fs
        self.sound_speed_mps = c
        self.max_range_m = rmax
        self.m_hops = m
        self.threshold = thr
        self.refine = refine
        self.n_candidates = positive_int("n_candidates", n_candidates)
        self.fft_workers = positive_int("fft_workers", fft_workers)
        self.speeds_mps: FloatArray = np.zeros(1) if n_dop == 1 else np.linspace(-vmax, vmax, n_dop)
        self.alphas: FloatArray = np.asarray(alpha_of_speed(self.speeds_mps, c), dtype=float)
        self._max_delay_s = 2.0 * rmax / c
        self._build_codewords()
        self._build_front_end()
        self._build_bank()
        self.reset()

    # ------------------------------------------------------------------ set-up
    def _build_codewords(self) -> None:
        sch = self.schedule
        p = sch.period_hops
        ends = np.empty(p)
        spans = np.empty(p)
        for j in range(p):
            hops = sch.hops(j - self.m_hops + 1, self.m_hops)
            ends[j] = hops.start_s[-1] + hops.duration_s[-1]
            spans[j] = ends[j] - hops.start_s[0]
        self._t_end: FloatArray = ends  # transmit end time of hop j, period 0 (s)
        self._t_win: FloatArray = spans  # codeword duration T_w (s)
        self.n_codewords = p

    def _build_front_end(self) -> None:
        """Centre, passband and decimation of the baseband holding every stretched replica."""
        sch, fs = self.schedule, self.fs_hz
        margin_hz = _BAND_MARGIN_HOPS / float(np.min(sch.duration_s))
        f_lo = max(0.0, sch.min_frequency_hz() * float(self.alphas.min()) - margin_hz)
        f_hi = sch.max_frequency_hz() * float(self.alphas.max()) + margin_hz
        passband = 0.5 * (f_hi - f_lo)
        centre = 0.5 * (f_lo + f_hi)
        if not f_hi < fs / 2:
            raise ConfigError(
                "fs_hz",
                fs,
                f"> 2 × {f_hi:.1f} Hz (the highest Doppler-stretched frequency)",
                "raise the sample rate or lower max_speed_mps",
            )
        decimation = max(1, int(fs / (2.0 * _TRANSITION_FACTOR * passband)))
        self.baseband = ComplexBaseband(fs, centre, decimation=decimation, passband_hz=passband)
        self._dec = decimation  # R: input samples per lag of the grid
        self._gd = self.baseband.group_delay  # input samples
        self._m0 = int(math.ceil(self._gd / decimation))

    def _build_bank(self) -> None:
        fs, r = self.fs_hz, self._dec
        lengths = np.rint(self._t_win[:, None] * fs / self.alphas[None, :]).astype(np.int64)
        if int(lengths.min()) < 2:
            raise ConfigError("m_hops", self.m_hops, "codewords of at least 2 samples")
        self._lengths = lengths  # (J, D) full-rate replica lengths
        # Baseband replica m covers τ_m = ((m0 + m)R − g)/fs < L/fs.
        lb = np.ceil((lengths + self._gd) / r).astype(np.int64) - self._m0
        lb_max = int(lb.max())
        n_b = max(_MIN_FRAME, 1 << int(math.ceil(math.log2(2 * lb_max))))
        self._n_fft = n_b
        self._step = n_b - lb_max + 1  # lags per frame
        centre = self.baseband.center_hz
        # Codewords with the same replica lengths share one energy normalisation: group them.
        _, first_of, group_of = np.unique(lengths, axis=0, return_index=True, return_inverse=True)
        self._order = np.argsort(group_of.reshape(-1), kind="stable")
        counts = np.bincount(group_of.reshape(-1))
        groups = []
        first = 0
        for g_no, count in enumerate(counts):
            spectra = np.empty((int(count), self.alphas.shape[0], n_b), dtype=np.complex64)
            for g_i, j in enumerate(self._order[first : first + count]):
                for d, a in enumerate(self.alphas):
                    tau = ((self._m0 + np.arange(int(lb[j, d]))) * r - self._gd) / fs
                    tau = tau[tau < lengths[j, d] / fs]
                    t = self._t_end[j] + float(a) * (tau - lengths[j, d] / fs)
                    env = self.schedule.evaluate_analytic(t) * np.exp(-2j * np.pi * centre * tau)
                    norm = math.sqrt(float(np.vdot(env, env).real) * r)  # ‖h‖ (Riemann)
                    spectra[g_i, d] = np.conj(scipy.fft.fft(env, n_b)) * (r / norm)
            full = lengths[int(first_of[g_no])]
            groups.append(_LengthGroup(first, int(count), full, spectra))
            first += int(count)
        self._groups = tuple(groups)
        # Reused product/inverse-FFT buffer: a fresh multi-megabyte temporary per chunk would
        # be page-faulted in again every time.
        chunk = min(_D_CHUNK, self.alphas.shape[0])
        self._work = np.empty((int(counts.max()), chunk, n_b), dtype=np.complex64)
        # Half a (received, fastest) hop in lags: the local-maximum neighbourhood.
        hop_min = float(np.min(self.schedule.duration_s))
        self._half = max(1, int(0.5 * hop_min * fs / float(self.alphas.max()) / r))
        self._pad = 2 * r + 64

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget all state; the next sample is sample 0 again."""
        self._seen = 0
        self._restart(0)

    def _restart(self, origin: int) -> None:
        r = self._dec
        self._origin = origin  # global index of the first sample of this segment
        self._x = np.zeros(0)
        self._x0 = origin  # global index of self._x[0]
        self.baseband.reset(origin)
        self._q_first = -(-origin // r)  # absolute lag (in R samples) of the first grid lag
        self._z = np.zeros(0, dtype=np.complex64)
        self._z0 = self.baseband.next_output_index  # absolute baseband index of self._z[0]
        self._frame_q = self._q_first  # absolute lag of the next frame's first lag
        j_count = self.n_codewords
        self._scores = np.zeros(0)  # best ρ over (j, d) per lag
        self._rho_j = np.zeros((0, j_count))  # best ρ over d per lag and codeword
        self._d_j = np.zeros((0, j_count), dtype=np.int64)  # its Doppler index
        self._s0 = 0  # segment-local lag of self._scores[0]
        self._q_next = 0  # first segment-local lag not yet decided

    @property
    def mults_per_sample(self) -> float:
        """Complex multiplies per input sample of the bank (no refinement): the front end's
        ``T/R`` complex taps, then per frame (``S_b·R`` input samples) one ``N_b``-point FFT
        and, per correlator, ``N_b`` spectral products and one inverse FFT
        (:func:`~hil.estimation.cost.fft_mults`); the |c|² pass adds one per lag and
        correlator."""
        n_b, s_b, r = self._n_fft, self._step, self._dec
        jd = self._lengths.size
        per_frame = fft_mults(n_b) + jd * (n_b + fft_mults(n_b) + s_b)
        return self.baseband.n_taps / r + per_frame / (s_b * r)

    # ------------------------------------------------------------------ streaming
    def process(self, block: NDArray[np.floating], *, gap_before: int = 0) -> list[Estimate]:
        """Consume ``block`` (shape ``(n,)``, real samples) and return new estimates."""
        x = check_block(block, gap_before)
        out: list[Estimate] = []
        if gap_before:
            out.extend(self._finish())
            self._seen += int(gap_before)
            self._restart(self._seen)
        self._x = np.concatenate((self._x, x))
        self._z = np.concatenate((self._z, self.baseband.process(x).astype(np.complex64)))
        self._seen += x.shape[0]
        while self._frame_ready():
            self._run_frame(final=False)
        out.extend(self._decide(final=False))
        self._trim()
        return out

    def flush(self) -> list[Estimate]:
        """End of input: correlate the partial last frames and decide the remaining lags."""
        out = self._finish()
        self._restart(self._seen)
        return out

    def _frame_ready(self) -> bool:
        """Baseband and full-rate input both reach the end of the next frame."""
        f = self._frame_q + self._m0
        x_end = (self._frame_q + self._step - 1) * self._dec + int(self._lengths.max())
        return f + self._n_fft <= self._z0 + self._z.shape[0] and x_end <= self._seen

    def _finish(self) -> list[Estimate]:
        # Samples after the input count as zero: push the low-pass tail out.
        tail = self.baseband.process(np.zeros(self.baseband.n_taps + self._dec))
        self._z = np.concatenate((self._z, tail.astype(np.complex64)))
        l_max = int(self._lengths.max())
        while self._frame_q * self._dec + l_max <= self._seen:
            self._run_frame(final=True)
        return self._decide(final=True)

    def _run_frame(self, *, final: bool) -> None:
        n_b, step, r = self._n_fft, self._step, self._dec
        a = self._frame_q + self._m0 - self._z0
        frame = self._z[a : a + n_b]
        if frame.shape[0] < n_b:
            frame = np.concatenate((frame, np.zeros(n_b - frame.shape[0], dtype=np.complex64)))
        spec = scipy.fft.fft(frame, workers=self.fft_workers)
        # Full-rate energy of every window: a running sum of x² from the frame's first lag.
        n0 = self._frame_q * r - self._x0
        xs = self._x[n0 : n0 + (step - 1) * r + int(self._lengths.max())]
        cs = np.concatenate(([0.0], np.cumsum(xs * xs)))
        starts = np.arange(step) * r
        valid_len = self._seen - self._frame_q * r  # samples of real input from the first lag
        j_count, d_count = self._lengths.shape
        best = np.zeros((j_count, step), dtype=np.float32)  # best ρ² over Doppler
        best_d = np.zeros((j_count, step), dtype=np.int64)
        work = self._work
        for grp in self._groups:
            ends = starts[None, :] + grp.full[:, None]  # (D, S)
            energy = cs[np.minimum(ends, xs.shape[0])] - cs[np.minimum(starts, xs.shape[0])]
            inv = np.where(energy > 0, 2.0 / np.where(energy > 0, energy, 1.0), 0.0)
            if final:
                inv = np.where(ends <= valid_len, inv, 0.0)
            inv32 = inv.astype(np.float32)
            rows = slice(grp.first, grp.first + grp.count)
            for d0 in range(0, d_count, _D_CHUNK):
                d1 = min(d_count, d0 + _D_CHUNK)
                prod = np.multiply(grp.spectra[:, d0:d1, :], spec, out=work[: grp.count, : d1 - d0])
                corr = scipy.fft.ifft(prod, axis=-1, overwrite_x=True, workers=self.fft_workers)
                _best_over_doppler(corr, inv32, d0, best[rows], best_d[rows])
        # Back from group order to codeword order.
        rho_j = np.empty((j_count, step))
        rho_j[self._order] = np.sqrt(np.minimum(best, 1.0))
        d_j = np.empty((j_count, step), dtype=np.int64)
        d_j[self._order] = best_d
        self._rho_j = np.concatenate((self._rho_j, rho_j.T))
        self._d_j = np.concatenate((self._d_j, d_j.T))
        self._scores = np.concatenate((self._scores, rho_j.max(axis=0)))
        self._frame_q += step

    def _decide(self, *, final: bool) -> list[Estimate]:
        h = self._half
        avail = self._s0 + self._scores.shape[0]  # decimated lags known
        last = avail if final else avail - h
        if last <= self._q_next:
            return []
        lo = self._q_next - h
        pad_left = max(0, self._s0 - lo)
        seg = self._scores[max(0, lo - self._s0) :]
        seg = np.concatenate((np.full(pad_left, -1.0), seg))
        if final:
            seg = np.concatenate((seg, np.full(h, -1.0)))
        windows = sliding_window_view(seg, 2 * h + 1)[: last - self._q_next]
        centre = windows[:, h]
        is_peak = (
            (centre >= self.threshold)
            & (centre >= windows.max(axis=1))
            & (centre > windows[:, :h].max(axis=1))
        )
        out: list[Estimate] = []
        for off in np.flatnonzero(is_peak):
            q = self._q_next + int(off)
            est = self._readout(q)
            if est is not None:
                out.append(est)
        self._q_next = last
        return out

    def _trim(self) -> None:
        keep_q = self._q_next - self._half - 1
        if keep_q > self._s0:
            cut = keep_q - self._s0
            self._scores = self._scores[cut:]
            self._rho_j = self._rho_j[cut:]
            self._d_j = self._d_j[cut:]
            self._s0 = keep_q
        r = self._dec
        # Never past the samples held: the next block's first sample keeps its index.
        keep_x = min(self._frame_q * r, (self._q_first + keep_q) * r - self._pad, self._seen)
        if keep_x > self._x0:
            self._x = self._x[keep_x - self._x0 :]
            self._x0 = keep_x
        keep_z = min(self._frame_q + self._m0, self._z0 + self._z.shape[0])
        if keep_z > self._z0:
            self._z = self._z[keep_z - self._z0 :]
            self._z0 = keep_z

    # ------------------------------------------------------------------ readout
    def _corr(self, j: int, t_c: float, alpha: float) -> tuple[float, float, int]:
        """|c|, normalised ρ and sample count of the exact correlation at (t_c, α)."""
        fs = self.fs_hz
        half = 0.5 * self._t_win[j] / alpha
        k_lo = max(math.ceil((t_c - half) * fs), self._x0)
        k_hi = min(math.ceil((t_c + half) * fs), self._x0 + self._x.shape[0], self._seen)
        if k_hi - k_lo < 2:
            return 0.0, 0.0, 0
        k = np.arange(k_lo, k_hi)
        t_mid = self._t_end[j] - 0.5 * self._t_win[j]
        h = self.schedule.evaluate_analytic(t_mid + alpha * (k / fs - t_c))
        x = self._x[k_lo - self._x0 : k_hi - self._x0]
        c = complex(np.dot(x, np.conj(h)))
        hh = float(np.vdot(h, h).real)
        xx = float(np.dot(x, x))
        rho = math.sqrt(2.0) * abs(c) / math.sqrt(hh * xx) if hh * xx > 0 else 0.0
        return abs(c), rho, int(k.shape[0])

    def _profile_peak(self, j: int, alpha: float, t_c: float, span: int) -> tuple[float, float]:
        """Best window-centre time (s) within ±``span`` samples of ``t_c`` at fixed ``α``, and
        the |c| there (parabolic interpolation between integer lags)."""
        fs = self.fs_hz
        half = 0.5 * self._t_win[j] / alpha
        k0 = math.ceil((t_c - half) * fs)
        k1 = math.ceil((t_c + half) * fs)
        end = min(self._x0 + self._x.shape[0], self._seen)
        span = max(0, min(span, k0 - self._x0, end - k1))
        if k1 - k0 < 2 or k0 - span < self._x0 or k1 + span > end:
            return t_c, 0.0
        t_mid = self._t_end[j] - 0.5 * self._t_win[j]
        h = self.schedule.evaluate_analytic(t_mid + alpha * (np.arange(k0, k1) / fs - t_c))
        seg = self._x[k0 - span - self._x0 : k1 + span - self._x0]
        mag = np.abs(correlate(seg, h, mode="valid"))
        i = int(np.argmax(mag))
        if 0 < i < mag.shape[0] - 1:
            off, top = parabolic_peak(float(mag[i - 1]), float(mag[i]), float(mag[i + 1]))
        else:
            off, top = 0.0, float(mag[i])
        return t_c + (i - span + off) / fs, top

    def _refine(self, j: int, d: int, t_c: float) -> tuple[float, float]:
        """Profile search: for each α the best delay (the delay–Doppler ridge of a hopped code
        is slanted), first on a grid across the Doppler cell, then parabolic in α."""
        alpha = float(self.alphas[d])
        sch = self.schedule
        f0 = 0.5 * (sch.min_frequency_hz() + sch.max_frequency_hz())
        b_occ = max(sch.max_frequency_hz() - sch.min_frequency_hz(), 1.0 / self._t_win[j])
        t_win = float(self._t_win[j])
        res = 1.0 / (f0 * t_win)  # coherent α resolution
        d_max = self.alphas.shape[0] - 1
        if d_max > 0:
            lo, hi = float(self.alphas[max(d - 1, 0)]), float(self.alphas[min(d + 1, d_max)])
            cell = (hi - lo) / (2.0 if 0 < d < d_max else 1.0)  # one grid step
        else:
            cell = res
        # Delay shift along the ridge across the searched α span, plus the main-lobe width.
        ridge_s = 3.0 * cell * f0 * t_win / b_occ + 4.0 / b_occ
        span = int(min(math.ceil(ridge_s * self.fs_hz), 0.5 * t_win * self.fs_hz))
        count = min(129, int(math.ceil(3.0 * cell / (res / 3.0))) + 1) | 1
        best_t, best_v, best_a = t_c, -1.0, alpha
        for a in alpha + np.linspace(-1.5, 1.5, count) * cell:
            t_a, v_a = self._profile_peak(j, float(a), t_c, span)
            if v_a > best_v:
                best_t, best_v, best_a = t_a, v_a, float(a)
        t_c, alpha = best_t, best_a
        step = max(3.0 * cell / max(count - 1, 1), 1e-12)
        fine = max(4, int(math.ceil(step * f0 * t_win / b_occ * self.fs_hz)) + 4)
        for _ in range(_REFINE_ROUNDS):
            alpha = self._parabolic_step(
                lambda a, t_now=t_c: self._profile_peak(j, a, t_now, fine)[1], alpha, step
            )
            t_c = self._profile_peak(j, alpha, t_c, fine)[0]
            step *= 0.5
        return t_c, alpha

    @staticmethod
    def _parabolic_step(f: Any, x0: float, step: float) -> float:
        """Move ``x0`` to the vertex of the parabola through f at x0 − step, x0, x0 + step."""
        y_m, y_0, y_p = f(x0 - step), f(x0), f(x0 + step)
        # Walk uphill (at most a few steps) when the centre is not the largest value.
        for _ in range(4):
            if y_0 >= y_m and y_0 >= y_p:
                break
            if y_p > y_m:
                x0, y_m, y_0, y_p = x0 + step, y_0, y_p, f(x0 + 2 * step)
            else:
                x0, y_p, y_0, y_m = x0 - step, y_0, y_m, f(x0 - 2 * step)
        off, _ = parabolic_peak(y_m, y_0, y_p)
        return x0 + off * step

    def _readout(self, q: int) -> Estimate | None:
        row = self._rho_j[q - self._s0]
        n = (self._q_first + q) * self._dec  # global sample of the replica start
        if self.refine and n + int(self._lengths.max()) + self._pad > self._seen:
            return None  # the refinement would run off the end of the input
        # Grid scalloping can let a codeword sharing most hops win on the grid: refine the
        # strongest few and keep the best refined one.
        order = np.argsort(-row, kind="stable")[: self.n_candidates if self.refine else 1]
        best: tuple[float, int, float, float, int] | None = None
        for j in (int(i) for i in order):
            if row[j] < _CANDIDATE_RATIO * row[order[0]]:
                break
            d = int(self._d_j[q - self._s0, j])
            alpha = float(self.alphas[d])
            t_c = (n + int(self._lengths[j, d])) / self.fs_hz - 0.5 * self._t_win[j] / alpha
            rho, count = float(row[j]), int(self._lengths[j, d])
            if self.refine:
                t_c, alpha = self._refine(j, d, t_c)
                _, rho_exact, count_exact = self._corr(j, t_c, alpha)
                if count_exact:
                    rho, count = rho_exact, count_exact
            if best is None or rho > best[0]:
                best = (rho, j, t_c, alpha, count)
        assert best is not None
        rho, j, t_c, alpha, count = best
        t_win = float(self._t_win[j])
        t_rx = t_c + 0.5 * t_win / alpha
        resolved = resolve_transmit_time(
            t_rx, float(self._t_end[j]), self.schedule.period_s, self._max_delay_s
        )
        if resolved is None:
            return None
        t_tx, period_no = resolved
        rho_c = min(rho, 1.0 - 1e-12)
        snr = 10.0 * math.log10(max(rho_c * rho_c / (1.0 - rho_c * rho_c) * count / 2.0, 1e-30))
        c = self.sound_speed_mps
        return Estimate(
            t_s=t_rx,
            range_m=c * (t_rx - t_tx) / 2.0,
            speed_mps=float(speed_of_alpha(alpha, c)),
            hop_index=j + period_no * self.schedule.period_hops,
            score=rho,
            snr_db=snr,
            alpha=alpha,
            t_tx_s=t_tx,
            codeword=j,
            receiver=self.name,
        )
