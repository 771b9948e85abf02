"""The undetected echo inside the span whose ghost a detection may be.

An echo's every tone read as the tone ``n`` spacings away is its ghost, ``n`` tone spacings'
speed from it (27.0-29.1 m/s on ``att`` for ``n`` = 1; :mod:`hil.estimation.gcas.
ghost_source`). Where the echo was measured lately, a detection there is refused as its
ghost (:meth:`~hil.estimation.refine.CoherentRefiner.ghost_of_known`); where the echo lies
beyond the span, its source is looked for there (:mod:`hil.estimation.gcas.beyond_span`).
Near the threshold neither need hold for an echo inside the span: with few hops at low SNR
(``att``, M = 3 at -20 dB per-sample SNR, E/N0 about 15 dB over the window) the echo's own
peak is often below the threshold while its ghost's crosses it, and the ghost's few-hop fit
passes the echo test (its phases happen to agree): sim-05's 13.6 m/s target at 63 m,
detected on 12 of about 50 boundaries, was also reported three times at -14.3 m/s.

So a detection whose fit passes the echo test with no echo measured within
:data:`~hil.estimation.refine.KNOWN_HOPS` hops of it is read as a ghost once (a track's own
fits, and the detections beside measured echoes, are not looked at: they pay nothing; a
lone target's detections pay where its track starts again). Its source is looked for inside
the span where the ghost puts it (:meth:`~hil.estimation.gcas.ghost_source.GhostSources.
inside_bands`: one to :data:`~hil.estimation.gcas.ghost_source.SPACINGS` tone spacings
either way, outside the reverberation's cells), at the likelihood's best point over the
hops of one code period whose tones, shifted by those spacings, the ghost's codeword holds
(:meth:`~hil.estimation.gcas.ghost_source.GhostSources.peak`; at M = 3 the best point over
every hop can be noise's on another hop: sim-05's ghost at hop 52 put it at hop 46, the
source's boundary there ending hop 48).

Which of the two is the echo is not told by one window: a ghost whose codeword holds the
source's shifted tones on all M hops holds the source's whole energy there (sim-05, M = 3:
ghosts fitted at 1.13-1.24, their target's own fits at 1.2-1.4, the source refitted at the
ghost's boundary 0.68-0.71 and short of the echo test: that boundary was not detected
because its noise took energy away). The amplitude ratio the check beyond the span uses
(:data:`~hil.estimation.gcas.beyond_span.GHOST_SOURCE_RATIO`) is therefore not the test
here. Across boundaries it is told: a source holds its energy at every boundary, its ghost
only where its codeword and the source's shifted tones agree, so the likelihood of each,
carried back over a code period of boundaries (:meth:`InsideSources.evidence`), is the
source's the larger. Where the source's holds :data:`EVIDENCE_RATIO` times the detection's,
the detection is its ghost: refused (counted among the fits not one echo), its own fit
forgotten by the refinement (:meth:`~hil.estimation.refine.CoherentRefiner.forget`), and
the source refined at its boundary; where that fit is one echo inside the band it is the
echo's estimate at its own boundary (remembered by the refinement as any fit of one echo,
so the ghosts that follow are refused as a measured echo's).

A second target a tone spacing's speed from another holds its own energy at every boundary
too: the sum tells it apart where it is less than about 3 dB weaker; a weaker one, detected
while the other was not measured near it, is refused there (the other is reported and
measured in its place), and from its next detection on it is read with the other taken out
(:meth:`~hil.estimation.refine.CoherentRefiner.ghost_of_known`).
"""

from __future__ import annotations

import numpy as np

from hil.estimation.gcas.ghost_source import GhostSources
from hil.estimation.refine import EchoTest, Refinement

#: Times across ±½ grating lobe and speeds across ± the ``M`` hops' Doppler resolution at
#: which :meth:`InsideSources.evidence` is read.
TIME_POINTS = 9
SPEED_POINTS = 5
#: How many times the detection's own :meth:`InsideSources.evidence` the source's must hold
#: for the detection to be its ghost (likelihoods, noise's reading included). Measured on
#: sim-05's point at M = 3, -20 dB per-sample SNR (att, 30 trials, the likelihood's best
#: point in the band against the detection's fit): the targets' own detections, 141 read,
#: 0.09-1.01 (where noise lies in the band); their ghosts that reached the search, 8, at
#: 2.91-4.46 (5, refused) and 0.91-1.28 (3, whose source the code period's boundaries
#: hold no better: kept).
EVIDENCE_RATIO = 2.0


def evidence_history_s(
    period_hops: int, hop_s: float, max_speed_mps: float, sound_speed_mps: float
) -> float:
    """The input (s) the refinement must keep beyond its own history for
    :meth:`InsideSources.evidence`: the code period's ``period_hops`` boundaries read back,
    plus two hops (the source's boundary lies up to a hop before the ghost's, and the two
    time scales' drift up to about a hop and a half more at M = 29), each hop of ``hop_s``
    (s) received at the slowest time scale in the span ``±max_speed_mps`` (m/s). The
    refinement's own history holds ``2M + 1`` hops: without this, boundaries of the period
    were gone when read (16 of 680 reads in three of sim-05's trials at M = 3), and which
    ones would depend on how far the input had been pushed when the detection was decided."""
    c, v = float(sound_speed_mps), float(max_speed_mps)
    return (int(period_hops) + 2) * float(hop_s) * (c + v) / (c - v)


