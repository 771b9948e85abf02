"""GCAS readout (SPEC §3 step 7): a detected peak becomes an :class:`Estimate`.

Parabolic offsets of the peak in time and across ``d`` give the boundary receive time
``t_rx`` (window centred on the hop, group delay removed) and ``α̂``; ``t_tx`` is the transmit
end of hop ``ĵ`` plus the multiple of the code period that puts the delay in ``[0, τ_max]``,
``τ_max = 2 max_range/c`` (a longer delay, or a negative one, is refused and counted);
``R = c (t_rx − t_tx)/2``, ``v = c (α̂ − 1)/(α̂ + 1)``. A peak on a refused hypothesis (the
edge of the reverberation band, :mod:`hil.estimation.reverb_band`) is the leak of an echo
inside the band, not a detection: it is noted, and that echo is measured when another
detection comes near it (:mod:`hil.estimation.gcas.hidden_echoes`: what it leaks is then
refused). The default
refinement (:mod:`hil.estimation.refine`) measures ``t_rx`` and ``α`` by local maximum
likelihood and refuses a detection that is not one echo of the schedule (a still echo read
at the tone spacing's speed, an echo beyond the span: :data:`ECHO_TEST`; in the still
reverberation's Doppler cells, with the band off, against the interference measured on the
other tones of its windows where a point echo was confirmed lately
(:mod:`hil.estimation.gcas.point_echoes`), and a diffuse fit there is counted as clutter:
:mod:`hil.estimation.reverb_band`); without it the coherent sum refines ``t_rx`` and ``α̂``.
The first-arrival readout (:mod:`hil.estimation.first_arrival`) replaces ``t_rx`` by the
direct path's. Hop-index consistency is a soft flag.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from hil.estimation.base import Estimate
from hil.estimation.crlb import Crlb
from hil.estimation.detection import parabolic_offset
from hil.estimation.doppler_grid import alpha_to_speed, speed_to_alpha
from hil.estimation.first_arrival import FirstArrivalReadout
from hil.estimation.gcas.beyond_span import BeyondSpan, BeyondSpanCheck
from hil.estimation.gcas.candidates import new_pair_rows, second_echo_rows
from hil.estimation.gcas.clutter_seen import ClutterLog, ClutterSeen
from hil.estimation.gcas.front_end import FrontEnd
from hil.estimation.gcas.ghost_inside import InsideSources
from hil.estimation.gcas.hidden_echoes import HiddenEchoes
from hil.estimation.gcas.point_echoes import PointEchoes
from hil.estimation.gcas.residual import STEP_HOPS
from hil.estimation.gcas.threshold import Peak
from hil.estimation.refine import CoherentRefiner, EchoTest, Refinement
from hil.estimation.reverb_band import (
    doppler_resolution_mps,
    is_diffuse,
    reverberation_coherence,
)

#: A refined detection is an echo of the schedule when its hops' coherence is at least
#: COHERENCE_FRACTION of what one echo of its SNR would have, or their coherence over runs of
#: 3 consecutive hops at least RUN_COHERENCE_FRACTION of it (:meth:`Refinement.is_echo
#: <hil.estimation.refine.Refinement.is_echo>`), and it collects MIN_ECHO_SNR_DB. Measured on
#: att (0.8-1 s, 55-90 detections each): echoes 0.99-1.01 at -10 dB per-sample SNR; a still
#: echo at the tone spacing's speed 0.03-0.49 at 0 dB and up to 0.86 at -10 dB; a 35 m/s
#: target with a 30 m/s span 0.03-0.58. Over runs (an accelerating echo drifts in phase
#: against the constant-speed fit): 0.93-0.95 for a target braking at 5 m/s², 0.85+ at
#: 7 m/s² (kept), 0.62-0.81 at 10 m/s² (refused: the constant-speed fit over M hops no longer
#: holds); still-echo ghosts and aliases p90 0.55-0.69. The coherence within each tone is not
#: a test: ghosts of a still echo read 0.98-1.04 of one echo's there. MIN_ECHO_SNR_DB: the
#: E/N0 over the M hops a fit must collect once the other echoes measured lately are taken out
#: (:mod:`hil.estimation.refine`): the leak of a stronger echo into its ghost's or
#: sidelobe's cells then collects what noise does, 6.7-10.6 dB (att, two echoes 10 dB apart
#: at 0 dB and -10 dB per-sample SNR, 410 such fits); one echo at -20 dB per-sample SNR
#: collects about 16 dB over M = 10 hops.
COHERENCE_FRACTION = 0.8
RUN_COHERENCE_FRACTION = 0.85
MIN_ECHO_SNR_DB = 12.0
ECHO_TEST = EchoTest(COHERENCE_FRACTION, RUN_COHERENCE_FRACTION, MIN_ECHO_SNR_DB)
#: A detection of the first search beside echoes measured lately, off the span's edges, whose
#: reading with them taken out (:meth:`~hil.estimation.refine.CoherentRefiner.
#: left_beside_known`) is more than LEFT_MARGIN_DB below MIN_ECHO_SNR_DB is refused as not one
#: echo without a fit: a fit collects at most a few dB more than the reading (5.9 dB at most
#: on att, bench_gcas's input, M = 5, 10 and 29). Such detections lie on the ridge of the echo
#: beside them, some half a hop off its boundary and three Doppler cells of a hop off its
#: speed: on that input, 329 of 430, 378 of 420 and 142 of 145 full searches at M = 5, 10 and
#: 29, each refused after the search, whose fits collected 11.2 dB at most.
LEFT_MARGIN_DB = 3.0
#: An echo measured lately whose next boundary no detection brought is fitted where its fit
#: puts it once the peaks decided have passed that boundary by this many hops
#: (:meth:`Readout._follow`): peaks are decided in the order of their candidates' blocks,
#: within a fine window of them, so a detection of that boundary comes before.
FOLLOW_LAG_HOPS = 1.0
#: A followed boundary's fit that collects more than this much less E/N0 than the echo's
#: latest fit is not that echo (:meth:`Readout._follow`): consecutive fits of one echo share
#: M - 1 of their M hops (at -20 dB per-sample SNR, M = 10, an echo's fits collect 16.6-18.6
#: dB, 10th-90th percentile). Where a detection was fitted on a speed sidelobe beside a
#: strong echo and remembered as a second echo, its followed fit with the true echo taken out
#: collects what that echo's residue leaves (Fig 6.4, M = 5, -5 dB, one trial: 28.0 then
#: 13.9 dB, reported 0.92 m short beside the true echo's own boundary).
FOLLOW_DROP_DB = 6.0

#: Grid steps the detector-only readout moves its Doppler parabola onto the largest of the
#: sums measured on common tones (:meth:`Readout._doppler_offset`): the search's hypothesis
#: is at most one step off beside masked cells.
DOPPLER_MOVES = 2

#: ``unit_values(n_star, d0, tone)``: the M terms' unit correlators of the peak at sample
#: ``n_star``, hypothesis ``d0``, tone index per term (shape ``(M,)``), weighted, complex.
UnitValues = Callable[[int, int, NDArray[np.int64]], NDArray[np.complex128]]


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


@dataclass(frozen=True)
class _ReadoutConstants:
    """Per-receiver constants of :meth:`Readout.decide` as Python numbers (the readout runs
    once per detection; NumPy scalars there cost more than the arithmetic)."""

    speeds: list[float]
    speed_step: float
    lengths: list[int]
    hop_samples: float
    decimation: int
    group_delay: float
    fs_in: float
    period: float
    hop_end: list[float]

    @classmethod
    def of(cls, fe: FrontEnd) -> _ReadoutConstants:
        sch = fe.schedule
        return cls(
            speeds=fe.grid.speeds_mps.tolist(),
            speed_step=fe.grid.speed_step_mps,
            lengths=fe.grid.lengths.tolist(),
            hop_samples=fe.hop_s * fe.fs_bb,
            decimation=fe.baseband.decimation,
            group_delay=fe.baseband.group_delay,
            fs_in=fe.baseband.fs_hz,
            period=sch.period_s,
            hop_end=(sch.t0_s + (sch.start_s + sch.duration_s)).astype(np.float64).tolist(),
        )


class Readout:
    """Turns peaks into estimates and keeps the counts of those it refuses.

    ``unit_values`` reads the unit correlators of the search in use (coherent refinement);
    ``first_arrival`` is the multipath readout, or None for the peak.
    """

    def __init__(
        self,
        fe: FrontEnd,
        *,
        max_range_m: float,
        coherent: bool,
        first_arrival: FirstArrivalReadout | None,
        unit_values: UnitValues,
        refiner: CoherentRefiner | None,
        receiver: str,
        beyond_span: BeyondSpanCheck | None = None,
    ) -> None:
        self._fe = fe
        self._k = _ReadoutConstants.of(fe)
        self._max_delay = 2.0 * max_range_m / fe.sound_speed_mps
        self._coherent = coherent
        self._first_arrival = first_arrival
        self._unit_values = unit_values
        #: Each codeword's term tones (term m is hop codeword − m), shape (M,), made once.
        self._term_tones: dict[int, NDArray[np.int64]] = {}
        self._refiner = refiner
        self._receiver = receiver
        #: The check for an echo beyond the Doppler span (with the refinement).
        self.beyond_span = beyond_span
        #: The echoes the reverberation band hides, measured where what they leak is near
        #: (with the refinement: :mod:`hil.estimation.gcas.hidden_echoes`).
        self.hidden = None if refiner is None else HiddenEchoes(refiner, fe.hop_s)
        #: Where clutter was refused (:mod:`hil.estimation.gcas.clutter_seen`).
        self.clutter_seen = ClutterLog()
        tones, c = np.asarray(fe.tones_hz, dtype=np.float64), fe.sound_speed_mps
        span_hz = float(np.ptp(tones)) if tones.size > 1 else 1.0 / fe.hop_s
        #: One echo's resolution cell: the likelihood's main lobe in time (``1/B``, s) and
        #: the M-hop fit's Doppler resolution (m/s).
        self._lobe_s = 1.0 / span_hz
        self._cell_mps = doppler_resolution_mps(tones, fe.hop_s, c) / fe.m_hops
        #: Speeds below this share their Doppler cells with the still reverberation, m/s
        #: (:func:`~hil.estimation.reverb_band.in_reverberation`'s bound, made once).
        self._still_mps = doppler_resolution_mps(tones, fe.hop_s, c)
        #: A boundary's speed one hop's Doppler resolution beyond the reverberation band
        #: (m/s): out of the band whatever the window's other hops are.
        self._out_of_band_mps = fe.reverb_speed_mps + self._still_mps
        #: The undetected echo inside the span whose ghost an echo's fit may be (with the
        #: beyond-span check, whose geometry it shares: :mod:`hil.estimation.gcas.ghost_inside`).
        self.inside_sources = (
            None
            if beyond_span is None
            else InsideSources(beyond_span.ghosts, ECHO_TEST, self._still_mps)
        )
        #: How far (s of receive time) the second search's detections lie behind the first's
        #: at most: its start-up's ``M + 1`` hops, a stretch and a hop of decision
        #: (:mod:`hil.estimation.gcas.residual`); an estimate is kept that long to tell a
        #: repeat of it (:meth:`_reported_already`).
        self._residual_lag_s = (fe.m_hops + 3 + STEP_HOPS) * fe.hop_s
        #: Hypotheses where a refused fit may be one of two echoes at one speed
        #: (:func:`~hil.estimation.gcas.candidates.second_echo_rows`): not at the band's or the
        #: span's edges, where the leaks of other echoes fit as well with a partner taken out.
        self._pair_rows = second_echo_rows(fe)
        #: Hypotheses where a refused fit is first tried as two echoes of one speed
        #: (:func:`~hil.estimation.gcas.candidates.new_pair_rows`).
        self._new_pair_rows = new_pair_rows(fe)
        #: The point echoes confirmed lately in the still reverberation's cells.
        self.point_echoes = PointEchoes(
            fe.hop_s, fe.schedule.period_hops, self._lobe_s, self._cell_mps, c
        )
        self.reset()

    def reset(self) -> None:
        """Zero the counts and forget the previous detection."""
        self.restart()
        self.inconsistent_count = 0
        self.refused_count = 0
        #: Detections refused as the edge leak of an echo inside the reverberation band.
        self.in_band_count = 0
        #: Detections refused by the refinement as no one echo of the schedule
        #: (:data:`COHERENCE_FRACTION`).
        self.incoherent_count = 0
        #: Detections refused as clutter: diffuse reverberation in the echo's Doppler cells,
        #: not one point echo (:func:`~hil.estimation.reverb_band.is_diffuse`).
        self.clutter_count = 0
        #: Detections the refinement could not measure: their hops reach back before the
        #: input's start or a gap (refused: the search reports every echo's cell, ghosts
        #: included, and only the refinement tells them apart).
        self.unmeasured_count = 0
        #: Detections of an echo already reported at the same boundary (two peaks of one
        #: echo, both refined onto it): the first is kept.
        self.same_echo_count = 0
        #: Detections whose echo ended within their window: its last hops hold none
        #: (:attr:`~hil.estimation.refine.Refinement.ended`); the echo is not there at
        #: their boundary.
        self.ended_count = 0
        #: Estimates of echoes measured lately fitted where their fits put their next
        #: boundary, without a detection there (:meth:`_follow`).
        self.followed_count = 0
        #: Estimates of detections in the input with the echoes measured lately taken out
        #: (:mod:`hil.estimation.gcas.residual`).
        self.residual_count = 0
        #: Detections there dropped unrefined: what was left of a measured echo, in the
        #: still reverberation's Doppler cells (what the echoes measured there hid is the
        #: reverberation itself), or where no echo taken out could hide one
        #: (:meth:`~hil.estimation.refine.CoherentRefiner.hidden_by_known`).
        self.leftover_count = 0
        #: The second echo's estimate of the peak being decided, where its fit was a
        #: resolved pair (:meth:`decide_all` reports it after the first).
        self._second: Estimate | None = None
        #: The estimates reported lately: (hop index, boundary time s, speed m/s).
        self._reported: list[tuple[int, float, float]] = []
        self.last_detection: DetectionInfo | None = None
        if self.beyond_span is not None:
            self.beyond_span.reset()
        if self.inside_sources is not None:
            self.inside_sources.reset()
        self.clutter_seen.reset()
        self.point_echoes.reset()
        #: What the receiver says of what it refused (beyond the span, clutter), in the
        #: order seen.
        self.notices: list[BeyondSpan | ClutterSeen] = []

    def restart(self) -> None:
        """Forget the previous hop (a gap: consistency restarts with the next detection, and
        the hidden echoes noted before it are forgotten with the refinement's input)."""
        self._last_hop: int | None = None
        self._last_t = 0.0
        if self.hidden is not None:
            self.hidden.reset()

    def decide_all(self, peaks: Iterable[Peak], residual: bool = False) -> list[Estimate]:
        """:meth:`decide` on each peak, in order; the estimates it accepts. A peak
        ``beside`` the one before it (its window's second codeword, two still echoes at once:
        :mod:`hil.estimation.gcas.still_codewords`) is decided only where that one was
        refused: beside a still echo reported, the other is the one the stage-1 search masks
        by turns (a still target and a lone still scatterer a few milliseconds apart), and
        deciding it would report every still scatterer beside every still target. A second
        echo of one speed (:attr:`~hil.estimation.gcas.threshold.Peak.second`: a moving
        window's second codeword, a row's second maximum) is decided whatever became of the
        one before it, where :meth:`decide` finds a partner or two echoes at its speed.

        With the refinement, before each peak the echoes measured lately whose next boundary
        the peaks have passed by :data:`FOLLOW_LAG_HOPS` without a fit there are fitted where
        their fits put it (:meth:`_follow`): another echo's ghost or Doppler response can
        hold the row's maximum at that boundary. Decided in the peaks' order, so any
        chunking of the input gives the same estimates. ``residual``: the peaks of the
        second search, in the input with the echoes measured lately taken out
        (:meth:`decide`)."""
        out: list[Estimate] = []
        refused = False
        for p in peaks:
            boundary = self._boundary(p)
            if self._refiner is not None:
                out += self._follow(boundary[0] - FOLLOW_LAG_HOPS * self._fe.hop_s)
            if p.beside and not p.second and not refused:
                continue
            self._second = None
            est = self.decide(p, boundary, residual)
            refused = est is None
            if est is not None:
                out.append(est)
                if self._second is not None:
                    out.append(self._second)
        return out

    def decide(
        self, p: Peak, boundary: tuple[float, float, float, int] | None = None,
        residual: bool = False,
    ) -> Estimate | None:  # fmt: skip
        """The estimate of one peak, or None where it is refused (band edge, too far);
        ``boundary`` its :meth:`_boundary` where the caller has it already. A ``residual``
        peak (the second search, :mod:`hil.estimation.gcas.residual`) where a measured echo
        puts its boundary is what is left of that echo, one in the still reverberation's
        Doppler cells is the reverberation the echoes measured there hid, and one where no
        echo taken out could have hidden it is one the first search saw or refused (all
        dropped, :attr:`leftover_count`); it is checked for the ghosts of the echoes not taken out
        only (the others' ghosts went with them)."""
        fe = self._fe
        t_rx, alpha, t_tx, hop_index = self._boundary(p) if boundary is None else boundary
        edge = self._edge_side(p.d0)
        if residual and (
            abs(fe.sound_speed_mps * (alpha - 1.0) / (alpha + 1.0)) < self._still_mps
            or self._refiner is None
            or self._refiner.continues_known(t_rx, alpha, hop_index, self._residual_lag_s)
            or not self._refiner.hidden_by_known(t_rx, alpha, self._residual_lag_s)
        ):
            self.leftover_count += 1
            return None
        # An echo moving on through rest leaves the band on the curve it went in on, its
        # detections on the band's edge for half a window: measured, where its fit's
        # boundary is outside the band by a hop's Doppler resolution and it collects what
        # the echo's did going in (within FOLLOW_DROP_DB: what still water or noise leaves
        # on a curve it does not follow is far weaker).
        leaving, exit_db = None, math.inf
        if fe.refused_hypotheses[p.d0] and self._refiner is not None and not residual:
            exit_ = self._refiner.band_exit(t_rx, alpha, hop_index, self._out_of_band_mps)
            if exit_ is not None:
                leaving, exit_db = exit_[0], exit_[1] - FOLLOW_DROP_DB
        if fe.refused_hypotheses[p.d0] and leaving is None:
            if self.hidden is not None:
                self.hidden.note(t_rx, alpha, hop_index, p.peak - p.mean)
            if (
                not residual
                and self.beyond_span is not None
                and self.beyond_span.in_band_ghost(t_rx, alpha, hop_index)
            ):
                self._say_beyond_span()
            else:
                self.in_band_count += 1
            return None
        bound = None
        if p.second and (
            self._refiner is None or not self._refiner.beside_known(t_rx, alpha, hop_index)
        ):
            return None
        if (
            p.masked
            and self._refiner is not None
            and self._refiner.followed_near(t_rx, alpha, hop_index)
        ):
            return None
        if self._refiner is not None:
            if self.hidden is not None:
                self.hidden.measure_near(t_rx, p.peak - p.mean)
            if self._refiner.ghost_of_known(
                t_rx, alpha, hop_index, edge, p.peak - p.mean, residual
            ):
                self.incoherent_count += 1
                return None
            pair_row = bool(self._pair_rows[p.d0])
            # Whether no echo was measured near, read before the fit remembers its own.
            inside = self.inside_sources
            alone = inside is not None and not self._refiner.known_echoes(
                t_rx, self._residual_lag_s if residual else 0.0
            )
            if not residual and edge == 0:
                left = self._refiner.left_beside_known(t_rx, alpha, hop_index, fe.max_speed_mps)
                if left is not None and left < MIN_ECHO_SNR_DB - LEFT_MARGIN_DB:
                    self.incoherent_count += 1
                    return None
            refined = self._refiner.refine(
                t_rx, alpha, hop_index, partners=pair_row, residual=residual,
                lag_s=self._residual_lag_s if residual else 0.0, pairs=pair_row,
                new_pairs=bool(self._new_pair_rows[p.d0]), curve=leaving,
                halves=edge == 0,
            )  # fmt: skip
            if refined is None:
                self.unmeasured_count += 1
                return None
            if leaving is not None and not (
                refined.is_echo(ECHO_TEST)
                and abs(refined.speed_mps(fe.sound_speed_mps)) >= self._out_of_band_mps
                and refined.e_over_n0_db >= exit_db
            ):
                self.in_band_count += 1
                return None
            if self.beyond_span is not None and self.beyond_span.check(
                t_rx, alpha, hop_index, edge, refined,
                self._residual_lag_s if residual else 0.0,
            ):  # fmt: skip
                self._say_beyond_span()
                return None
            if refined.ended:
                self.ended_count += 1
                return None
            if refined.is_echo(ECHO_TEST) and self._refiner.still_leak(refined, hop_index):
                self.incoherent_count += 1
                return None
            if refined.is_echo(ECHO_TEST) and self._refiner.weak_in_still_leak(refined):
                self._refiner.forget(refined)
                self.incoherent_count += 1
                return None
            if inside is not None and alone and refined.is_echo(ECHO_TEST):
                source = inside.source_of(t_rx, alpha, hop_index, refined)
                if source is not None:
                    self.incoherent_count += 1
                    fit, hop = source
                    return None if fit is None else self._source_estimate(fit, hop, p, residual)
            if refined.is_echo(ECHO_TEST):
                self._confirm_point_echo(refined, hop_index)
            else:
                verdict = self._in_reverberation(p, refined, hop_index)
                if verdict is not True:
                    if verdict is False:
                        self.clutter_count += 1
                        self._say_clutter(refined, t_tx, hop_index)
                    else:
                        self.incoherent_count += 1
                    return None
            if self._in_still_field(refined, hop_index):
                self.clutter_count += 1
                self._say_clutter(refined, t_tx, hop_index)
                return None
            t_rx, alpha, bound = refined.t_s, refined.alpha, refined.bound
            if refined.second is not None:
                self._second = self._second_of(refined.second, t_tx, hop_index, p, residual)
        elif self._coherent:
            t_rx, alpha = self._coherent_refine(p.n_star, p.d0, hop_index, t_rx, alpha)
        est = self._estimate(t_rx, alpha, t_tx, hop_index, bound, *_score(p))
        if est is None:
            return None
        consistent = self._consistent(hop_index, est.t_s, est.alpha)
        self.last_detection = DetectionInfo(p.n_star, p.threshold, p.mean, p.ratio, consistent)
        self.residual_count += residual
        return est

    def _say_beyond_span(self) -> None:
        """Add the beyond-span check's latest sighting to :attr:`notices`, once."""
        said = self.beyond_span.sightings if self.beyond_span is not None else []
        if said and said[-1] not in self.notices:
            self.notices.append(said[-1])

    def _source_estimate(
        self, fit: Refinement, hop_index: int, p: Peak, residual: bool
    ) -> Estimate | None:
        """The estimate of the echo found inside the span whose ghost peak ``p`` was
        (:mod:`hil.estimation.gcas.ghost_inside`), fitted as ``fit`` at its own boundary
        ending hop ``hop_index``, scored as ``p``; None where already reported."""
        fe, k = self._fe, self._k
        word = hop_index % fe.n_codewords
        t_tx = k.hop_end[word] + (hop_index // fe.n_codewords) * k.period
        return self._scored(
            self._estimate(fit.t_s, fit.alpha, t_tx, hop_index, fit.bound, *_score(p)), residual
        )

    def _second_of(
        self, fit: Refinement, t_tx: float, hop_index: int, p: Peak, residual: bool
    ) -> Estimate | None:
        """The estimate of the second echo of a resolved pair (:attr:`~hil.estimation.
        refine.Refinement.second`) at the boundary ending hop ``hop_index`` (transmitted at
        ``t_tx``, s), scored as its peak ``p``; None beyond the range or the span, or
        already reported."""
        fe = self._fe
        if abs(fit.speed_mps(fe.sound_speed_mps)) > fe.max_speed_mps:
            return None
        return self._scored(
            self._estimate(fit.t_s, fit.alpha, t_tx, hop_index, fit.bound, *_score(p)), residual
        )

    def _scored(self, est: Estimate | None, residual: bool) -> Estimate | None:
        """``est`` (an echo read from a peak at a boundary of its own, scored as that peak:
        :func:`_score`) counted among the second search's where ``residual``; None for
        None."""
        if est is None:
            return None
        self.residual_count += residual
        return est

    def _boundary(self, p: Peak) -> tuple[float, float, float, int]:
        """A peak's boundary: received at ``t_rx`` (s) at time scale ``α`` (the detector's
        speed), transmitted at ``t_tx`` (s, the end of hop ``hop_index``, folded by whole code
        periods into ``[0, τ_max]``)."""
        k = self._k
        dd = p.dd if self._refiner is not None else self._doppler_offset(p)
        speed = k.speeds[p.d0] + dd * k.speed_step
        c = self._fe.sound_speed_mps
        alpha = (c + speed) / (c - speed)  # speed_to_alpha, on Python floats
        exact_len = k.hop_samples / alpha
        t_rx = ((p.n_star + p.dn) * k.decimation - k.group_delay) / k.fs_in + (
            exact_len - k.lengths[p.d0] + 1
        ) / (2.0 * self._fe.fs_bb)
        end_j = k.hop_end[p.codeword]
        q = math.floor((t_rx - end_j + 2.0 / self._fe.fs_bb) / k.period)
        return t_rx, alpha, end_j + q * k.period, p.codeword + q * self._fe.n_codewords

    def _estimate(
        self, t_rx: float, alpha: float, t_tx: float, hop_index: int,
        bound: Crlb | None, score: float = math.nan, snr_db: float = math.nan,
    ) -> Estimate | None:  # fmt: skip
        """The estimate of the boundary ending hop ``hop_index`` (transmitted at ``t_tx``,
        s) measured at ``t_rx`` (s) and time scale ``alpha``, timed at its first arrival where
        the multipath readout is on; None beyond the range or already reported. Its ``score``
        and ``snr_db`` are its detection's (:func:`_score`), NaN for a followed boundary."""
        c = self._fe.sound_speed_mps
        if self._first_arrival is not None:
            first = self._first_arrival.first_arrival(t_rx, alpha, hop_index)
            if first is not None:
                t_rx, alpha = first.t_s, first.alpha
        delay = t_rx - t_tx
        slack = 2.0 / self._fe.fs_bb
        if delay > self._max_delay + slack or delay < -slack:
            # A followed fit's transmit time is its hop's, unfolded: an echo carried past the
            # transducer (range through zero) would read a negative range.
            self.refused_count += 1
            return None
        speed = c * (alpha - 1.0) / (alpha + 1.0)  # alpha_to_speed, on Python floats
        if self._reported_already(int(hop_index), t_rx, speed):
            self.same_echo_count += 1
            return None
        return Estimate(
            t_s=t_rx,
            range_m=c * delay / 2.0,
            speed_mps=speed,
            hop_index=int(hop_index),
            score=score,
            snr_db=snr_db,
            alpha=alpha,
            t_tx_s=t_tx,
            codeword=int(hop_index) % self._fe.n_codewords,
            receiver=self._receiver,
            crlb_range_m=math.nan if bound is None else bound.sigma_range_m,
            crlb_speed_mps=math.nan if bound is None else bound.sigma_speed_mps,
        )

    def _follow(self, t_s: float) -> list[Estimate]:
        """The boundaries of echoes measured lately that no detection brought by ``t_s``
        (s), fitted where their latest fits put them
        (:meth:`~hil.estimation.refine.CoherentRefiner.due`, measured as
        :meth:`~hil.estimation.refine.CoherentRefiner.refine` measures a followed boundary):
        those one echo by the echo test and within :data:`FOLLOW_DROP_DB` of what the echo's
        latest fit collected (:attr:`followed_count`). None in the reverberation
        band's refused hypotheses (an echo measured there is hidden,
        :mod:`hil.estimation.gcas.hidden_echoes`) nor beyond the Doppler span (an echo fitted
        there, the source of ghosts inside it, is followed to be taken out of other
        detections, and said once, :mod:`hil.estimation.gcas.beyond_span`)."""
        assert self._refiner is not None
        out = []
        fe = self._fe
        for hop_index, t_pred, alpha, latest_db in self._refiner.due(t_s):
            speed = fe.sound_speed_mps * (alpha - 1.0) / (alpha + 1.0)
            if fe.refused_hypotheses[int(np.argmin(np.abs(fe.grid.speeds_mps - speed)))]:
                continue  # in the reverberation band: hidden, not reported
            refined = self._refiner.refine(t_pred, alpha, hop_index, partners=False, followed=True)
            if refined is None or refined.ended or not refined.is_echo(ECHO_TEST):
                continue
            if refined.e_over_n0_db < latest_db - FOLLOW_DROP_DB:
                continue  # not the echo followed: what another echo's residue left
            if self._refiner.still_leak(refined, hop_index):
                continue  # the still water's leak, not an echo of its own
            if abs(refined.speed_mps(fe.sound_speed_mps)) > fe.max_speed_mps:
                continue  # beyond the span: fitted to keep it taken out, refused (beyond_span)
            k = self._k
            word = hop_index % fe.n_codewords
            t_tx = k.hop_end[word] + (hop_index // fe.n_codewords) * k.period
            est = self._estimate(refined.t_s, refined.alpha, t_tx, hop_index, refined.bound)
            if est is not None:
                self.followed_count += 1
                out.append(est)
        return out

    def _reported_already(self, hop_index: int, t_s: float, speed_mps: float) -> bool:
        """Whether an estimate reported at this boundary (hop ``hop_index``) lies within one
        resolution cell of ``(t_s, speed_mps)``: the same echo (two echoes that close are not
        resolved). Otherwise it is kept among those reported at this hop. Kept for
        :attr:`_residual_lag_s` of receive time (the second search's estimates come out that
        far behind the first search's)."""
        self._reported = [r for r in self._reported if r[1] >= t_s - self._residual_lag_s]
        for hop, t, v in self._reported:
            if (
                hop == hop_index
                and abs(t - t_s) <= 0.5 * self._lobe_s
                and abs(v - speed_mps) <= self._cell_mps
            ):
                return True
        self._reported.append((hop_index, t_s, speed_mps))
        return False

    def _say_clutter(self, fit: Refinement, t_tx: float, hop_index: int) -> None:
        """Note clutter refused at the fit's range (:class:`ClutterLog`), said where no
        notice so far is near it."""
        c = self._fe.sound_speed_mps
        seen = ClutterSeen(
            t_s=fit.t_s,
            hop_index=int(hop_index),
            range_m=c * (fit.t_s - t_tx) / 2.0,
            speed_mps=float(alpha_to_speed(fit.alpha, c)),
        )
        if self.clutter_seen.add(seen):
            self.notices.append(seen)

    def _doppler_offset(self, p: Peak) -> float:
        """The peak's Doppler offset from ``d0`` (grid steps), measured on the tones weighted
        1 at every hypothesis the parabola reads; the search's own (``p.dd``) where their
        weights agree.

        Next to the Doppler cells the reverberation band masks as another tone's clutter (a
        ghost speed), a hypothesis there lacks a tone its neighbour holds: its sum is lower,
        so the search settles on the unmasked neighbour even when the echo lies nearer the
        masked one, and the parabola through sums of unequal tones leans away from the
        masked side (+25 m/s on ``att``, beside the third tone's ghost cells from
        25.15 m/s, read 0.34 m/s low). Compared on the same tones, the sums are one echo's
        Doppler response again: the parabola is centred on the largest of them (moved up to
        :data:`DOPPLER_MOVES` steps) and read there."""
        fe, d = self._fe, p.d0
        if fe.tone_w is None or d == 0 or d == fe.grid.size - 1:
            return p.dd
        tone = self._term_tone(p.codeword)
        lo, hi = max(0, d - DOPPLER_MOVES - 1), min(fe.grid.size, d + DOPPLER_MOVES + 2)
        w = fe.tone_w[lo:hi][:, tone]  # (H, M)
        if np.all(w == w[d - lo]):
            return p.dd
        common = np.all(w >= 1.0, axis=0)
        if not common.any():
            return p.dd
        power = {
            h: float(np.sum(np.abs(self._unit_values(p.n_star, h, tone)[common]) ** 2))
            for h in range(lo, hi)
        }
        h = d
        for _ in range(DOPPLER_MOVES):
            up = h + 1 < hi - 1 and power[h + 1] > power[h]
            down = h - 1 > lo and power[h - 1] > power[h]
            if not (up or down):
                break
            h = h + 1 if up else h - 1
        return (h - d) + parabolic_offset(power[h - 1], power[h], power[h + 1])

    def _confirm_point_echo(self, refined: Refinement, hop_index: int) -> None:
        """A fit that passed the white-noise echo test in the still reverberation's cells
        confirms a point echo there (:mod:`hil.estimation.gcas.point_echoes`)."""
        fe = self._fe
        c = fe.sound_speed_mps
        if abs(float(refined.speed_mps(c))) < self._still_mps:  # in_reverberation
            self.point_echoes.note(hop_index, refined.t_s, refined.alpha, abs(refined.amplitude))

    def _in_still_field(self, refined: Refinement, hop_index: int) -> bool:
        """Whether an echo is a still scatterer among others, not one standing out of them
        (:meth:`~hil.estimation.gcas.point_echoes.PointEchoes.crowded`)."""
        return self.point_echoes.crowded(
            hop_index, refined.t_s, refined.alpha, abs(refined.amplitude)
        )

    def _in_reverberation(self, p: Peak, refined: Refinement, hop_index: int) -> bool | None:
        """A fit short of one echo's coherence in white noise, judged again where it shares
        its Doppler cells with the still reverberation (:mod:`hil.estimation.reverb_band`):
        True, one echo against the interference measured on the other tones of its windows,
        where a point echo confirmed lately predicts it
        (:mod:`hil.estimation.gcas.point_echoes`); False, clutter (diffuse reverberation);
        None, neither (refused as incoherent: no echo, or one not yet confirmed as a point
        echo), also outside the reverberation's cells."""
        fe, test = self._fe, ECHO_TEST
        c = fe.sound_speed_mps
        if not (refined.found and refined.e_over_n0_db >= test.min_e_over_n0_db):
            return None
        if not abs(float(refined.speed_mps(c))) < self._still_mps:  # in_reverberation
            return None
        k = fe.n_tones
        tone = self._term_tone(p.codeword)
        on = self._unit_values(p.n_star, p.d0, tone)
        off = np.stack([self._unit_values(p.n_star, p.d0, (tone + j) % k) for j in range(1, k)])
        if refined.coherence.measured >= test.fraction * reverberation_coherence(on, off.T):
            # Reported where a point echo was confirmed; elsewhere neither reported nor said
            # to be clutter: a target whose clear hops are still to come reads so too.
            return (
                True if self.point_echoes.predicts(hop_index, refined.t_s, refined.alpha) else None
            )
        coherence, tone_coherence = refined.coherence.fraction, refined.tone_coherence.fraction
        return False if is_diffuse(coherence, tone_coherence, test.fraction) else None

    def _term_tone(self, codeword: int) -> NDArray[np.int64]:
        """The tones of ``codeword``'s M terms (term m is hop ``codeword − m``), shape
        ``(M,)``: the same every code period, so made once per codeword."""
        tone = self._term_tones.get(codeword)
        if tone is None:
            m = self._fe.m_hops
            hops = self._fe.schedule.hops(codeword - m + 1, m)
            tone = np.ascontiguousarray(hops.tone_index[::-1], dtype=np.int64)
            self._term_tones[codeword] = tone
        return tone

    def _edge_side(self, d0: int) -> int:
        """+1 for the span's closing edge hypothesis, −1 for its opening one, else 0."""
        n = self._fe.grid.size
        return 1 if d0 == n - 1 else -1 if d0 == 0 else 0

    def _consistent(self, hop_index: int, t_rx: float, alpha: float) -> bool | None:
        """Did the hop index advance as the time since the previous detection predicts?
        None for the first detection after a (re)start."""
        consistent: bool | None = None
        if self._last_hop is not None:
            expected = round((t_rx - self._last_t) * alpha / self._fe.hop_s)
            consistent = hop_index - self._last_hop == expected
            if not consistent:
                self.inconsistent_count += 1
        self._last_hop, self._last_t = hop_index, t_rx
        return consistent

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
        fe = self._fe
        power = _coherent_power(fe, d0, hop_end, lambda tone: self._unit_values(n_star, d0, tone))
        c, step = fe.sound_speed_mps, fe.grid.speed_step_mps
        df = float(np.min(np.diff(np.sort(fe.tones_hz)))) if fe.n_tones > 1 else 1 / fe.hop_s
        # Pass 1: ±½ grating lobe in time, ±1 Doppler step; pass 2: a finer grid around the
        # best cell (the range–Doppler ridge is tilted, so one coarse pass leaves a bias).
        speed = float(alpha_to_speed(alpha_guess, c))
        t_rx = t_guess
        for half_t, half_v, nb in (
            (0.5 / (df * alpha_guess), step, 81),
            (0.1 / (df * alpha_guess), 0.25 * step, 41),
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


def _score(p: Peak) -> tuple[float, float]:
    """A detection's score (its peak over its threshold) and SNR (dB: its peak above its
    noise mean, over that mean), as its estimate carries them."""
    mean, thr = p.mean, p.threshold
    snr = (p.peak - mean) / mean if mean > 0 and math.isfinite(mean) else math.inf
    return (
        p.peak / thr if thr > 0 else math.inf,
        10.0 * math.log10(snr) if snr > 0 else -math.inf,
    )


def _coherent_power(
    fe: FrontEnd,
    d0: int,
    hop_end: int,
    unit_values: Callable[[NDArray[np.int64]], NDArray[np.complex128]],
) -> Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]:
    """``power(speeds, b)``: the coherent sum ``|Σ_m u_m e^{−j arg u_m(τ0, α)}|²`` of the M
    hops ending with ``hop_end`` at hypothesis ``d0``, on speeds (m/s) × boundary times
    ``b`` (s); ``unit_values(tone)`` gives the terms' unit correlators (phase model:
    :meth:`Readout._coherent_refine`)."""
    m = fe.m_hops
    hops = fe.schedule.hops(hop_end - m + 1, m)
    order = np.arange(m - 1, -1, -1)  # term m is hop hop_end − m
    tone = hops.tone_index[order]
    f = fe.tones_hz[tone]
    t_i = hops.start_s[order]
    phi = hops.phase_rad[order]
    v = unit_values(tone)
    a_d = float(fe.grid.alphas[d0])
    g = fe.baseband.group_delay / fe.fs_hz
    nu = a_d * f - fe.center_hz
    c = fe.sound_speed_mps
    t_end = float(hops.start_s[-1]) + fe.hop_s
    base = phi / (2.0 * np.pi) - np.mod(f * t_i, 1.0) - nu * g  # cycles, (M,)
    mid = t_i + 0.5 * fe.hop_s

    def power(speeds: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
        al = np.asarray(speed_to_alpha(speeds, c))[:, None, None]
        tau0 = b[None, :, None] - t_end / al
        cyc = base - f * al * tau0 + (al - a_d) * f * (tau0 + mid / al)
        result: NDArray[np.float64] = np.abs(np.exp(-2j * np.pi * cyc) @ v) ** 2
        return result

    return power
