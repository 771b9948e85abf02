"""GCAS: group correlators and accumulated sum, streaming (SPEC §3).

Pipeline per input block (every stage carries its state; any chunking of the input gives the
same estimates as one call on the whole signal):

1. :class:`~hil.estimation.baseband.ComplexBaseband`: mix by ``f_c`` (absolute sample index),
   linear-phase FIR low-pass, decimate by ``R`` to ``fs_bb``; the group delay is compensated in
   every reported time.
2. :class:`~hil.estimation.unit_correlators.UnitCorrelatorBank`: ``u[n, d, k]`` for the
   ``D`` Doppler hypotheses of :func:`~hil.estimation.doppler_grid.doppler_grid` (uniform in
   speed over ±max_speed) and the ``K`` tones, ``ν[d, k] = α_d f_k − f_c``, window
   ``N_d = round(T_h fs_bb/α_d)``; ``U = |u|²``.
3. Group correlators ``G_d = Σ_k U[:, d, k]``, accumulated over ``M`` hops by the comb
   recursion ``Acc_d[n] = Acc_d[n − N_d] + G_d[n] − G_d[n − M N_d]`` (cost independent of
   ``M``). Per sample, ``d̂[n] = argmax_d w_d Acc_d[n]`` (``w_d``: reverberation-band weights).
4. Accumulated sums at ``d̂`` and its two neighbours, for every codeword ``j`` of the period::

       A[n, d, j] = Σ_{m<M} U[n − ℓ_{d,m}, d, c_{j−m}]                  (noncoherent)
       A[n, d, j] = |Σ_{m<M} u[n − ℓ_{d,m}, d, c_{j−m}] e^{−jθ_{j,m}(n)}|²   (coherent)

   with lags ``ℓ_{d,m} = round(m L_d)``, ``L_d = T_h fs_bb/α_d`` [R: the spec writes
   ``m N_d``; rounding each lag separately keeps the M terms aligned within half a sample
   instead of letting the rounding of ``N_d`` accumulate to ``m/2`` samples]. The coherent
   phase (derived in :meth:`GcasReceiver._coherent_refine`, verified on noiseless echoes to
   < 0.01 rad by ``test_coherent_phase_model_matches_the_unit_correlators``): the unit
   correlator covering echo hop ``i`` (tone ``f``, start ``t_i``, start phase ``φ_i``) of
   ``s(α(t − τ0))`` has phase ``φ_i − 2π f (α τ0 + t_i) − 2π ν_d g + 2π (α − α_d) f c_i``
   (``g`` the filter delay, ``c_i`` the centre of the received hop); ``θ_{j,m}(n)`` below is
   its value at ``α = α_d`` and the integer-sample boundary of ``n`` (map diagnostics only).
   [R] With ``coherent=True`` detection, codeword and coarse time still come from the
   noncoherent sums (whose noise moments set the threshold); the coherent sum then refines
   each detection's boundary time and α on a fine grid of candidate ``(τ0, α)`` (±½ grating
   lobe ``1/(α Δf)``, ±1 Doppler step): at integer samples alone its ``1/B_w`` fine structure
   and the Doppler mismatch ``α − α_d`` (a phase ramp of ``2π f (α − α_d) m T_h`` over the
   terms) would pick neighbouring lobes.
5. The time–codeword map ``P[n, j] = A[n, d̂, j]`` (computed for every sample only when
   ``on_map`` is given: it costs ``J·M·K`` per sample and grows with ``M``).
6. Detection [R] (:mod:`hil.estimation.detection`), in two steps so that the cost per sample
   does not depend on ``M``: candidates are the local maxima over ``±N_min/2`` of the group
   statistic ``g[n] = max_d w_d Acc_d[n]``; at each candidate the exact sums ``A`` are
   evaluated for ``n`` within ``±W`` (``W = ⌈(M − 1)/4⌉ + 2``: the comb's integer lag puts
   its peak up to ``(M − 1)/4`` samples from the exact one) at ``d̂`` and its neighbours;
   ``s = max_j A[n, d̂, j]`` at its best ``n`` must exceed ``μ̂ + λσ̂`` and the best codeword
   ``ρ`` times the runner-up. CFAR modes: ``"bank"`` (default) estimates the
   unit-correlator noise power ``μ_U`` as the median over all (d, k) cells of ``U`` (÷ ln 2,
   the median of an exponential), averaged over a trailing window, and uses the noise
   moments of ``s``; ``"statistic"`` is the literal reading of SPEC §3.5 applied to the
   group statistic: median/MAD of ``g`` over a trailing window that ends one hop before the
   candidate. The bank mode stays valid while a target is tracked (the trailing statistic of
   a tracked target never returns to the noise floor, which blinds the literal form at high
   SNR). ``λ`` is set directly or from ``pfa`` per update.
   Reverberation band [R]: with ``reverb_speed_mps > 0`` every unit-correlator cell
   ``(d, k)`` whose frequency ``α_d f_k`` lies within ``[α(−v_r), α(v_r)]·f_k'`` (± half a
   main lobe) for ANY tone ``k'`` gets ``reverb_weight`` in ``G`` and in ``A``: a stationary
   echo of tone ``k'`` would otherwise appear as tone ``k`` at the ghost speed where
   ``α_d f_k = f_k'``.
7. Readout: parabolic interpolation of the peak in time and across ``d``; boundary receive time
   ``t_rx`` (window centred on the hop, group delay removed); ``ĵ = argmax_j``; ``t_tx`` the
   transmit end of hop ``ĵ`` plus the multiple of the code period that puts the delay in
   ``[0, τ_max]``, ``τ_max = 2 max_range/c`` (otherwise the detection is refused and counted);
   ``R = c (t_rx − t_tx)/2``, ``v = c (α̂ − 1)/(α̂ + 1)``; hop-index consistency is a soft
   flag (:attr:`GcasReceiver.last_detection`, :attr:`GcasReceiver.inconsistent_count`).

Searches. Steps 2–6 above are the ``search="full"`` form: every unit correlator at every
baseband sample (the reference). The default ``search="two-stage"`` [R] finds the same
boundaries at a fraction of the cost. Stage 1 (:class:`~hil.estimation.coarse_search.CoarseSearch`)
runs steps 2–3 on blocks of ``B`` baseband samples (windows of ``Q_d = round(L_d/B)`` blocks,
the comb's lags rounded per term for a shortlist of hypotheses) and gives the candidate blocks
(local maxima of the coarse statistic over ``±N_min/2``), ``d̂``, a runner-up hypothesis more
than one step from ``d̂`` and the noise floor. Stage 2
(:func:`~hil.estimation.kernels.codeword_sums`, straight from the baseband history, ``w·|u|²``
cached per sample) evaluates the exact sums ``A`` of step 4 within ``±(W + 6)`` samples of
each candidate for ``d̂`` and the runner-up (only the samples that can hold a maximum), keeps
the one with the larger weighted maximum (the group statistic cannot tell a hypothesis from
its ghost, every tone seen as its neighbour at another speed; the codeword sums can), moves
the window onto a peak at its edge, and evaluates ``d ± 1`` at the peak sample for the
Doppler interpolation. Thresholds and readout are shared. The hot loops of both stages and
of the front end are compiled (:mod:`hil.estimation.kernels`).

Latency: a boundary is reported once ``N_min/2`` baseband samples past it have arrived (plus
the filter delay), within one hop.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.estimation.baseband import ComplexBaseband
from hil.estimation.coarse_search import CoarseSearch
from hil.estimation.detection import (
    lambda_for_pfa,
    noise_moments,
    parabolic_offset,
    parabolic_offsets,
)
from hil.estimation.doppler_grid import DopplerGrid, alpha_to_speed, doppler_grid, speed_to_alpha
from hil.estimation.first_arrival import FirstArrivalReadout
from hil.estimation.kernels import (
    codeword_sums,
    exact_windows,
    fine_doppler,
    fine_keep,
    fine_pick,
    fine_recentre,
    first_possible_peak,
    peak_indices,
)
from hil.estimation.reverb_band import (
    AUTO,
    clutter_cells,
    edge_hypotheses,
    resolve_reverb_speed,
)
from hil.estimation.row_buffer import RowBuffer
from hil.estimation.unit_correlators import UnitCorrelatorBank
from hil.resident_arrays import resident_zeros
from hil.signals.random_cyclic import minimum_distance
from hil.signals.schedule import HopSchedule

HFCCW_FAMILIES = ("random-cyclic", "three-state")
#: Largest correlator length accepted (the seed uses up to 29).
M_MAX = 64
#: Baseband rate over twice the highest baseband frequency (room for the filter transition).
TRANSITION_FACTOR = 1.3
#: Noise-floor estimate on every this-many baseband samples (absolute grid).
NOISE_STRIDE = 32
CFAR_MODES = ("bank", "statistic")
#: Correlator searches: every hypothesis at every sample, or coarse-then-fine (two-stage).
SEARCH_MODES = ("full", "two-stage")
#: Range readouts: the peak of the accumulated sums, or the first arrival (tank multipath).
RANGE_READOUTS = ("peak", "first-arrival")
#: Default coarse step B of the two-stage search, baseband samples.
COARSE_STEP = 8
#: Anchor grid of the stage-2 prefix sums, baseband samples (values cached per sample).
EXACT_ANCHOR = 16
#: Stamp of an empty stage-2 cache slot (no sample index can equal it; −1 can, before a
#: stream's first sample).
NO_SAMPLE = np.iinfo(np.int64).min
#: Times the two-stage search moves its fine window onto an edge peak, at most.
RECENTRE_STEPS = 4
#: A hypothesis and its two neighbours on the Doppler grid (offsets, shape (1, 3)).
_NEIGHBOURS = np.arange(-1, 2, dtype=np.int64)[None, :]
#: Guard around every tone's reverberation band, in unit-correlator main lobes (1/T_h).
#: Measured: 0.5 leaves no ghost on the clutter-plus-target test; wider guards move the
#: ghost to the first unmasked hypothesis past the guard instead of removing it.
REVERB_GUARD_LOBES = 0.5

MapCallback = Callable[[NDArray[np.float64], NDArray[np.float32], NDArray[np.float64]], None]


@dataclass(frozen=True)
class DetectionInfo:
    """Diagnostics of one detection, beside its :class:`Estimate`.

    ``sample`` (baseband index of the peak), ``threshold`` and ``noise_mean`` (statistic
    units), ``runner_up_ratio`` (best / second-best codeword), ``consistent`` (hop index
    advanced as the elapsed time predicts since the previous detection; None for the first).
    """

    sample: int
    threshold: float
    noise_mean: float
    runner_up_ratio: float
    consistent: bool | None


def minimum_m_hops(code: NDArray[np.int64], upper: int = M_MAX) -> int:
    """Smallest M at which all M-hop codewords of the cyclic ``code`` differ (d_min >= 1).

    >>> minimum_m_hops(np.array([0, 1, 2, 0, 2, 0, 2, 1]))
    4
    """
    for m in range(1, upper + 1):
        if minimum_distance(code, m) >= 1:
            return m
    raise ConfigError("code", code.tolist(), f"a code whose codewords differ at some M <= {upper}")


def _check_schedule(schedule: HopSchedule, fs_hz: float, c: float, v_max: float) -> None:
    if schedule.family not in HFCCW_FAMILIES:
        raise ConfigError(
            "schedule.family",
            schedule.family,
            f"an HFC-CW family ({' or '.join(HFCCW_FAMILIES)})",
            "GCAS decodes tone-hop codes; use the fmcw, stft or mfbank receiver for this waveform",
        )
    if np.any(schedule.code < 0):
        raise ConfigError("schedule.code", schedule.code.tolist(), "no silent hops")
    schedule.hop_s  # noqa: B018 - raises for unequal hops
    design_fs = schedule.params.get("fs_hz")
    if design_fs is not None and not math.isclose(float(design_fs), fs_hz, rel_tol=1e-9):
        raise ConfigError(
            "fs_hz",
            fs_hz,
            f"the rate the schedule was designed for, {float(design_fs):g} Hz",
            "resample the input or rebuild the schedule for this rate",
        )
    nyquist = 2.0 * float(speed_to_alpha(v_max, c)) * schedule.max_frequency_hz()
    if fs_hz <= nyquist:
        raise ConfigError(
            "fs_hz", fs_hz, f"> {nyquist:.1f} Hz (Nyquist of the Doppler-scaled top tone)"
        )


@dataclass(frozen=True)
class _ReadoutConstants:
    """Per-receiver constants of :meth:`GcasReceiver._decide` as Python numbers (the readout
    runs once per detection; NumPy scalars there cost more than the arithmetic)."""

    speeds: list[float]
    speed_step: float
    lengths: list[int]
    hop_samples: float
    decimation: int
    group_delay: float
    fs_in: float
    period: float
    hop_end: list[float]


class GcasReceiver:
    """Streaming GCAS receiver; see the module docstring for the algorithm.

    Parameters
    ----------
    schedule:
        The transmit schedule (``random-cyclic`` or ``three-state``); the first input sample
        is at the schedule's t = 0.
    fs_hz:
        Input sample rate, Hz.
    sound_speed_mps, max_speed_mps, max_range_m:
        c (m/s), the Doppler search span ± (m/s) and the largest range reported (m).
    m_hops:
        Correlator length M, from the code's minimum (all M-hop codewords distinct) to
        :data:`M_MAX`.
    n_doppler:
        Number of Doppler hypotheses D.
    coherent:
        Coherent accumulated sum (phases restored) instead of the noncoherent default [R].
    pfa:
        False-alarm probability per update used to set λ when ``cfar_lambda`` is None.
    cfar_lambda:
        λ of the threshold ``μ̂ + λσ̂`` (overrides ``pfa``).
    runner_up_ratio:
        ρ: best codeword over the runner-up, >= 1.
    cfar_window_hops:
        Length of the trailing CFAR window, hops.
    cfar_mode:
        ``"bank"`` or ``"statistic"`` (module docstring, step 6).
    reverb_speed_mps, reverb_weight:
        Reverberation band: Doppler cells that stationary clutter of speed ``|v| <``
        ``reverb_speed_mps`` (m/s) fills get ``reverb_weight`` in the Doppler decision (0
        excludes them). Default ``"auto"``: the waveform's clutter main lobe
        (:mod:`hil.estimation.reverb_band`: targets slower than the Doppler resolution
        ``c/(2 f T_h)`` are not reported); 0 turns the band off (a stationary or slow target).
        Detections on the band's edge are refused (:attr:`in_band_count`).
    decimation:
        Baseband decimation R; default the largest that keeps the Doppler-scaled band.
    attenuation_db:
        Stop-band attenuation of the baseband low-pass, dB.
    search:
        ``"two-stage"`` (default: coarse correlators every ``coarse_step`` samples choose the
        hypothesis and the candidate times; exact sums only around each candidate) or
        ``"full"`` (every unit correlator at every baseband sample; the reference).
    coarse_step:
        Coarse step B of the two-stage search, baseband samples.
    range_readout, max_spread_s:
        ``"peak"`` (default): the boundary time is the peak of the accumulated sums (in
        multipath, the centroid of the arrivals); ``"first-arrival"``: the onset of the next
        tone, the direct path in a tank (:mod:`hil.estimation.first_arrival`; arrivals up to
        ``max_spread_s`` s before the peak; default 0.3 hop).
    on_map:
        Called as ``on_map(t_s, P, speed_mps)`` with the time–codeword map of each new stretch
        of baseband samples: times (s, shape ``(n,)``), ``P`` (shape ``(n, J)``) and the chosen
        Doppler hypothesis as a speed (m/s, shape ``(n,)``).
    """

    name = "gcas"

    def __init__(
        self,
        schedule: HopSchedule,
        fs_hz: float,
        *,
        sound_speed_mps: float,
        max_speed_mps: float,
        max_range_m: float,
        m_hops: int,
        n_doppler: int = 64,
        coherent: bool = False,
        pfa: float = 1e-3,
        cfar_lambda: float | None = None,
        runner_up_ratio: float = 1.05,
        cfar_window_hops: float = 8.0,
        cfar_mode: str = "bank",
        reverb_speed_mps: float | str | None = AUTO,
        reverb_weight: float = 0.0,
        decimation: int | None = None,
        attenuation_db: float = 70.0,
        on_map: MapCallback | None = None,
        search: str = "two-stage",
        coarse_step: int = COARSE_STEP,
        range_readout: str = "peak",
        max_spread_s: float | None = None,
    ) -> None:
        if not (math.isfinite(fs_hz) and fs_hz > 0):
            raise ConfigError("fs_hz", fs_hz, "> 0 Hz")
        c = float(sound_speed_mps)
        if not (math.isfinite(c) and c > 0):
            raise ConfigError("sound_speed_mps", sound_speed_mps, "> 0 m/s")
        if not (math.isfinite(max_speed_mps) and 0 < max_speed_mps < c):
            raise ConfigError("max_speed_mps", max_speed_mps, f"0 < v < c = {c} m/s")
        _check_schedule(schedule, float(fs_hz), c, float(max_speed_mps))
        code = schedule.code.astype(np.int64)
        m_min = minimum_m_hops(code)
        if int(m_hops) != m_hops or not m_min <= m_hops <= M_MAX:
            raise ConfigError(
                "m_hops",
                m_hops,
                f"an integer in {m_min}..{M_MAX} for this code (codewords are distinct, "
                f"d_min >= 1, from M = {m_min}; {M_MAX} is the largest correlator supported)",
                "M larger than the code allows or too short to tell codewords apart",
            )
        if not (math.isfinite(max_range_m) and max_range_m > 0):
            raise ConfigError("max_range_m", max_range_m, "> 0 m")
        r_unamb = schedule.unambiguous_range_m(c)
        if max_range_m > r_unamb:
            raise ConfigError(
                "max_range_m",
                max_range_m,
                f"<= the unambiguous range c·period/2 = {r_unamb:.2f} m",
                "lengthen the code or the hop, or lower the maximum range",
            )
        if cfar_mode not in CFAR_MODES:
            raise ConfigError("cfar_mode", cfar_mode, f"one of {', '.join(CFAR_MODES)}")
        if not (math.isfinite(runner_up_ratio) and runner_up_ratio >= 1):
            raise ConfigError("runner_up_ratio", runner_up_ratio, ">= 1")
        if not (math.isfinite(cfar_window_hops) and cfar_window_hops >= 1):
            raise ConfigError("cfar_window_hops", cfar_window_hops, ">= 1 hop")
        if search not in SEARCH_MODES:
            raise ConfigError("search", search, f"one of {', '.join(SEARCH_MODES)}")
        self.search = search
        if range_readout not in RANGE_READOUTS:
            raise ConfigError("range_readout", range_readout, f"one of {', '.join(RANGE_READOUTS)}")
        self.range_readout = range_readout
        self._first_arrival = (
            FirstArrivalReadout(schedule, float(fs_hz), int(m_hops), max_spread_s)
            if range_readout == "first-arrival"
            else None
        )

        self.schedule = schedule
        self.fs_hz = float(fs_hz)
        self.sound_speed_mps = c
        self.max_speed_mps = float(max_speed_mps)
        self.max_range_m = float(max_range_m)
        self.m_hops = int(m_hops)
        self.coherent = bool(coherent)
        self.cfar_mode = cfar_mode
        self.runner_up_ratio = float(runner_up_ratio)
        self.on_map = on_map
        self.code = code
        self.n_codewords = int(code.shape[0])
        self.hop_s = schedule.hop_s
        tones = schedule.tones_hz
        self.tones_hz = tones
        center = 0.5 * (float(tones.min()) + float(tones.max()))
        self.center_hz = center

        # Baseband: the band must hold every Doppler-scaled tone plus a sinc main lobe.
        a_lo, a_hi = speed_to_alpha(-self.max_speed_mps, c), speed_to_alpha(self.max_speed_mps, c)
        band = max(abs(a_hi * tones.max() - center), abs(a_lo * tones.min() - center))
        passband = float(band) + 2.0 / self.hop_s
        if decimation is None:
            decimation = max(1, int(self.fs_hz / (2.0 * TRANSITION_FACTOR * passband)))
        self.baseband = ComplexBaseband(
            self.fs_hz,
            center,
            decimation=int(decimation),
            passband_hz=passband,
            attenuation_db=attenuation_db,
        )
        self.fs_bb = self.baseband.fs_out_hz
        reverb_speed = resolve_reverb_speed(
            reverb_speed_mps, tones, self.hop_s, c, self.max_speed_mps
        )
        self.grid: DopplerGrid = doppler_grid(
            self.max_speed_mps,
            int(n_doppler),
            c,
            self.hop_s,
            self.fs_bb,
            reverb_speed_mps=reverb_speed,
            reverb_weight=reverb_weight,
        )
        # The per-sample bank of the full search (the two-stage search never builds it).
        self.bank: UnitCorrelatorBank | None = None
        if search == "full":
            self.bank = UnitCorrelatorBank(
                self.fs_bb, self.grid.frequencies(tones, center), self.grid.lengths
            )
        d, k, m, j = self.grid.size, self.n_tones, self.m_hops, self.n_codewords
        #: The band's clutter speed in use, m/s (0: no band).
        self.reverb_speed_mps = reverb_speed
        self.reverb_weight = float(reverb_weight)
        self._tone_w = self._reverb_tone_mask()
        #: Hypotheses whose detections are refused (the band's edge; see reverb_band).
        self.refused_hypotheses = self._refused_hypotheses()
        m_idx = np.arange(m)
        self.lags = np.round(m_idx[None, :] * self.grid.exact_lengths[:, None]).astype(np.int64)
        self._w_coh = self._codeword_weights()[1]
        # Cell m·K + c_{j−m} of the (M·K) terms that is term m of codeword j, shape (M, J):
        # the noncoherent sums gather these.
        self._term_cell = m_idx[:, None] * k + code[(np.arange(j)[None, :] - m_idx[:, None]) % j]
        self._n_min = int(self.grid.lengths.min())
        self._n_max = int(self.grid.lengths.max())
        self._comb_lag = (m * self.grid.lengths)[None, :]  # (1, D) samples
        self.half_width = max(1, self._n_min // 2)
        self._cfar_window = max(2, int(round(cfar_window_hops * self.hop_s * self.fs_bb)))
        # Detection (threshold, codeword, coarse time) always runs on the noncoherent sums;
        # the coherent form refines the time and Doppler of each detection (step 7).
        self._moments = noise_moments(m, False)
        if cfar_lambda is None:
            self.cfar_lambda = lambda_for_pfa(pfa, m, j, False) if cfar_mode == "bank" else 5.0
        else:
            if not math.isfinite(cfar_lambda):
                raise ConfigError("cfar_lambda", cfar_lambda, "a finite number")
            self.cfar_lambda = float(cfar_lambda)
        self._settle = (
            int(self.lags.max()) + self._n_max + self.baseband.n_taps // int(decimation) + 2
        )
        # Coherent restoration constants per (d, k): f_k α_d and the filter-delay phase ν g.
        g = self.baseband.group_delay / self.fs_hz
        nu = self.grid.frequencies(tones, center)
        self._fa = tones[None, :] * self.grid.alphas[:, None]  # (D, K) Hz
        self._delta0 = (self.grid.exact_lengths - self.grid.lengths + 1) / (2.0 * self.fs_bb)
        self._coh_const = np.mod(self._fa * self._delta0[:, None] + nu * g, 1.0)  # cycles
        # Candidate search window (baseband samples) around a peak of the group statistic:
        # the comb uses the integer lag N_d, so its peak may sit up to (M − 1)|N_d − L_d|/2
        # <= (M − 1)/4 samples from the peak of the exactly lagged codeword sums.
        self.search_half = min(int(math.ceil((m - 1) / 4.0)) + 2, max(1, self.half_width - 1))
        lag_keep = int(self.lags.max()) + 2 * self.search_half + self.half_width + 2
        self._u_ring = RowBuffer(lag_keep, (d, k), np.complex64 if self.coherent else np.float32)
        self._g_ring = RowBuffer(m * self._n_max + 1, (d,), np.float64)
        self._acc_ring = RowBuffer(self._n_max + 1, (d,), np.float64)
        det_keep = self._cfar_window + 2 * self._n_max + 4
        self._s_ring = RowBuffer(det_keep, (), np.float64)
        self._dhat_ring = RowBuffer(det_keep, (), np.int64)
        self._noise_ring = RowBuffer(det_keep, (), np.float64)
        if search == "two-stage":
            self._init_two_stage(coarse_step, det_keep)
        sch = schedule
        self._readout_constants = _ReadoutConstants(
            speeds=self.grid.speeds_mps.tolist(),
            speed_step=self.grid.speed_step_mps,
            lengths=self.grid.lengths.tolist(),
            hop_samples=self.hop_s * self.fs_bb,
            decimation=self.baseband.decimation,
            group_delay=self.baseband.group_delay,
            fs_in=self.baseband.fs_hz,
            period=sch.period_s,
            hop_end=(sch.t0_s + (sch.start_s + sch.duration_s)).astype(np.float64).tolist(),
        )
        self.reset()
        self._warm_up()

    def _warm_up(self) -> None:
        """Run every compiled kernel once on a few zeros, then forget it: the first call in a
        process loads the machine code from numba's cache (or compiles it, seconds), which must
        not happen inside the first live block. The map callback is not called."""
        on_map, self.on_map = self.on_map, None
        try:
            self.process(np.zeros(self.baseband.decimation * 64))
            peak_indices(np.zeros(3), 1, 0, 3)
            if self.search == "two-stage":
                one = np.zeros((1, 1), dtype=np.int64)
                self._fine_sums(one[:, 0], one, self.fine_half, prune=True)
                # The stage-2 kernels between the sums, on one made-up candidate.
                two = np.zeros((1, 2), dtype=np.int64)
                a2 = self._fine_sums(two, two, self.fine_half, prune=True)
                d0, centre, a, s_win, i_pk, edges = fine_pick(
                    a2, two, two, self._hyp_w, self.fine_half, True
                )
                sums = self._fine_sums(centre[edges], d0[edges, None], self.fine_half)
                fine_recentre(a, sums, edges, s_win, i_pk, centre, self.fine_half, True)
                _, _, word, _, _, sides = fine_keep(
                    one[0], a, s_win, i_pk, d0, self.grid.size, self.fine_half, 1.0
                )
                side = self._fine_sums(one[0], sides, 0)
                fine_doppler(side, a, one[0], i_pk, word, d0, sides)
                # The coherent readout and the time–codeword map (``on_map``, off here) both
                # read exact windows, the map also when noncoherent.
                self._exact_windows(one[:, 0], one[:, 0], 1)
        finally:
            self.on_map = on_map
        self.reset()

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_options(
        cls,
        schedule: HopSchedule,
        fs_hz: float,
        *,
        sound_speed_mps: float,
        max_speed_mps: float,
        max_range_m: float,
        m_hops: int,
        **extra: Any,
    ) -> GcasReceiver:
        """The registry's common constructor (:mod:`hil.estimation.registry`)."""
        known = {
            "n_doppler", "coherent", "pfa", "cfar_lambda", "runner_up_ratio",
            "cfar_window_hops", "cfar_mode", "reverb_speed_mps", "reverb_weight",
            "decimation", "attenuation_db", "on_map", "search", "coarse_step",
            "range_readout", "max_spread_s",
        }  # fmt: skip
        unknown = sorted(set(extra) - known)
        if unknown:
            raise ConfigError("gcas option", unknown, f"one of {sorted(known)}")
        return cls(
            schedule,
            fs_hz,
            sound_speed_mps=sound_speed_mps,
            max_speed_mps=max_speed_mps,
            max_range_m=max_range_m,
            m_hops=m_hops,
            **extra,
        )

    @property
    def n_tones(self) -> int:
        """Number of tones K."""
        return int(self.tones_hz.shape[0])

    def _reverb_tone_mask(self) -> NDArray[np.float32] | None:
        """Per-(d, k) weights of the reverberation band, shape ``(D, K)``; None without one.

        The unit correlator ``(d, k)`` listens at ``α_d f_k``; it sees stationary clutter
        whenever that frequency lies within half a main lobe of the clutter band of ANY tone
        ``k'`` (:func:`~hil.estimation.reverb_band.clutter_cells`), not only ``k' = k``: a
        stationary echo of tone ``k'`` looks like tone ``k`` moving at the speed where
        ``α_d f_k = f_k'`` (a ghost speed). Such cells get ``reverb_weight`` in the group
        statistic and in the codeword sums [R]: the band is handled per tone in frequency.
        """
        if self.reverb_speed_mps <= 0.0:
            return None
        hit = clutter_cells(
            self.grid.alphas, self.tones_hz, self.reverb_speed_mps, self.sound_speed_mps,
            REVERB_GUARD_LOBES / self.hop_s, any_tone=True,
        )  # fmt: skip
        return np.where(hit, self.reverb_weight, 1.0).astype(np.float32)

    def _refused_hypotheses(self) -> NDArray[np.bool_]:
        """Hypotheses whose detections are refused, shape ``(D,)``: the edge of the band
        around zero Doppler (:func:`~hil.estimation.reverb_band.edge_hypotheses`). Cells
        masked as another tone's clutter (the ghost speeds) are not an edge: a target there
        keeps its other tones, and the codeword sums tell it from the clutter."""
        if self.reverb_speed_mps <= 0.0:
            return np.zeros(self.grid.size, dtype=bool)
        own = clutter_cells(
            self.grid.alphas, self.tones_hz, self.reverb_speed_mps, self.sound_speed_mps,
            REVERB_GUARD_LOBES / self.hop_s, any_tone=False,
        ).any(axis=1)  # fmt: skip
        in_band = own | (self.grid.weights < 1.0)
        return edge_hypotheses(np.where(in_band, 0.0, 1.0), self.reverb_weight > 0)

    def _codeword_weights(self) -> tuple[NDArray[np.float32], NDArray[np.complex64]]:
        """Codeword matrices of shape ``(M·K, J)``: tone indicator, and with phases restored."""
        m, k, j, p = self.m_hops, self.n_tones, self.n_codewords, self.n_codewords
        jj = np.arange(j)[None, :]
        mm = np.arange(m)[:, None]
        tone = self.code[(jj - mm) % p]  # (M, J): tone of term m of codeword j
        onehot = (tone[:, None, :] == np.arange(k)[None, :, None]).astype(np.float32)
        w_non = onehot.reshape(m * k, j)
        # Φ_end of hop h (global, h = j − m in −M+1..P−1) is the start phase of hop h + 1.
        table = self.schedule.hops(-m + 2, p + m - 1)
        phase_end = table.phase_rad[(jj - mm) + m - 1]  # (M, J)
        f = self.tones_hz[tone]
        theta = phase_end + 2.0 * np.pi * np.mod(f * mm * self.hop_s, 1.0)
        w_coh = (onehot * np.exp(-1j * theta)[:, None, :]).astype(np.complex64)
        return w_non, w_coh.reshape(m * k, j)

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget all state; the next sample is sample 0 again."""
        self._samples_seen = 0
        self._restart(0)
        self.inconsistent_count = 0
        self.refused_count = 0
        #: Detections refused as the edge leak of an echo inside the reverberation band.
        self.in_band_count = 0
        self.last_detection: DetectionInfo | None = None

    @property
    def samples_seen(self) -> int:
        """Input samples consumed so far (gaps included)."""
        return self._samples_seen

    def _restart(self, input_index: int) -> None:
        """Restart every accumulation at absolute input sample ``input_index``."""
        self.baseband.reset(input_index)
        if self._first_arrival is not None:
            self._first_arrival.reset(input_index)
        b0 = self.baseband.next_output_index
        if self.bank is not None:
            self.bank.reset(b0)
        for ring in (
            self._u_ring, self._g_ring, self._acc_ring, self._s_ring, self._dhat_ring,
            self._noise_ring,
        ):  # fmt: skip
            ring.reset(b0)
        self._origin = b0
        self._valid_from = b0 + self._settle
        self._det_next = b0
        if self.search == "two-stage":
            self.coarse.reset(b0)
            c0 = self.coarse.next_block
            for ring in (self._cs_ring, self._cd_ring, self._cn_ring):
                ring.reset(c0)
            self._y_ring.reset(b0)
            self._cache_n.fill(NO_SAMPLE)
            self._c_origin = c0
            self._c_valid_from = -(-self._valid_from // self._B) + 1
            self._det_next = c0
        self._last_hop: int | None = None
        self._last_t = 0.0

    # ------------------------------------------------------------------ streaming
    def process(self, block: ArrayLike, *, gap_before: int = 0) -> list[Estimate]:
        """Consume real samples (shape ``(n,)``); return the estimates completed by them.

        ``gap_before`` samples are missing before this block: estimates still pending are
        finalised, the time base advances and every accumulation restarts.
        """
        x = np.asarray(block, dtype=np.float64)
        if x.ndim != 1:
            raise ConfigError("block", f"shape {x.shape}", "a 1-D array of real samples")
        if int(gap_before) != gap_before or gap_before < 0:
            raise ConfigError("gap_before", gap_before, "an integer >= 0 (samples)")
        bad = ~np.isfinite(x)
        if bad.any():
            i = int(np.argmax(bad))
            raise ConfigError(
                "block",
                f"{x[i]} at sample index {self._samples_seen + gap_before + i}",
                "finite samples (no NaN or inf)",
                "check the acquisition; mark missing samples with gap_before instead",
            )
        out: list[Estimate] = []
        if gap_before:
            out += self.flush()
            self._samples_seen += int(gap_before)
            self._restart(self._samples_seen)
        if self._first_arrival is not None:
            self._first_arrival.push(x, self._samples_seen)
        self._samples_seen += x.shape[0]
        y = self.baseband.process(x)
        if y.shape[0]:
            out += self._two_stage(y) if self.search == "two-stage" else self._stage2(y)
        return out

    def flush(self) -> list[Estimate]:
        """End of input: decide the candidates still waiting for their look-ahead."""
        # Candidates whose ±N/2 look-ahead never arrived are not decided: a peak cut by the
        # end of the input has no reliable time or codeword.
        if self.search == "two-stage":
            return self._detect_two_stage(self._cs_ring.next_index)
        return self._detect(self._s_ring.next_index - self.half_width)

    # ------------------------------------------------------------------ stage 2
    def _stage2(self, y: NDArray[np.complex128]) -> list[Estimate]:
        assert self.bank is not None  # built for the full search
        a0 = self.bank.next_index
        u = self.bank.process_last(y)  # (D, K, n): samples on the contiguous axis
        n = u.shape[2]
        power = np.square(u.real) + np.square(u.imag)
        masked = power if self._tone_w is None else power * self._tone_w[:, :, None]
        grp = masked.sum(axis=1, dtype=np.float64).T
        kept: NDArray[Any] = masked
        if self.coherent:
            kept = u if self._tone_w is None else u * self._tone_w[:, :, None]
        self._u_ring.append(kept.transpose(2, 0, 1), a0)
        self._g_ring.append(grp, a0)
        acc = self._accumulate_groups(grp, a0)
        self._acc_ring.append(acc, a0)
        wacc = acc * self.grid.weights[None, :]
        d_hat = np.argmax(wacc, axis=1)
        self._s_ring.append(np.take_along_axis(wacc, d_hat[:, None], axis=1)[:, 0], a0)
        self._dhat_ring.append(d_hat, a0)
        idx = a0 + np.arange(n, dtype=np.int64)
        self._noise_ring.append(self._noise_floor(power, idx, a0), a0)
        if self.on_map is not None:
            # Diagnostics only: the full map costs J·M·K per sample (the detector itself
            # evaluates the codeword sums only around candidate peaks).
            self.on_map(
                self.baseband.time_of(idx),
                self._sums(idx, d_hat, self.coherent),
                self.grid.speeds_mps[d_hat].astype(np.float64),
            )
        return self._detect(self._s_ring.next_index - self.half_width)

    def _accumulate_groups(self, grp: NDArray[np.float64], a0: int) -> NDArray[np.float64]:
        """``Acc_d[n] = Acc_d[n − N_d] + G_d[n] − G_d[n − M N_d]`` for the new samples."""
        return _comb(grp, a0, self._g_ring, self._acc_ring, self.grid.lengths, self.m_hops)

    # ------------------------------------------------------------------ two-stage search
    def _init_two_stage(self, coarse_step: int, det_keep: int) -> None:
        """State of the two-stage search (:meth:`_two_stage`)."""
        top = max(1, self._n_min // 4)
        if int(coarse_step) != coarse_step or not 1 <= coarse_step <= top:
            raise ConfigError(
                "coarse_step",
                coarse_step,
                f"an integer in 1..{top} (a quarter of the shortest hop, baseband samples)",
                "the coarse response of a hop boundary is a tent about two hops wide",
            )
        b = self._B = int(coarse_step)
        m = self.m_hops
        exact = self.grid.exact_lengths
        self._q = np.maximum(1, np.round(exact / b)).astype(np.int64)  # (D,) blocks per hop
        hop_blocks = exact / b
        lag_blocks = np.round(np.arange(m)[None, :] * hop_blocks[:, None])  # (D, M), as stage 1
        # Coarse block → fine sample of a candidate: the coarse window (Q_d·B samples) peaks
        # (Q_d·B − N_d)/2 later than the exact one, and term m of the coarse comb sits
        # ℓ_{d,m} − B·lag_m samples off the exact one, which moves its peak by their mean.
        self._c_shift = np.round(
            b
            - 1
            - 0.5 * (self._q * b - self.grid.lengths)
            + np.mean(self.lags - b * lag_blocks, axis=1)
        ).astype(np.int64)
        self._hc = max(1, self.half_width // b)
        self._max_shift = int(np.max(self._c_shift))
        self.fine_half = self.search_half + 6
        reach = int(np.max(self._c_shift)) + self.fine_half  # samples past the block start
        self._c_lookahead = self._hc + max(0, -(-reach // b))
        self.coarse = CoarseSearch(
            self.fs_bb,
            self.grid.frequencies(self.tones_hz, self.center_hz),
            self._q,
            block=b,
            m_hops=m,
            hop_blocks=hop_blocks,
            cell_weights=self._tone_w,
            hyp_weights=self.grid.weights,
            noise_every=max(1, NOISE_STRIDE // b),
            noise_scale=self.grid.lengths / (self._q * b),
        )
        c_keep = det_keep // b + 4
        self._cs_ring = RowBuffer(c_keep, (), np.float64)
        self._cd_ring = RowBuffer(c_keep, (2,), np.int64)  # d̂ and the runner-up
        self._cn_ring = RowBuffer(c_keep, (), np.float64)
        y_keep = (
            int(self.lags.max()) + self._n_max + 2 * self.fine_half + (self._c_lookahead + 2) * b
            + abs(int(np.min(self._c_shift))) + RECENTRE_STEPS * self.fine_half + 8
        )  # fmt: skip
        self._y_ring = RowBuffer(y_keep, (), np.complex128)
        self._nu_fs = self.grid.frequencies(self.tones_hz, self.center_hz) / self.fs_bb  # (D, K)
        self._table: NDArray[np.float64] | None = None
        self._phasor_table(max(2 * self.fine_half + 1, EXACT_ANCHOR))
        # Stage-2 cache of w·|u|² by absolute sample (slot n mod cap, stamped with n).
        reach = (
            int(self.lags.max()) + self._n_max + 2 * self.fine_half + 2 * EXACT_ANCHOR
            + 2 * self._B
        )  # fmt: skip
        cap = 1 << int(math.ceil(math.log2(2 * reach)))
        # Mapped now, not page by page in the first live blocks (hil.resident_arrays).
        self._cache_p = resident_zeros((self.grid.size, self.n_tones, cap))
        self._cache_max = resident_zeros((self.grid.size, cap))
        self._hyp_w = np.ascontiguousarray(self.grid.weights, dtype=np.float64)
        self._cache_n = np.full((self.grid.size, cap), NO_SAMPLE, dtype=np.int64)
        code, m_idx = self.code, np.arange(m)
        self._term_tone = code[(np.arange(self.n_codewords)[None, :] - m_idx[:, None]) % code.size]
        tone_w = (
            self._tone_w if self._tone_w is not None else np.ones((self.grid.size, self.n_tones))
        )
        self._cell_w = np.ascontiguousarray(tone_w, dtype=np.float64)

    def _phasor_table(self, width: int) -> NDArray[np.float64]:
        """``e^{−j2πν[d, k] i/fs}`` for offsets ``i < N_max + width − 1``, shape
        ``(D, ·, K, 2)`` (re, im), grown on demand."""
        need = self._n_max + width - 1
        if self._table is None or self._table.shape[1] < need:
            i = np.arange(need, dtype=np.float64)
            ph = np.exp(-2j * np.pi * np.mod(i[None, :, None] * self._nu_fs[:, None, :], 1.0))
            self._table = np.ascontiguousarray(np.stack((ph.real, ph.imag), axis=-1))
        return self._table

    def _two_stage(self, y: NDArray[np.complex128]) -> list[Estimate]:
        """Stage 1 on the new baseband samples ``y``; stage 2 at the decided candidates."""
        self._y_ring.append(y, self._y_ring.next_index)
        stat, d_hat, noise, c0 = self.coarse.process(y)
        if stat.shape[0]:
            self._cs_ring.append(stat, c0)
            self._cd_ring.append(d_hat, c0)
            self._cn_ring.append(noise, c0)
        if self.on_map is not None:
            stop = self._y_ring.next_index
            idx = np.arange(stop - y.shape[0], stop, dtype=np.int64)
            if self._cd_ring.next_index > self._c_origin:
                blk = np.clip(idx // self._B, self._c_origin, self._cd_ring.next_index - 1)
                d_map = self._cd_ring.rows(blk)[:, 0]
            else:
                d_map = np.zeros(idx.shape[0], dtype=np.int64)
            self.on_map(
                self.baseband.time_of(idx),
                self._sums(idx, d_map, self.coherent),
                self.grid.speeds_mps[d_map].astype(np.float64),
            )
        return self._detect_two_stage(self._cs_ring.next_index)

    def _exact_windows(
        self, first: NDArray[np.int64], dd: NDArray[np.int64], width: int
    ) -> NDArray[np.complex128]:
        """Exact unit correlators ``u[first_r + t, dd_r, k]`` for ``t < width`` (shape
        ``(R, width, K)``; ``first`` and ``dd`` of shape ``(R,)``) from the baseband history
        (:func:`hil.estimation.kernels.exact_windows`: every row is a function of its own
        ``first``, ``dd`` and ``width``, so batching and chunking cannot change a bit)."""
        ring = self._y_ring
        out = np.empty((first.shape[0], width, self.n_tones, 2))
        exact_windows(
            ring.array[: ring.available], ring.next_index - ring.available,
            np.ascontiguousarray(first, dtype=np.int64), np.ascontiguousarray(dd, dtype=np.int64),
            width, self.grid.lengths, self._nu_fs, self._phasor_table(width), out,
        )  # fmt: skip
        return out[..., 0] + 1j * out[..., 1]

    def _exact_terms(self, idx: NDArray[np.int64], dcol: NDArray[np.int64]) -> NDArray[Any]:
        """Unit-correlator values of the M terms, ``u[n − ℓ_{d,m}, d, k]`` (complex when
        coherent, else ``w·|u|²``), shape ``(n, M, K)``."""
        n, m = idx.shape[0], self.m_hops
        first = (idx[:, None] - self.lags[dcol]).reshape(-1)
        u = self._exact_windows(first, np.repeat(dcol, m), 1)[:, 0, :].reshape(n, m, -1)
        w = None if self._tone_w is None else self._tone_w[dcol][:, None, :]
        if self.coherent:
            uc = u.astype(np.complex64)
            return uc if w is None else uc * w
        p = (np.square(u.real) + np.square(u.imag)).astype(np.float32)
        return p if w is None else p * w

    def _detect_two_stage(self, next_block: int) -> list[Estimate]:
        """Decide the coarse candidates whose look-ahead has arrived (blocks below
        ``next_block − lookahead``); exact codeword sums around each (stage 2)."""
        return self._decide_blocks(next_block - self._hc)

    @property
    def next_decision_index(self) -> int:
        """Input sample count (as :attr:`samples_seen`) the stream must reach before the next
        estimate can come out: :meth:`process` returns nothing while ``samples_seen`` stays
        below it (an unbroken stream; a gap flushes). A live loop may wait for that many
        samples instead of calling once per block: fewer, larger calls, the same estimates,
        emitted no later. The full search gives no such bound (``samples_seen``)."""
        if self.search != "two-stage":
            return self._samples_seen
        return max(self._decision_input(), self._samples_seen)

    def _decision_input(self) -> int:
        """:attr:`next_decision_index` from the coarse blocks completed so far.

        A candidate is a coarse peak (greater than the ``hc`` blocks before it, not smaller
        than the ``hc`` after), so the earliest block that can still become one is the first
        undecided block greater than its ``hc`` predecessors and not exceeded by a block
        already known after it (or the next block to come). It is decided once the ``hc``
        blocks after it are complete and its fine window (which ends ``c_shift`` of its
        hypotheses, at most ``max(c_shift)``, plus ``2·fine_half`` samples past its start)
        has arrived; baseband sample ``k`` exists once input sample ``k·R`` has.
        """
        next_block = self.coarse.next_block
        h = self._hc
        lo = self._det_next
        first = max(lo - h, self._c_origin)
        if next_block > lo:
            s = np.array(self._cs_ring.span(first, next_block), dtype=np.float64)
            s[: max(0, self._c_valid_from - first)] = -np.inf
            cand = first_possible_peak(s, h, lo - first, next_block - first) + first
        else:
            cand = max(lo, next_block)
        b = self._B
        # The fine window's shift depends on the block's hypotheses (known once it is seen).
        seen = cand < next_block
        shift = int(self._c_shift[self._hypotheses(np.array([cand]))].max()) if seen else None
        late = cand * b + (self._max_shift if shift is None else shift) + 2 * self.fine_half
        need_bb = max((cand + h + 1) * b - 1, late)
        return need_bb * self.baseband.decimation + 1

    def _decide_blocks(self, stop: int) -> list[Estimate]:
        """Stage 2 for the coarse candidates in blocks ``< stop``."""
        lo = self._det_next
        if stop <= lo:
            return []
        h = self._hc
        first = max(lo - h, self._c_origin)
        last = min(stop + h, self._cs_ring.next_index)
        s = np.array(self._cs_ring.span(first, last), dtype=np.float64)
        s[: max(0, self._c_valid_from - first)] = -np.inf
        cand_b = peak_indices(s, h, lo - first, stop - first) + first
        # A candidate waits until its fine window has arrived (its shift depends on d̂).
        shift = self._c_shift[self._hypotheses(cand_b)].max(axis=1)  # of d̂ and runner-up
        late = cand_b * self._B + shift + 2 * self.fine_half
        wait = np.flatnonzero(late >= self._y_ring.next_index)
        if wait.size:
            stop = int(cand_b[wait[0]])
            cand_b = cand_b[: wait[0]]
        self._det_next = stop
        if cand_b.size == 0:
            return []
        return self._fine_stage(cand_b)

    def _hypotheses(self, cand_b: NDArray[np.int64]) -> NDArray[np.int64]:
        """d̂ and the runner-up of coarse blocks ``cand_b`` (shape ``(C, 2)``; d̂ twice where
        no runner-up was found)."""
        pair: NDArray[np.int64] = self._cd_ring.rows(cand_b)
        pair[:, 1] = np.where(pair[:, 1] < 0, pair[:, 0], pair[:, 1])
        return pair

    def _fine_stage(self, cand_b: NDArray[np.int64]) -> list[Estimate]:
        """Stage 2: exact codeword sums around the coarse candidate blocks ``cand_b``.

        The sums come from :func:`~hil.estimation.kernels.codeword_sums`, everything between
        them from small compiled kernels (:func:`~hil.estimation.kernels.fine_pick`,
        ``fine_recentre``, ``fine_keep``, ``fine_doppler``): as NumPy it took some 60 small
        array calls per estimate, most of the call that emits it. (One kernel calling
        ``codeword_sums`` inside would save a few more calls but tripled the first
        compilation, to about 30 s.) :meth:`_fine_stage_reference` is the NumPy formulation;
        tests check that both give the same estimates, bit for bit.
        """
        w = self.fine_half
        pair = np.ascontiguousarray(self._hypotheses(cand_b), dtype=np.int64)
        centres = np.empty(pair.shape, dtype=np.int64)
        np.add(cand_b[:, None] * self._B, self._c_shift[pair], out=centres)
        a2 = self._fine_sums(centres, pair, w, prune=True)
        d0, centre, a, s_win, i_pk, edges = fine_pick(
            a2, pair, centres, self._hyp_w, w, RECENTRE_STEPS > 0
        )
        for it in range(RECENTRE_STEPS):
            if edges.size == 0:
                break
            sums = self._fine_sums(centre[edges], d0[edges, None], w)
            edges = fine_recentre(a, sums, edges, s_win, i_pk, centre, w, it + 1 < RECENTRE_STEPS)
        n_pk = centre - w + i_pk
        stat = self._cs_ring.rows(cand_b) if self.cfar_mode == "statistic" else None
        mean, thr, hit = self._cfar_test(n_pk, s_win[np.arange(cand_b.shape[0]), i_pk], stat)
        if hit.size == 0:
            return []
        keep, peak, word, ratio, dn, sides = fine_keep(
            hit, a, s_win, i_pk, d0, self.grid.size, w, float(self.runner_up_ratio)
        )
        if keep.size == 0:
            return []
        kept = hit[keep]
        side = self._fine_sums(n_pk[kept], sides, 0)
        dd = fine_doppler(side, a, kept, i_pk, word, d0, sides)
        values = zip(
            n_pk[kept].tolist(), peak.tolist(), word.tolist(), ratio.tolist(), dn.tolist(),
            d0[kept].tolist(), dd.tolist(), mean[kept].tolist(), thr[kept].tolist(),
            strict=True,
        )  # fmt: skip
        return self._decide_all(values)

    def _decide_all(self, values: Iterable[tuple[Any, ...]]) -> list[Estimate]:
        """:meth:`_decide` on each readout tuple, in order; the estimates it accepts."""
        out: list[Estimate] = []
        for args in values:
            est = self._decide(*args)
            if est is not None:
                out.append(est)
        return out

    def _fine_stage_reference(self, cand_b: NDArray[np.int64]) -> list[Estimate]:
        """:meth:`_fine_stage` as NumPy expressions (the reference the compiled path is
        tested against)."""
        pair = self._hypotheses(cand_b)  # (C, 2): d̂ and the runner-up
        centres = cand_b[:, None] * self._B + self._c_shift[pair]
        w = self.fine_half
        # The hypothesis is the better of the two by the exact sums: the group statistic
        # cannot tell a hypothesis from its ghost (every tone seen as its neighbour at another
        # speed), the codeword sums can.
        a2 = self._fine_sums(centres, pair, w, prune=True)  # (C, 2, 2w + 1, J)
        # Weighted as stage 1 ranks them (the reverberation band's weights); a hypothesis
        # pruned whole (−inf) cannot win, even at weight 0.
        best = a2.max(axis=(2, 3))
        score = np.where(np.isfinite(best), best * self._hyp_w[pair], -np.inf)
        pick = np.argmax(score, axis=1)
        r = np.arange(cand_b.shape[0])
        d0, centre, a = pair[r, pick], centres[r, pick], a2[r, pick]  # a: (C, 2w + 1, J)
        # A peak on the window's edge lies outside it (early in the stream the coarse comb
        # is not yet full): move the window onto that edge, a few times at most (later only
        # once: the look-ahead covers one window more; earlier is in the history).
        for it in range(RECENTRE_STEPS):
            ip = np.argmax(a.max(axis=2), axis=1)
            edge = np.flatnonzero((ip == 0) | ((ip == 2 * w) & (it == 0)))
            if edge.size == 0:
                break
            centre[edge] += ip[edge] - w
            a[edge] = self._fine_sums(centre[edge], d0[edge, None], w)[:, 0]
        dset = np.minimum(np.maximum(d0[:, None] + _NEIGHBOURS, 0), self.grid.size - 1)

        def sides(hit: NDArray[np.int64], n_pk: NDArray[np.int64]) -> NDArray[np.float64]:
            return self._fine_sums(n_pk, dset[hit][:, [0, 2]], 0)[:, :, 0]

        tested = self._cs_ring.rows(cand_b) if self.cfar_mode == "statistic" else None
        return self._threshold_readout(centre, w, dset, a, sides, tested)

    def _fine_sums(
        self, centre: NDArray[np.int64], dset: NDArray[np.int64], half: int, prune: bool = False
    ) -> NDArray[np.float64]:
        """Exact noncoherent ``A[n, d, j]`` for ``n`` within ``±half`` of ``centre`` (shape
        ``(C,)``, or ``(C, nd)``: one per hypothesis) at the hypotheses ``dset`` (shape
        ``(C, nd)``): shape ``(C, nd, 2·half + 1, J)``
        (:func:`hil.estimation.kernels.codeword_sums`; with ``prune``, rows that cannot hold a
        maximum are −inf)."""
        ring = self._y_ring
        width = 2 * half + 1
        out = np.empty((centre.shape[0], dset.shape[1], width, self.n_codewords))
        # A fresh writable array every time: a read-only view (what broadcasting gives when
        # no copy is needed) is another numba signature, loaded mid-stream on first use.
        centres = np.empty(dset.shape, dtype=np.int64)
        centres[...] = centre.reshape(dset.shape[0], -1)
        codeword_sums(
            ring.array[: ring.available], ring.next_index - ring.available, ring.next_index,
            centres,
            np.ascontiguousarray(dset, dtype=np.int64), half, self.lags, self.grid.lengths,
            self._phasor_table(EXACT_ANCHOR), self._term_tone, self._cell_w, EXACT_ANCHOR,
            self._cache_p, self._cache_max, self._cache_n, self._B, self._hyp_w, prune, out,
        )  # fmt: skip
        return out

    def _sums(
        self, idx: NDArray[np.int64], dcol: NDArray[np.int64], coherent: bool = False
    ) -> NDArray[np.float32]:
        """``A[n, d_n, j]`` for samples ``idx`` (shape ``(n,)``) at hypotheses ``dcol``;
        noncoherent unless ``coherent`` (which needs the complex history of ``coherent=True``).
        """
        n = idx.shape[0]
        if self.search == "two-stage":
            terms_all = self._exact_terms(idx, dcol)  # (n, M, K)
        else:
            pos = self._u_ring.position(idx[:, None] - self.lags[dcol])  # (n, M)
            terms_all = self._u_ring.array[pos, dcol[:, None], :]
        if not coherent:
            # Gather term m of every codeword j directly (tone c_{j−m}), then a sum over the
            # middle axis (sequential adds, not BLAS): each row's value does not depend on
            # how many rows are computed together.
            v = terms_all.reshape(n, -1)  # (n, M·K)
            terms = np.take(v, self._term_cell, axis=1)  # (n, M, J)
            if self.coherent:
                terms = np.square(terms.real) + np.square(terms.imag)
            out: NDArray[np.float32] = terms.sum(axis=1)  # (n, J)
            return out
        v = terms_all  # (n, M, K)
        t = self.baseband.time_of(idx)
        cyc = np.mod(self._fa[dcol] * t[:, None], 1.0) + self._coh_const[dcol]
        rot = np.exp(2j * np.pi * cyc).astype(np.complex64)  # (n, K)
        z = ((v * rot[:, None, :]).reshape(n, -1, 1) * self._w_coh[None]).sum(axis=1)
        res: NDArray[np.float32] = (np.square(z.real) + np.square(z.imag)).astype(np.float32)
        return res

    def _noise_floor(
        self, power: NDArray[np.float32], idx: NDArray[np.int64], a0: int
    ) -> NDArray[np.float64]:
        """μ_U estimate on the absolute grid of :data:`NOISE_STRIDE` samples; NaN elsewhere.

        ``power`` is ``|u|²`` with samples last, shape ``(D, K, n)``; ``idx`` the sample
        indices ``a0 ..``."""
        out = np.full(idx.shape[0], np.nan)
        on = np.flatnonzero(idx % NOISE_STRIDE == 0)
        if on.size:
            # One contiguous row of D·K cells per sample: the median partitions along rows.
            flat = np.ascontiguousarray(power[:, :, on].reshape(-1, on.size).T)
            out[on] = np.median(flat, axis=1) / math.log(2.0)
        return out

    # ------------------------------------------------------------------ detection
    def _detect(self, stop: int) -> list[Estimate]:
        """Decide the candidates ``< stop`` (their ±N_min/2 look-ahead has arrived)."""
        lo = self._det_next
        if stop <= lo:
            return []
        h = self.half_width
        first = max(lo - h, self._origin)
        last = min(stop + h, self._s_ring.next_index)
        s = np.array(self._s_ring.span(first, last), dtype=np.float64)
        s[: max(0, self._valid_from - first)] = -np.inf
        cand = peak_indices(s, h, lo - first, stop - first) + first
        self._det_next = stop
        if cand.size == 0:
            return []
        # Exact codeword sums A[n, d, j] for every candidate at once: n within ±W of the
        # candidate, d at the chosen hypothesis and its two neighbours.
        w = self.search_half
        offs = np.arange(-w, w + 1, dtype=np.int64)
        d0 = self._dhat_ring.rows(cand)
        dset = np.clip(d0[:, None] + np.arange(-1, 2)[None, :], 0, self.grid.size - 1)
        n_idx = np.broadcast_to(
            cand[:, None, None] + offs[None, :, None], (*cand.shape, 2 * w + 1, 3)
        )
        d_idx = np.broadcast_to(dset[:, None, :], n_idx.shape)
        a = self._sums(n_idx.reshape(-1), d_idx.reshape(-1)).reshape(*n_idx.shape, -1)

        def sides(hit: NDArray[np.int64], n_pk: NDArray[np.int64]) -> NDArray[np.float32]:
            side: NDArray[np.float32] = a[hit, n_pk - cand[hit] + w][:, [0, 2], :]
            return side

        tested = self._s_ring.rows(cand) if self.cfar_mode == "statistic" else None
        return self._threshold_readout(cand, w, dset, a[:, :, 1, :], sides, tested)

    def _cfar_test(
        self,
        n_pk: NDArray[np.int64],
        peak: NDArray[np.floating[Any]],
        stat_tested: NDArray[np.float64] | None,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
        """The CFAR test of candidates peaking at samples ``n_pk`` (shape ``(C,)``): the
        noise mean and threshold per candidate and the indices of those over it. ``"bank"``
        tests the codeword-sum ``peak``; ``"statistic"`` tests ``stat_tested``, the group
        statistic at the candidates."""
        if self.cfar_mode == "bank":
            mean, std = self._bank_moments(n_pk)
            tested = np.asarray(peak, dtype=np.float64)
        else:
            ms = [self._statistic_moments(int(v)) for v in n_pk.tolist()]
            mean, std = np.array([v[0] for v in ms]), np.array([v[1] for v in ms])
            assert stat_tested is not None
            tested = stat_tested
        thr = mean + self.cfar_lambda * std
        return mean, thr, np.flatnonzero(tested > thr)

    def _threshold_readout(
        self,
        cand: NDArray[np.int64],
        w: int,
        dset: NDArray[np.int64],
        a: NDArray[np.floating[Any]],
        sides: Callable[[NDArray[np.int64], NDArray[np.int64]], NDArray[np.floating[Any]]],
        stat_tested: NDArray[np.float64] | None,
    ) -> list[Estimate]:
        """Threshold test and readout of candidates centred on samples ``cand`` (shape
        ``(C,)``): ``a`` holds ``A[n, d, j]`` at the chosen hypothesis (middle of ``dset``,
        shape ``(C, 3)``) for ``n`` within ``±w``, shape ``(C, 2w + 1, J)``;
        ``sides(hit, n)`` gives ``A`` at the two neighbouring hypotheses at samples ``n`` of
        candidates ``hit`` (shape ``(H, 2, J)``); ``stat_tested`` the group statistic at the
        candidates (``"statistic"`` CFAR)."""
        # Threshold test for all candidates at once; only the survivors are read out.
        s_win = a.max(axis=2)  # (C, 2W + 1)
        i_pk = np.argmax(s_win, axis=1)
        n_pk = cand - w + i_pk
        peak_all = s_win[np.arange(cand.shape[0]), i_pk].astype(np.float64)
        mean, thr, hit = self._cfar_test(n_pk, peak_all, stat_tested)
        if hit.size == 0:
            return []
        # Readout quantities of every survivor at once (per-candidate numpy calls would
        # dominate the cost): peak sample, codeword, runner-up ratio, time and Doppler offsets.
        ip = i_pk[hit]
        sw = s_win[hit].astype(np.float64)
        r = np.arange(hit.size)
        peak = sw[r, ip]
        rows = a[hit, ip].astype(np.float64)  # (H, J)
        jh = np.argmax(rows, axis=1)
        runner = np.partition(rows, -2, axis=1)[:, -2] if rows.shape[1] > 1 else np.zeros(r.size)
        ratio = np.full(r.size, np.inf)
        np.divide(peak, runner, out=ratio, where=runner > 0)
        keep = np.flatnonzero(ratio >= self.runner_up_ratio)
        if keep.size == 0:
            return []
        inner = (ip > 0) & (ip < 2 * w)
        dn = np.where(
            inner,
            parabolic_offsets(sw[r, np.maximum(ip - 1, 0)], peak, sw[r, np.minimum(ip + 1, 2 * w)]),
            0.0,
        )
        dh = dset[hit]
        side = sides(hit[keep], n_pk[hit[keep]]).astype(np.float64)  # (H', 2, J)
        jk = jh[keep]
        rk = np.arange(keep.size)
        d_in = (dh[keep, 0] != dh[keep, 1]) & (dh[keep, 2] != dh[keep, 1])
        dd = np.where(
            d_in, parabolic_offsets(side[rk, 0, jk], rows[keep, jk], side[rk, 1, jk]), 0.0
        )
        n_star = (cand[hit] - w + ip)[keep].tolist()
        values = zip(
            n_star, peak[keep].tolist(), jk.tolist(), ratio[keep].tolist(), dn[keep].tolist(),
            dh[keep, 1].tolist(), dd.tolist(), mean[hit[keep]].tolist(), thr[hit[keep]].tolist(),
            strict=True,
        )  # fmt: skip
        return self._decide_all(values)

    def _bank_moments(
        self, n_pk: NDArray[np.int64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Noise mean and std of the codeword sum at samples ``n_pk`` (shape ``(C,)``): the
        noise-floor estimates μ_U over the trailing CFAR window times the noise moments."""
        ring, origin = self._noise_ring, self._origin
        lo = np.maximum(n_pk - self._cfar_window, self._origin + self._n_max)
        if self.search == "two-stage":
            # Coarse noise floor, on blocks; the peak's block may not be complete yet.
            ring, origin = self._cn_ring, self._c_origin
            n_pk = np.minimum(n_pk // self._B, ring.next_index - 1)
            lo = np.minimum(np.maximum(lo // self._B, origin), n_pk)
        # One fixed-length row per candidate, summed along the row: each window's sum is then
        # independent of the other candidates decided with it (chunking cannot change a bit).
        width = self._cfar_window + 1
        if self.search == "two-stage":
            width = self._cfar_window // self._B + 2
        idx = lo[:, None] + np.arange(width)
        inside = idx <= n_pk[:, None]
        vals = ring.rows(np.where(inside, idx, n_pk[:, None]))
        ok = inside & np.isfinite(vals)
        n_ok = ok.sum(axis=1)
        total = np.where(ok, vals, 0.0).sum(axis=1)
        mu_u = np.where(n_ok > 0, total / np.maximum(n_ok, 1), np.inf)
        mean, std = self._moments
        return mean * mu_u, std * mu_u

    def _statistic_moments(self, n_star: int) -> tuple[float, float]:
        """``"statistic"`` CFAR: median and MAD-based std of the group statistic over the
        trailing window that ends one hop before ``n_star``."""
        w = self._cfar_window
        guard = self._n_max
        ring, valid = self._s_ring, self._valid_from
        if self.search == "two-stage":
            ring, valid = self._cs_ring, self._c_valid_from
            w, guard, n_star = w // self._B, -(-guard // self._B), n_star // self._B
        lo = max(n_star - guard - w, valid)
        hi = n_star - guard
        if hi - lo < 8:
            return math.inf, 0.0
        vals = np.asarray(ring.span(lo, hi))
        med = float(np.median(vals))
        return med, 1.4826 * float(np.median(np.abs(vals - med)))

    def _decide(
        self, n_star: int, peak: float, j_hat: int, ratio: float, dn: float, d0: int,
        dd: float, mean: float, thr: float,
    ) -> Estimate | None:  # fmt: skip
        """Readout of one candidate that passed the threshold ``thr`` (noise mean ``mean``)
        and the runner-up test: peak sample ``n_star`` (baseband index) with sub-sample offset
        ``dn``, statistic ``peak``, codeword ``j_hat`` (best over runner-up ``ratio``),
        hypothesis ``d0`` with offset ``dd`` (grid steps)."""
        if self.refused_hypotheses[d0]:
            self.in_band_count += 1
            return None
        c = self.sound_speed_mps
        k = self._readout_constants
        speed = k.speeds[d0] + dd * k.speed_step
        alpha = (c + speed) / (c - speed)  # speed_to_alpha, on Python floats
        exact_len = k.hop_samples / alpha
        t_rx = ((n_star + dn) * k.decimation - k.group_delay) / k.fs_in + (
            exact_len - k.lengths[d0] + 1
        ) / (2.0 * self.fs_bb)
        # Transmit time: end of hop ĵ, folded by whole code periods into [0, τ_max].
        period = k.period
        end_j = k.hop_end[j_hat]
        tol = 2.0 / self.fs_bb
        q = math.floor((t_rx - end_j + tol) / period)
        t_tx = end_j + q * period
        if self.coherent:
            t_rx, alpha = self._coherent_refine(
                n_star, d0, j_hat + q * self.n_codewords, t_rx, alpha
            )
        if self._first_arrival is not None:
            t_first = self._first_arrival.first_arrival(t_rx, alpha, j_hat + q * self.n_codewords)
            if t_first is not None:
                t_rx = t_first
        delay = t_rx - t_tx
        if delay > 2.0 * self.max_range_m / c + tol:
            self.refused_count += 1
            return None
        hop_index = j_hat + q * self.n_codewords
        consistent: bool | None = None
        if self._last_hop is not None:
            expected = round((t_rx - self._last_t) * alpha / self.hop_s)
            consistent = hop_index - self._last_hop == expected
            if not consistent:
                self.inconsistent_count += 1
        self._last_hop, self._last_t = hop_index, t_rx
        self.last_detection = DetectionInfo(n_star, thr, mean, ratio, consistent)
        snr = (peak - mean) / mean if mean > 0 and math.isfinite(mean) else math.inf
        return Estimate(
            t_s=t_rx,
            range_m=c * delay / 2.0,
            speed_mps=c * (alpha - 1.0) / (alpha + 1.0),  # alpha_to_speed, on Python floats
            hop_index=int(hop_index),
            score=peak / thr if thr > 0 else math.inf,
            snr_db=10.0 * math.log10(snr) if snr > 0 else -math.inf,
            alpha=alpha,
            t_tx_s=t_tx,
            codeword=j_hat,
            receiver=self.name,
        )

    def _coherent_refine(
        self, n_star: int, d0: int, hop_end: int, t_guess: float, alpha_guess: float
    ) -> tuple[float, float]:
        """Coherent readout: the boundary time (s) and α maximising the coherent sum.

        ``hop_end`` is the global index of the hop whose end boundary was detected; the M
        terms are hops ``hop_end − m``, their unit-correlator values those of the detected
        sample ``n*`` at hypothesis ``d0`` (lags ``ℓ_{d0,m}``). A window that covers echo hop
        ``i`` (tone ``f``, start ``t_i``, start phase ``φ_i``) of ``a·s(α(t − τ0))`` gives

            arg u_i = φ_i − 2π f (α τ0 + t_i) − 2π ν_d g + 2π (α − α_d) f c_i,

        ``ν_d = α_d f − f_c``, ``g`` the filter group delay (s), ``c_i = τ0 + (t_i + T_h/2)/α``
        the centre of the received hop (the last term is the residual rotation of a
        correlator listening at ``α_d ≠ α``; the phase does not depend on where the window
        sits within ±a few samples of the hop, only its magnitude does). The sum
        ``|Σ_m u_m e^{−j arg u_m(τ0, α)}|²`` is evaluated on a fine grid of candidate
        ``(τ0, α)`` around the noncoherent estimate (±½ grating lobe ``1/(α Δf)`` in time,
        ±1 Doppler grid step) and refined by parabolas; its time resolution is ``~1/B_w``.
        """
        m = self.m_hops
        hops = self.schedule.hops(hop_end - m + 1, m)
        order = np.arange(m - 1, -1, -1)  # term m is hop hop_end − m
        tone = hops.tone_index[order]
        f = self.tones_hz[tone]
        t_i = hops.start_s[order]
        phi = hops.phase_rad[order]
        if self.search == "two-stage":
            first = n_star - self.lags[d0]
            u = self._exact_windows(first, np.full(m, d0, dtype=np.int64), 1)[:, 0, :]
            v = u[np.arange(m), tone]
            if self._tone_w is not None:
                v = v * self._tone_w[d0, tone]
        else:
            pos = self._u_ring.position(n_star - self.lags[d0])
            v = self._u_ring.array[pos, d0, tone].astype(np.complex128)  # (M,)
        a_d = float(self.grid.alphas[d0])
        g = self.baseband.group_delay / self.fs_hz
        nu = a_d * f - self.center_hz
        c = self.sound_speed_mps
        t_end = float(hops.start_s[-1]) + self.hop_s
        base = phi / (2.0 * np.pi) - np.mod(f * t_i, 1.0) - nu * g  # cycles, (M,)
        mid = t_i + 0.5 * self.hop_s

        def power(speeds: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
            """|coherent sum|² on the grid speeds (m/s) × boundary times b (s)."""
            al = np.asarray(speed_to_alpha(speeds, c))[:, None, None]
            tau0 = b[None, :, None] - t_end / al
            cyc = base - f * al * tau0 + (al - a_d) * f * (tau0 + mid / al)
            result: NDArray[np.float64] = np.abs(np.exp(-2j * np.pi * cyc) @ v) ** 2
            return result

        df = float(np.min(np.diff(np.sort(self.tones_hz)))) if self.n_tones > 1 else 1 / self.hop_s
        # Pass 1: ±½ grating lobe in time, ±1 Doppler step; pass 2: a finer grid around the
        # best cell (the range–Doppler ridge is tilted, so one coarse pass leaves a bias).
        speed = float(alpha_to_speed(alpha_guess, c))
        t_rx = t_guess
        for half_t, half_v, nb in (
            (0.5 / (df * alpha_guess), self.grid.speed_step_mps, 81),
            (0.1 / (df * alpha_guess), 0.25 * self.grid.speed_step_mps, 41),
        ):
            speeds = speed + np.linspace(-half_v, half_v, 9)
            b = t_rx + np.linspace(-half_t, half_t, nb)
            z = power(speeds, b)
            ia, ib = np.unravel_index(int(np.argmax(z)), z.shape)
            ob = oa = 0.0
            if 0 < ib < nb - 1:
                ob = parabolic_offset(float(z[ia, ib - 1]), float(z[ia, ib]), float(z[ia, ib + 1]))
            if 0 < ia < 8:
                oa = parabolic_offset(float(z[ia - 1, ib]), float(z[ia, ib]), float(z[ia + 1, ib]))
            t_rx = float(b[ib]) + ob * float(b[1] - b[0])
            speed = float(speeds[ia]) + oa * float(speeds[1] - speeds[0])
        return float(t_rx), float(speed_to_alpha(speed, c))

    # ------------------------------------------------------------------ diagnostics
    def accumulated_sums(self, count: int) -> tuple[NDArray[np.float64], NDArray[np.float32]]:
        """The full ``A[n, d, j]`` for the last ``count`` baseband samples (diagnostics).

        Returns times (s, shape ``(count,)``) and ``A`` (shape ``(count, D, J)``), computed
        from the retained unit-correlator history; ``count`` is limited to the samples since
        the last restart.
        """
        ring = self._y_ring if self.search == "two-stage" else self._u_ring
        stop = ring.next_index
        extra = self._n_max if self.search == "two-stage" else 0
        count = int(min(count, stop - self._origin, ring.available - self.lags.max() - 1 - extra))
        idx = np.arange(stop - count, stop, dtype=np.int64)
        full = np.stack(
            [
                self._sums(idx, np.full(count, d, dtype=np.int64), self.coherent)
                for d in range(self.grid.size)
            ],
            axis=1,
        )
        return self.baseband.time_of(idx), full


def _comb(
    grp: NDArray[np.float64],
    a0: int,
    g_ring: RowBuffer,
    acc_ring: RowBuffer,
    lengths: NDArray[np.int64],
    m_hops: int,
) -> NDArray[np.float64]:
    """Comb accumulation ``Acc_d[n] = Acc_d[n − N_d] + G_d[n] − G_d[n − M N_d]`` of the new
    rows ``grp`` (shape ``(n, D)``, first index ``a0``) with the histories of ``G`` and ``Acc``
    in ``g_ring`` and ``acc_ring``; ``lengths`` is ``N_d`` (shape ``(D,)``) in ring rows."""
    n, d = grp.shape
    cols = np.arange(d)
    idx = a0 + np.arange(n, dtype=np.int64)
    # Flat take() of G_d[n − M N_d]: cheaper than 2-D fancy indexing.
    flat = g_ring.position(idx[:, None] - (m_hops * lengths)[None, :]) * d + cols
    g_old = np.take(g_ring.array.reshape(-1), flat)
    x = grp - g_old
    # Every N_d >= N_min, so the N_min samples of one step depend only on earlier steps:
    # all hypotheses advance together, one step of the recursion per numpy call.
    h = int(lengths.max())
    work = np.empty((h + n, d))
    work[:h] = acc_ring.span(a0 - h, a0)
    flat_work = work.reshape(-1)
    back = (h - lengths[None, :]) * d + cols  # flat offset of Acc_d[n − N_d]
    step = int(lengths.min())
    for s in range(0, n, step):
        e = min(s + step, n)
        src = np.take(flat_work, back + d * np.arange(s, e)[:, None])
        np.add(src, x[s:e], out=work[h + s : h + e])
    return work[h:]