class InsideSources:
    """The search of the module docstring over ``ghosts``' geometry (its refiner, span and
    Doppler steps), with the echo test ``echo_test``; ``still_mps`` (m/s) the speeds the
    still reverberation's cells hold (no source is looked for slower than that)."""

    def __init__(self, ghosts: GhostSources, echo_test: EchoTest, still_mps: float) -> None:
        self.ghosts, self.test = ghosts, echo_test
        self.refiner = ghosts.refiner
        self.c = ghosts.c
        self.still_mps = float(still_mps)
        #: Boundaries read back for the evidence (:meth:`evidence`): one code period, every
        #: alignment of the ghost's codeword with the source's hops once.
        self.evidence_hops = int(ghosts.schedule.period_hops)
        self.reset()

    def reset(self) -> None:
        """Forget the count."""
        #: Detections read as the ghost of an echo found inside the span.
        self.count = 0

    def source_of(
        self, t_s: float, alpha: float, hop_index: int, fit: Refinement
    ) -> tuple[Refinement | None, int] | None:
        """Whether a detection at ``t_s`` (s), time scale ``alpha``, ending hop
        ``hop_index`` is the ghost of an echo inside the span, its own fit ``fit`` one echo
        and no echo measured near it (the caller's to know, before the fit): where the
        likelihood's best point in a band (:meth:`~hil.estimation.gcas.ghost_source.
        GhostSources.peak`) holds :data:`EVIDENCE_RATIO` times the detection's
        :meth:`evidence`, ``(the source's fit there, the hop its boundary ends)`` (counted;
        the fit None where it is not one echo inside the band: the detection is refused in
        any case), else None. A boundary whose ``M`` hops were not all transmitted (the
        schedule's first ``M − 1``) is no echo's fit: not looked at."""
        if hop_index < self.ghosts.m_hops - 1:
            return None
        own = -1.0
        for shift, v_lo, v_hi in self.ghosts.inside_bands(fit.alpha, self.still_mps):
            peak = self.ghosts.peak(t_s, alpha, v_lo, v_hi, (hop_index, shift))
            if peak is None:
                continue
            t_b, a_b, hop = peak
            if own < 0.0:
                own = self.evidence(fit.t_s, fit.alpha, hop_index)
            if not self.evidence(t_b, a_b, hop) >= EVIDENCE_RATIO * own > 0.0:
                continue
            self.count += 1
            # The detection's own fit, remembered by the refinement as one echo, is none:
            # forgotten, it is not taken out of its source's input (its model is the
            # source's tones on the hops they share) nor followed.
            self.refiner.forget(fit)
            source = self.refiner.refine(t_b, a_b, hop, partners=False)
            return (source if self._is_source(source, v_lo, v_hi) else None), hop
        return None

    def evidence(self, t_s: float, alpha: float, hop_index: int) -> float:
        """The likelihood ``|C|²`` of one echo near ``(t_s, alpha)`` of the boundary ending
        hop ``hop_index``, summed over that boundary and the :attr:`evidence_hops` − 1
        before it (the echo carried back at its time scale; those the input covers), at its
        best over ±½ grating lobe (:data:`TIME_POINTS`) and ± the ``M`` hops' Doppler
        resolution (:data:`SPEED_POINTS`) about the fit: one window's fit near the threshold
        is off by that much. A source holds its energy at every boundary; its ghost only
        where the ghost's codeword and the source's shifted tones agree (on ``att`` a quarter
        of the hops on average), so over a code period of boundaries the source's sum is the
        larger whichever of the two crossed the threshold at one of them."""
        c, ref, g = self.c, self.refiner, self.ghosts
        lobe = 1.0 / (alpha * ref.spacing_hz)
        speed = c * (alpha - 1.0) / (alpha + 1.0)
        speeds = speed + g.step_mps * np.linspace(-1.0, 1.0, SPEED_POINTS)[:, None]
        alphas = (c + speeds) / (c - speeds) + np.zeros((1, TIME_POINTS))
        offsets = 0.5 * lobe * np.linspace(-1.0, 1.0, TIME_POINTS)[None, :]
        total = np.zeros((SPEED_POINTS, TIME_POINTS))
        for j in range(self.evidence_hops):
            t = t_s - j * g.hop_s / alpha
            # Each speed's boundary j hops back drifts with its own time scale.
            tt = t_s - j * g.hop_s / alphas + offsets
            corr = ref.correlation(t, alpha, hop_index - j, tt, alphas)
            if corr is not None:
                total += np.abs(corr) ** 2
        return float(np.max(total))

    def _is_source(self, source: Refinement | None, v_lo: float, v_hi: float) -> bool:
        """Whether ``source`` is one echo (its window's, not ended) inside the band
        ``[v_lo, v_hi]`` (m/s, widened by the speed margin) and the span, out of the still
        reverberation's cells: its estimate."""
        if source is None or source.ended or not source.is_echo(self.test):
            return False
        v, margin = source.speed_mps(self.c), self.ghosts.margin_mps
        return (
            v_lo - margin <= v <= v_hi + margin
            and self.still_mps <= abs(v) <= self.ghosts.max_speed_mps
        )
