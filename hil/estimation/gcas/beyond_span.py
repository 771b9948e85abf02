"""An echo faster than the Doppler search span: refused, never aliased, and said.

A target closing (or opening) faster than the span ``±v_max`` is not on the receiver's
Doppler grid. What of it reaches the grid is of two kinds:

- its **ghosts**, every tone read as its neighbour one tone spacing's speed
  (``c Δf / (2 f_c)``, 27.5 m/s on ``att``) inward: the refinement's coherence test refuses
  them (the hops' phases are not one echo's; :mod:`hil.estimation.refine`);
- the **tail of its Doppler response on the span's edge hypothesis**: a unit correlator's
  response falls as ``sinc²`` of the Doppler offset, so an echo a few Doppler cells
  (``c/(2 f_c T_h)``) past the edge still peaks on the edge hypothesis. The fit started
  there climbs toward the echo and stops at, or past, the edge: a wrong speed (and range,
  along the range–Doppler ridge) if it were kept.

So a detection on an edge hypothesis (or whose fit ends within one Doppler resolution of the
``M`` hops, ``c/(2 f_max M T_h)``, of the edge or past it) is checked against an echo beyond
the span: the likelihood the refinement maximises, ``|C(t_rx, α)|²``, is scanned over a guard
band of :data:`GUARD_CELLS` Doppler cells past the edge (steps of half the ``M`` hops'
Doppler resolution; the boundary time moved by the comb's drift between the edge hypothesis
and each speed), and the refinement is run from the scan's best point. Where that fit is one
echo of the schedule (:meth:`~hil.estimation.refine.Refinement.is_echo`) beyond the span,
the detection is that echo's edge leak: refused, and the sighting kept (the first per side,
:class:`BeyondSpan`). A fit beyond the span by more than half that resolution is refused in
any case: the span is the receiver's promise.

An echo fitted inside the span within the guard band's width of an edge is checked once while
it is followed (:meth:`BeyondSpanCheck._outshone`): where the guard band's likelihood exceeds
the fit's, something beyond the span explains the detection better than the fit, which
stopped short of it, and it is refused. The ghost of a slow echo that the reverberation band
hides lies one tone spacing out, beyond the span when the span is narrower than the tone
spacing's speed (±25.72 m/s on ``att`` against 27.5 m/s): refined from the edge, its fit
stops inside (24.5-25.3 m/s for a 3.1 m/s target at +5 dB, 6 of 180 trials of the JIFS
comparison in docs/results.md), and the guard band holds 5-8 times its likelihood (refused
from :data:`OUTSHINE` times, beyond the fit's own main lobe). A target inside the span near
its edge outshines its own sidelobes beyond it.

A detection whose own fit is not one echo is refused whatever the scan finds (the scan only
decides whether it is counted and said as an echo beyond the span, and gives :meth:`_follow`
its warm start). Beside a strong echo inside the span, such detections come at nearly every
hop (its ghost one tone spacing out leaks onto the edge hypothesis) and a scan costs
hundreds of likelihood evaluations (about 20 ms of CPU on ``att``, M = 10): after a scan
for one finds nothing, that edge's next scans for them wait 1, 2, 4 … up to
:data:`MAX_SCAN_GAP_HOPS` hops, and a scan that finds the echo starts the waits again. An
echo fit near the edge once an echo beyond it was seen is always scanned: there the scan
decides whether it is reported.

Below about 0 dB per-sample SNR the edge leak may never cross the threshold while the
echo's ghosts do (``att``, 35 m/s with a 30 m/s span at -10 dB: none on the edge in 2 s, 190
ghost detections at 7.3-8.1 m/s). So a detection inside the span whose fit is not one echo
is read as a ghost (:mod:`hil.estimation.gcas.ghost_source`): where its source would lie
beyond the span (one, two or three tone spacings out, as far as that is: the refinement's
windows reach it, :meth:`BeyondSpanCheck.source_reach_mps`), that source is fitted again
from the latest fit beyond that edge (within :data:`GHOST_FOLLOW_HOPS`), else looked for
over every hop of a code period (every band of a side in one scan, with its own waits per
side, as above; not from a boundary whose ``M`` hops were not all transmitted) and refined;
a fit there that is one echo beyond the span and :data:`GHOST_SOURCE_RATIO` times the
ghost's own is a sighting, and the detection is refused as its. A detection at the still
water's ghost speeds (whole tone spacings from rest; the refiner's rule,
:meth:`~hil.estimation.refine.CoherentRefiner.ghost_of_rest`) where its window holds still
water (a target at rest, volume reverberation) is that water's ghost, and no source beyond
the span is scanned for (a scan of every band of a side for each one the waits let through:
about 0.02 s of CPU a scan on ``att``). An echo fitted inside the
span where a fit beyond the span lately puts its ghost (one to three tone spacings inward,
where its comb peaks) and weaker than that fit is refused as that ghost: at low SNR a
ghost's phases can agree (measured, 35 m/s at -10 dB: 7.44 m/s at 99.67 m; -35 m/s: 19.53
m/s). Each side is said at the second fit beyond it within :data:`GHOST_FOLLOW_HOPS` hops
of another whose hops were all transmitted, with that fit's time and speed: a lone fit may
be noise's, and one of hops partly before the schedule's first (a far echo's first
boundaries) is read 0.1 m/s off.

A ghost may fall inside the reverberation band, whose edge's detections are refused
whatever they are (three-state, 15 ms hops: 35 m/s with a 30 m/s span has its only ghost at
-1.67 m/s; at -10 dB nothing else of it is detected in 2 s). So a detection on the band's
edge whose source would lie beyond the span is fitted (the fit not remembered as an echo)
and read as a ghost (:meth:`BeyondSpanCheck.in_band_ghost`) where its window is known to
hold no still water (there the band's edge is that water's own leak). A slow, stopped or
reversing target's edge detections come at nearly every hop, so these looks are made
cheap: each edge of the band looks at its first detection, then waits 32, 64 … hops after
each look that finds nothing, and a look reads the source's likelihood only at the hops
whose tones, shifted by the band's tone spacings, its codeword holds on at least one of
its hops (as a scan does: at -10 dB one hop of a source beyond the span can pass), refining
only the best point of all bands (31-35 ms a look on three-state, where reading every hop of
a code period and refining each band's best point cost about 70 ms).

Nothing beyond the span is ever reported as an estimate. A target further than the guard
band past the edge leaves no edge detection: its ghosts are all that reach the grid, and
their sources are looked for wherever the tones' ratios put them, so it is said at its own
speed (``att``, a 30 m/s span, -10 dB: 40, 45, 50, 55 and 60 m/s closing and opening said
within 0.01 m/s; 35-45 m/s with 20 and 25.72 m/s spans). Were the search cut at the guard
band's end, the echo's lobe one Doppler cell inward would be fitted there and said at a
wrong speed (40 m/s: said at 37.5 m/s) and 45 m/s not at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from hil.estimation.gcas.ghost_source import GhostSources, SourceGrid
from hil.estimation.refine import (
    GHOST_HOPS,
    GHOST_LEAK_FRACTION,
    CoherentRefiner,
    EchoTest,
    Refinement,
)

#: Doppler cells of one hop (``c/(2 f_c T_h)``) past the span's edge that the check scans: an
#: echo three cells out still leaks onto the edge hypothesis above a 0 dB detection threshold.
GUARD_CELLS = 3.0
#: Time points of the scan over ±½ grating lobe around each speed's predicted boundary.
SCAN_TIME_POINTS = 9

#: How many times the fit's likelihood the guard band must hold, beyond the fit's own main
#: lobe (one Doppler resolution of the ``M`` hops), to outshine an echo fitted near the edge:
#: a ghost's source beyond the span held 5-8 times (docs/results.md, JIFS comparison), while
#: noise on a target 0.2 m/s inside the edge lifts its own lobe past the edge above its fit.
OUTSHINE = 2.0

#: Hops for which an echo fitted inside the span within the guard band's width of its edge
#: holds the edge's detections (its lobes).
INSIDE_HOPS = 3

#: How every notice of an echo beyond the span begins (:meth:`BeyondSpan.text`).
BEYOND_SPAN_TEXT = "an echo beyond the "

#: Hops from a fit beyond the span (before or after: a ghost's follow may have fitted a later
#: boundary) within which an edge detection is checked by fitting that echo again where it
#: puts the detection's boundary, before a scan.
FOLLOW_HOPS = 3

#: Longest wait, in hops, between two scans of an edge for detections not fitted as one echo
#: after scans that found nothing (module docstring): an echo beyond the span that appears
#: then is said at most this many hops late (0.3 s on ``att``).
MAX_SCAN_GAP_HOPS = 64

#: The first wait, in hops, after a look at a reverberation band's edge for the ghost of an
#: echo beyond the span that found nothing (:meth:`BeyondSpanCheck.in_band_ghost`): a slow
#: target's edge detections come at nearly every hop, and each look costs 31-35 ms
#: (three-state); a beyond-span target is said at most this many hops later than its first
#: look would have (0.48 s on three-state), then :data:`MAX_SCAN_GAP_HOPS`.
BAND_LOOK_GAP_HOPS = 32

#: Times read across the ±1 grating lobe of a band-edge look's likelihood reading
#: (:meth:`BeyondSpanCheck._band_edge_source`; a scan's are
#: :data:`~hil.estimation.gcas.ghost_source.TIME_POINTS`).
BAND_LOOK_TIME_POINTS = 9

#: Hops from the latest fit beyond an edge within which a ghost of that echo is followed
#: (its source fitted again where it puts the ghost's boundary, before a scan): its ghosts
#: come every few hops, and between them the refinement refuses them as the ghosts of a
#: known echo for :data:`~hil.estimation.refine.KNOWN_HOPS` without a fit.
GHOST_FOLLOW_HOPS = 8

#: How many times a ghost's own fit's amplitude its source beyond the span must have: a
#: ghost collects part of its echo's energy (0.15-0.34 of its echo's peak,
#: :data:`~hil.estimation.refine.GHOST_LEAK_FRACTION`), while the ghost beyond the span of
#: an echo inside it (a slow echo's, one tone spacing out) is weaker than that echo, and a
#: fit of noise where the ghost puts its source holds about the ghost's own (the sources are
#: looked for at every tone spacing, up to five bands a ghost, each a chance for noise).
#: Measured on ``att`` (a 30 m/s span, 35-60 m/s, -20 to 0 dB): sources 2.1-20 times their
#: ghosts' fits; noise fitted as an echo at -44.7 m/s beside a 10 m/s target at -20 dB, 1.0
#: and 1.6 times.
GHOST_SOURCE_RATIO = 2.0

#: Doppler cells of one hop within which a detection is the leak of an echo measured lately
#: inside the span (its codeword's Doppler sidelobes, 3-3.7 cells out on ``att`` at 0 dB: a
#: 12 m/s target leaks at 4.4 and 19.3 m/s, 20 m/s at 11.0, -12 m/s at -21.3), and within
#: which of that echo's ghosts' speeds (one to three tone spacings from it,
#: :data:`~hil.estimation.gcas.ghost_source.SPACINGS`) a detection is its ghost: neither is
#: scanned for a source beyond the span (a scan costs as much as the rest of a lone
#: target's hop).
LEAK_CELLS = 4.0
GHOST_CELLS = 1.0

#: The side of the span an echo is beyond: closing (positive speed) or opening.
CLOSING, OPENING = "closing", "opening"


@dataclass(frozen=True)
class BeyondSpan:
    """An echo seen beyond the Doppler search span: the boundary time ``t_s`` (s, input
    time) and ``hop_index`` of the detection it leaked into, its ``side`` (:data:`CLOSING`
    or :data:`OPENING`), the span ``max_speed_mps`` (m/s) and the speed it was fitted at
    beyond it (m/s, closing positive: where the guard band's likelihood peaked, which may be
    a sidelobe of the echo's at low SNR; not an estimate)."""

    t_s: float
    hop_index: int
    side: str
    max_speed_mps: float
    speed_mps: float

    def text(self) -> str:
        """One line for a person: what was seen, where, and what to do."""
        return (
            f"{BEYOND_SPAN_TEXT}±{self.max_speed_mps:g} m/s Doppler span was seen "
            f"({self.side}) at t = {self.t_s:.4f} s (hop {self.hop_index}); it is refused, "
            "not reported: raise --max-speed to measure it"
        )

    def to_dict(self) -> dict[str, object]:
        """JSON-ready fields, with ``"notice": "beyond_span"``."""
        return {
            "notice": "beyond_span",
            "t_s": self.t_s,
            "hop_index": self.hop_index,
            "side": self.side,
            "max_speed_mps": self.max_speed_mps,
            "speed_mps": self.speed_mps,
        }


class BeyondSpanCheck:
    """The check of the module docstring for one receiver: ``refiner`` (built for speeds up
    to the guard band's end), the span ``max_speed_mps`` (m/s), the echo test, and the
    waveform's hop length ``hop_s`` (s), centre frequency ``center_hz`` and highest tone
    ``f_max_hz`` (Hz)."""

    def __init__(
        self, refiner: CoherentRefiner, max_speed_mps: float, echo_test: EchoTest, *,
        hop_s: float, center_hz: float, f_max_hz: float,
    ) -> None:  # fmt: skip
        self.refiner, self.test = refiner, echo_test
        self.max_speed_mps = float(max_speed_mps)
        self.c = refiner.c
        self.hop_s, self.m_hops = float(hop_s), refiner.m_hops
        #: Doppler resolution of the ``M`` hops, m/s: a fit past the edge by half of it is
        #: beyond the span.
        self.resolution_mps = self.c / (2.0 * f_max_hz * self.m_hops * self.hop_s)
        #: One Doppler cell of a hop, m/s.
        self.cell_mps = self.c / (2.0 * center_hz * self.hop_s)
        #: Width of the guard band past the edge, m/s.
        self.guard_mps = self.guard_width_mps(self.c, center_hz, self.hop_s)
        #: Where the source of a ghost detected inside the span may be beyond it.
        self.ghosts = GhostSources(
            refiner, self.max_speed_mps, inside_mps=0.5 * self.resolution_mps,
            step_mps=self.resolution_mps, cell_mps=self.cell_mps,
        )  # fmt: skip
        self.reset()

    @staticmethod
    def guard_width_mps(sound_speed_mps: float, center_hz: float, hop_s: float) -> float:
        """The guard band's width past the edge, :data:`GUARD_CELLS` Doppler cells of one
        hop, m/s."""
        return GUARD_CELLS * sound_speed_mps / (2.0 * center_hz * hop_s)

    @staticmethod
    def source_reach_mps(
        tones_hz: NDArray[np.float64], max_speed_mps: float, sound_speed_mps: float,
        center_hz: float, hop_s: float,
    ) -> float:  # fmt: skip
        """The fastest echo (m/s) the check fits: the source of a ghost on the span's edge
        :data:`~hil.estimation.gcas.ghost_source.SPACINGS` tone spacings in
        (:meth:`GhostSources.farthest_mps`), or the guard band's end, whichever is further;
        the refinement's windows are made to reach it."""
        cell = sound_speed_mps / (2.0 * center_hz * hop_s)
        return max(
            GhostSources.farthest_mps(tones_hz, max_speed_mps, sound_speed_mps, cell),
            max_speed_mps + GUARD_CELLS * cell,
        )

    def reset(self) -> None:
        """Forget the sightings and the count."""
        #: The first sighting on each side, in the order seen.
        self.sightings: list[BeyondSpan] = []
        #: Detections refused as an echo beyond the span (its edge leak, or a fit past it).
        self.count = 0
        self._inside: list[tuple[float, float]] = []  # echoes near the edge: (t_s, speed)
        #: The latest fit beyond each edge (+1, −1): (hop index, boundary time s, α).
        self._last: dict[int, tuple[int, float, float]] = {}
        #: Per edge: the first hop at which a detection not fitted as one echo is scanned
        #: again, and the wait after the next scan that finds nothing (hops).
        self._next_scan: dict[int, int] = {}
        self._scan_gap: dict[int, int] = {}
        #: The same for the scans for the source of a ghost beyond each edge.
        self._next_ghost_scan: dict[int, int] = {}
        self._ghost_scan_gap: dict[int, int] = {}
        #: The same for the looks at each edge of the reverberation band (+1, −1;
        #: :meth:`in_band_ghost`).
        self._next_band_look: dict[int, int] = {}
        self._band_look_gap: dict[int, int] = {}

    def beyond(self, speed_mps: float) -> bool:
        """Whether a fitted speed (m/s) lies beyond the span (by more than half the
        resolution of the ``M`` hops)."""
        return abs(speed_mps) > self.max_speed_mps + 0.5 * self.resolution_mps

    def near_edge(self, speed_mps: float, within_mps: float) -> bool:
        """Whether a fitted speed (m/s) lies within ``within_mps`` of the edge or past it."""
        return abs(speed_mps) > self.max_speed_mps - within_mps

    def _seen_on(self, side: int) -> bool:
        """Whether an echo beyond the ``side`` edge (+1 closing, −1 opening) was seen (said:
        a lone fit there, not followed by another, may be noise's or an echo's lobe)."""
        name = CLOSING if side > 0 else OPENING
        return any(s.side == name for s in self.sightings)

    def _inside_echo_at(self, t_s: float, side: int) -> bool:
        """Whether an echo inside the span within the guard band's width of the ``side`` edge was
        fitted within :data:`INSIDE_HOPS` hops before ``t_s`` (s): the edge's detections are
        then its main lobe."""
        recent = [(t, v) for t, v in self._inside if t_s - t <= INSIDE_HOPS * self.hop_s]
        self._inside = recent
        return any(v * side > 0 for _, v in recent)

    def check(
        self, t_s: float, alpha: float, hop_index: int, side: int, fit: Refinement | None,
        lag_s: float = 0.0,
    ) -> bool:  # fmt: skip
        """Whether a detection at ``t_s`` (s), time scale ``alpha``, ending hop
        ``hop_index`` on the ``side`` edge (+1 closing, −1 opening, 0 not on an edge) with
        its own ``fit`` is the leak of an echo beyond the span, or is fitted past it
        (refused either way, counted; the first sighting per side kept). ``lag_s``: how far
        (s) the detection may lie before the echoes measured by now (the second search's
        lag, :meth:`~hil.estimation.refine.CoherentRefiner.hidden_by_known`): those echoes
        too may explain it as their leak (:meth:`_leak_of_known`)."""
        echo = fit is not None and fit.is_echo(self.test)
        own = math.nan if fit is None else fit.speed_mps(self.c)
        if echo and self.beyond(own):
            # Refused in any case; seen where it is not the lobe of an echo inside the span.
            out = 1 if own > 0 else -1
            if self._outshines_inside(fit, hop_index, out):  # type: ignore[arg-type]
                self._seen(fit, hop_index, out)  # type: ignore[arg-type]
            self.count += 1
            return True
        if echo:
            if not self.near_edge(own, self.guard_mps):
                return self._ghost_that_passed(t_s, alpha, fit)  # type: ignore[arg-type]
            side = 1 if own > 0 else -1
            if not (self._seen_on(side) and self.near_edge(own, self.cell_mps)):
                if not self._held(t_s, own) and self._outshone(
                    t_s,
                    alpha,
                    hop_index,
                    side,
                    fit,  # type: ignore[arg-type]
                ):
                    self.count += 1
                    return True
                # An echo inside the span near its edge: the edge's detections around it
                # are its lobes.
                self._inside.append((t_s, own))
                return False
            # Once an echo beyond this edge has been seen, a fit within one Doppler cell of
            # the edge may be its leak, fitted on a sidelobe of the likelihood: scanned.
        elif side == 0:
            return fit is not None and self._ghost_refused(t_s, alpha, hop_index, fit, lag_s)
        elif self._inside_echo_at(t_s, side):
            # An edge detection not fitted as an echo is checked unless an echo inside the
            # span near that edge holds its detections.
            return False
        found = self._follow(hop_index, side)
        if found is None and (echo or hop_index >= self._next_scan.get(side, hop_index)):
            found = self._scan(t_s, alpha, hop_index, side)
            if not echo:
                self._scanned(hop_index, side, found is not None, self._next_scan, self._scan_gap)
        if found is None:
            return False
        self._seen(found, hop_index, side)
        self.count += 1
        return True

    def _follow(self, hop_index: int, side: int) -> Refinement | None:
        """The echo beyond the ``side`` edge fitted within :data:`FOLLOW_HOPS` hops of
        ``hop_index``, fitted again where it puts this boundary (the refinement's warm
        start: a few evaluations, where a scan costs hundreds); None where there is none or
        the fit is not one echo beyond the span. Each fit is one of the echoes the
        refinement takes out of other detections (its ghosts then collect what noise
        does)."""
        last = self._last.get(side)
        if last is None or abs(hop_index - last[0]) > FOLLOW_HOPS:
            return None
        hop, t_fit, a_fit = last
        t_pred = t_fit + (hop_index - hop) * self.hop_s / a_fit
        fit = self.refiner.refine(t_pred, a_fit, hop_index)
        if fit is None or not fit.is_echo(self.test) or not self.beyond(fit.speed_mps(self.c)):
            return None
        return fit

    @staticmethod
    def _scanned(
        hop_index: int, side: int, found: bool, next_scan: dict[int, int], gaps: dict[int, int]
    ) -> None:
        """After a scan of the ``side`` edge at ``hop_index`` for a detection not fitted as
        one echo: the waits (``next_scan``: the next hop scanned, ``gaps``: the wait after the
        next scan that finds nothing) start again where it ``found`` the echo, else the next
        is doubled (module docstring)."""
        if found:
            next_scan.pop(side, None)
            gaps.pop(side, None)
            return
        gap = gaps.get(side, 1)
        next_scan[side] = hop_index + gap
        gaps[side] = min(2 * gap, MAX_SCAN_GAP_HOPS)

    def _ghost_refused(
        self, t_s: float, alpha: float, hop_index: int, fit: Refinement, lag_s: float = 0.0
    ) -> bool:
        """Whether a detection inside the span at ``t_s`` (s) and ``alpha`` (hop
        ``hop_index``) whose ``fit`` is not one echo is the ghost of an echo beyond the span
        (:mod:`hil.estimation.gcas.ghost_source`): its source is followed from the latest
        fit beyond that edge, else (with the scans' waits) looked for, unless an echo
        measured inside the span explains it (:meth:`_leak_of_known`, ``lag_s`` as
        :meth:`check`'s); found, it is counted and the first per side said."""
        # A boundary whose M hops were not all transmitted (the schedule's first M - 1) is
        # not one echo's fit whatever it is: no source is looked for from it (a lone target's
        # first boundaries would each cost a scan of every band).
        bands = self.ghosts.spaced_bands(alpha) if hop_index >= self.m_hops - 1 else []
        for side in dict.fromkeys(b[0] for b in bands):
            own = [b for b in bands if b[0] == side]
            found = None
            for _, _, v_lo, v_hi in own:
                found = found or self._follow_ghost(
                    t_s, alpha, (side, v_lo, v_hi), fit, timed=False
                )
            if (
                found is None
                and hop_index >= self._next_ghost_scan.get(side, hop_index)
                and not self._leak_of_known(t_s, alpha, fit, lag_s)
                and not self._ghost_of_still(t_s, alpha)
            ):
                # Each band is read only at the source's boundaries whose tones, shifted by its
                # tone spacings, the detection's codeword holds on a hop at least
                # (GhostSources.grid): where no band has one, no source beyond this edge can
                # have this ghost, nothing is read and the waits stand (they space out scans
                # that read and found nothing).
                grids = [
                    self.ghosts.grid(t_s, alpha, v_lo, v_hi, (hop_index, side * n))
                    for _, n, v_lo, v_hi in own
                ]
                if not any(g.hops for g in grids):
                    continue
                # One scan of a side reads every band of it (its tone spacings), nearest
                # first, and waits as one.
                for grid in grids:
                    if grid.hops:
                        found = found or self._scan_ghost(grid, side, fit)
                self._scanned(
                    hop_index, side, found is not None, self._next_ghost_scan, self._ghost_scan_gap
                )
            if found is not None:
                self._seen(found[0], found[1], side)
                self.count += 1
                return True
        return False

    def in_band_ghost(self, t_s: float, alpha: float, hop_index: int) -> bool:
        """Whether a detection on the reverberation band's edge at ``t_s`` (s) and ``alpha``
        (hop ``hop_index``), refused there whatever it is, is the ghost of an echo beyond the
        span (:meth:`_band_edge_source`; counted and the first per side said where found).
        A target one tone spacing's speed or more past the span can put its only ghost
        inside the band (three-state, 15 ms hops: 35 m/s with a 30 m/s span reads at
        -1.67 m/s); below about 0 dB nothing else of it is detected.

        Such a detection is looked at only to say the echo, so the look is kept cheap: a
        slow, stopped or reversing target's band-edge detections come at nearly every hop
        and are not ghosts. Not once a side where its source may lie was said (it is taken
        for that echo's ghost). A follow (a fit beyond the span within
        :data:`GHOST_FOLLOW_HOPS`) is always tried; otherwise each edge of the band looks
        at its first detection and, after a look that finds nothing (whatever ended it),
        waits :data:`BAND_LOOK_GAP_HOPS` hops, then twice as long, up to
        :data:`MAX_SCAN_GAP_HOPS` (:meth:`_band_looked`). Each edge waits on its own: at
        0 dB the ghost's Doppler sidelobes on the other edge come first (three-state, 35 m/s:
        ghost at -1.67 m/s detected at -2.6 and +2.5 m/s; the sources a look at +2.5 m/s
        reads do not hold 35 m/s). Not where the window is not known to hold no still water
        (:meth:`~hil.estimation.refine.CoherentRefiner.in_open_water`: there the band's
        edge is that water's own leak). Its fit is not remembered as an echo, and where it
        is one echo it is not read as a ghost (a target reversing through rest)."""
        if hop_index < self.m_hops - 1:
            return False
        sides = {band[0] for band in self.ghosts.bands(alpha)}
        if any(self._seen_on(side) for side in sides):
            return False
        following = any(
            abs(hop_index - self._last.get(side, (-(10**9),))[0]) <= GHOST_FOLLOW_HOPS
            for side in sides
        )
        edge = 1 if alpha > 1.0 else -1
        if not following and hop_index < self._next_band_look.get(edge, hop_index):
            return False
        if not self.refiner.in_open_water(t_s, alpha):
            return False
        fit = self.refiner.refine(t_s, alpha, hop_index, partners=False, remember=False)
        found = (
            fit is not None
            and not fit.is_echo(self.test)
            and self._band_edge_source(t_s, alpha, hop_index, fit)
        )
        if not following:
            self._band_looked(hop_index, found, edge)
        return found

    def _band_looked(self, hop_index: int, found: bool, edge: int) -> None:
        """After a look at a detection on the band's ``edge`` (+1, −1) at ``hop_index``
        (:meth:`in_band_ghost`): that edge's waits start again where it ``found`` an echo
        beyond the span; else its next look waits :data:`BAND_LOOK_GAP_HOPS` hops, then
        twice as long after each look that finds nothing, up to :data:`MAX_SCAN_GAP_HOPS`."""
        if found:
            self._next_band_look.pop(edge, None)
            self._band_look_gap.pop(edge, None)
            return
        gap = self._band_look_gap.get(edge, BAND_LOOK_GAP_HOPS)
        self._next_band_look[edge] = hop_index + gap
        self._band_look_gap[edge] = min(2 * gap, MAX_SCAN_GAP_HOPS)

    def _band_edge_source(self, t_s: float, alpha: float, hop_index: int, fit: Refinement) -> bool:
        """Whether a detection on the reverberation band's edge at ``t_s`` (s) and ``alpha``
        (hop ``hop_index``, its own ``fit`` not one echo) is the ghost of an echo beyond the
        span (:meth:`in_band_ghost`): followed from the latest fit beyond an edge where one
        is within reach (:meth:`_follow_ghost`), else, unless an echo measured inside the
        span explains it (:meth:`_leak_of_known`), the likelihood is read over every band
        where its source may lie (both sides, one to three tone spacings), each only at the
        source's hops whose tones, shifted by the band's tone spacings, are the detection's
        codeword's on at least
        :data:`~hil.estimation.gcas.ghost_source.MIN_BEYOND_MATCHES` of its ``M`` hops
        (:meth:`~hil.estimation.gcas.ghost_source.GhostSources.matching`: a ghost holds
        only those hops of its source, and at -10 dB one of them can pass; on three-state
        17-29 of a code period's 32, one and two spacings out), at
        :data:`BAND_LOOK_TIME_POINTS` times, and only the best point of all bands is
        refined. Found, it is counted and the first per side said.

        Measured on three-state (35-55 m/s closing and opening, 20, 25.72 and 30 m/s spans,
        -15 to 0 dB, seeds 1-3; 204 inputs with a look), against reading only the
        boundaries that match on 4 of 10 hops, as inside the span: one match says 3 sources
        that were never said (35 m/s, -15 and -10 dB), 8 others 15-52 hops sooner, 2 1-2
        hops sooner, one 28 hops sooner but 0.46 m/s off (-35 m/s, -5 dB), and 3 1-2 hops
        later (one of them said 1.8 m/s off before); the same wrong estimates. Reading every
        boundary says the same as one match. Cost, -10 dB: reading every hop of a code
        period and refining each band's best point (:meth:`_ghost_refused`) cost about
        70 ms a look (+40-140 % receiver CPU for a slow, reversing or braking target); this
        reading costs 31-35 ms a look (4 of 10 hops': 6-10 ms; +18-46 % receiver CPU over
        2 s of a slow or a 35 m/s target, +20 % over the 204 inputs)."""
        bands = self.ghosts.spaced_bands(alpha)
        for side, _, v_lo, v_hi in bands:
            followed = self._follow_ghost(t_s, alpha, (side, v_lo, v_hi), fit, timed=False)
            if followed is not None:
                self._seen(followed[0], followed[1], side)
                self.count += 1
                return True
        if self._leak_of_known(t_s, alpha, fit):
            return False
        best: tuple[float, float, float, int, int] | None = None
        for side, n, v_lo, v_hi in bands:
            peak = self.ghosts.best_point(
                t_s,
                alpha,
                v_lo,
                v_hi,
                (hop_index, side * n),
                time_points=BAND_LOOK_TIME_POINTS,
            )
            if peak is not None and (best is None or peak[0] > best[0]):
                best = (*peak, side)
        if best is None:
            return False
        _, t_b, a_b, hop, side = best
        source = self.refiner.refine(t_b, a_b, hop)
        if source is None or not self._source(source, side, fit):
            return False
        if not self._outshines_inside(source, hop, side):
            return False
        self._seen(source, hop, side)
        self.count += 1
        return True

    def _leak_of_known(self, t_s: float, alpha: float, fit: Refinement, lag_s: float = 0.0) -> bool:
        """Whether a detection at ``t_s`` (s) and ``alpha`` whose fit is ``fit`` is explained
        by an echo measured lately inside the span: within :data:`LEAK_CELLS` Doppler cells
        of its speed, within :data:`GHOST_CELLS` of one of its ghosts'
        (:data:`LEAK_CELLS`), or at most :data:`~hil.estimation.refine.GHOST_LEAK_FRACTION`
        of its amplitude anywhere (a strong echo's leaks reach further: 9 m/s at 20 dB
        leaks at -24.2 m/s; a ghost holds 0.15-0.34 of its source, so the source of a ghost
        that weak would be weaker than that echo, and is given up while it is measured)."""
        speed = self.c * (alpha - 1.0) / (alpha + 1.0)
        for v, amplitude in self.refiner.known_echoes(t_s, lag_s):
            if self.beyond(v):
                continue
            apart = abs(speed - v)
            if (
                apart <= LEAK_CELLS * self.cell_mps
                or any(
                    abs(apart - g) <= GHOST_CELLS * self.cell_mps for g in self.ghosts.spacing_mps
                )
                or abs(fit.amplitude) <= GHOST_LEAK_FRACTION * amplitude
            ):
                return True
        return False

    def _ghost_of_still(self, t_s: float, alpha: float) -> bool:
        """Whether a detection at ``t_s`` (s) and ``alpha`` is the still water's ghost: at a
        still echo's ghost speed (:meth:`~hil.estimation.refine.CoherentRefiner.ghost_of_rest`:
        within :data:`~hil.estimation.refine.STILL_GHOST_CELLS` Doppler cells of a whole number
        of tone spacings' speed from rest, ±27.5 m/s on ``att``; the ghost and its main lobe,
        detected from 22.5 to 30 m/s beside a target at rest), where its ``M`` hops' window
        holds still water (:meth:`~hil.estimation.refine.CoherentRefiner.in_still_water`: a
        target at rest, volume reverberation). Its source is that water, hidden in the
        reverberation band or measured as still: no echo beyond the span is scanned for."""
        speed = self.c * (alpha - 1.0) / (alpha + 1.0)
        return self.refiner.ghost_of_rest(speed) and self.refiner.in_still_water(t_s, alpha)

    def _ghost_that_passed(self, t_s: float, alpha: float, fit: Refinement) -> bool:
        """Whether an echo fitted inside the span (detected at ``t_s`` s, ``alpha``) is the
        ghost of an echo beyond it fitted lately, where that echo puts its ghost (one tone
        spacing's speed inward, within :data:`~hil.estimation.refine.GHOST_HOPS` of its
        comb's time) and stronger than it by :data:`GHOST_SOURCE_RATIO`: a ghost can pass
        the echo test at low SNR (its phases then happen to agree). Refused and counted."""
        if not self._last:
            return False
        for band in self.ghosts.bands(fit.alpha):
            side = band[0]
            found = self._follow_ghost(t_s, alpha, band, fit, timed=True)
            if found is not None:
                self._seen(found[0], found[1], side)
                self.count += 1
                return True
        return False

    def _follow_ghost(
        self, t_s: float, alpha: float, band: tuple[int, float, float], fit: Refinement, *,
        timed: bool,
    ) -> tuple[Refinement, int] | None:  # fmt: skip
        """The echo beyond the edge of ``band`` (side, and the speeds in m/s where the
        ghost's source may be: :meth:`GhostSources.bands`) fitted within
        :data:`GHOST_FOLLOW_HOPS` hops of a ghost detected at ``t_s`` (s) and ``alpha``
        (whose own fit is ``fit``) at a speed in that band, fitted again at its boundary that
        the ghost aligns with: ``(fit, hop index)`` where that fit is one echo beyond the
        span, stronger than the ghost's (:data:`GHOST_SOURCE_RATIO`); else None. ``timed``:
        the ghost's time must also lie within :data:`~hil.estimation.refine.GHOST_HOPS` of
        that boundary's comb, unless the ghost is at most
        :data:`~hil.estimation.refine.GHOST_LEAK_FRACTION` of the echo (a ghost two tone
        spacings out spreads further in time: measured 0.3-0.45 hop off at 0.06 of it)."""
        side, v_lo, v_hi = band
        last = self._last.get(side)
        if last is None:
            return None
        hop, t_fit, a_fit = last
        # The band is cut at the guard band's end, which a fit may pass.
        margin = self.ghosts.margin_mps
        if not v_lo - margin <= self.c * (a_fit - 1.0) / (a_fit + 1.0) <= v_hi + margin:
            return None
        t_b = self.ghosts.boundary(t_s, alpha, a_fit)
        if abs(t_b - t_fit) > GHOST_FOLLOW_HOPS * self.hop_s:
            return None
        period = self.hop_s / a_fit
        r = round((t_b - t_fit) / period)
        off = abs(t_b - t_fit - r * period)
        # Refitted at a boundary of the echo no later than the ghost's (GhostSources.not_after):
        # the warm start reads within a sixteenth of a lobe of it.
        back = round(
            (t_fit + r * period - self.ghosts.not_after(t_fit + r * period, a_fit, t_s)) / period
        )
        again = self.refiner.refine(t_fit + (r - back) * period, a_fit, hop + r - back)
        if again is None or not self._source(again, side, fit):
            return None
        if (
            timed
            and off > GHOST_HOPS * period
            and abs(fit.amplitude) > GHOST_LEAK_FRACTION * abs(again.amplitude)
        ):
            return None
        return again, hop + r - back

    def _scan_ghost(
        self, grid: SourceGrid, side: int, fit: Refinement
    ) -> tuple[Refinement, int] | None:
        """The source of a ghost (its own fit ``fit``) looked for on ``grid``
        (:meth:`~hil.estimation.gcas.ghost_source.GhostSources.grid`: speeds beyond the
        ``side`` edge) and refined: ``(fit, hop index)`` where it is one echo there, stronger
        than the ghost; else None."""
        best = self.ghosts.read(grid)
        if best is None:
            return None
        _, t_b, a_b, hop = best
        source = self.refiner.refine(t_b, a_b, hop)
        if source is None or not self._source(source, side, fit):
            return None
        if not self._outshines_inside(source, hop, side):
            return None
        return source, hop

    def _source(self, source: Refinement | None, side: int, ghost: Refinement) -> bool:
        """Whether ``source`` is one echo beyond the ``side`` edge that a ghost fitted as
        ``ghost`` may come from: stronger than it by :data:`GHOST_SOURCE_RATIO`."""
        if source is None or not source.is_echo(self.test):
            return False
        v = source.speed_mps(self.c)
        return (
            self.beyond(v)
            and side * v > 0
            and abs(source.amplitude) > GHOST_SOURCE_RATIO * abs(ghost.amplitude)
        )

    def _seen(self, fit: Refinement, hop_index: int, side: int) -> None:
        """Keep ``fit`` (ending hop ``hop_index``) as the latest beyond the ``side`` edge;
        the side's sighting is said at the first fit that follows another within
        :data:`GHOST_FOLLOW_HOPS` hops and whose ``M`` hops were all transmitted (hop
        ``M − 1`` on), with its time and speed: one fit may be noise's, and a fit of hops
        partly before the schedule's first is off in speed by more than the fit's resolution
        (a far echo's first boundaries: 34.86 m/s for 35 m/s at -5 dB)."""
        before = self._last.get(side)
        self._last[side] = (hop_index, fit.t_s, fit.alpha)
        name = CLOSING if side > 0 else OPENING
        if any(s.side == name for s in self.sightings):
            return
        if before is None or abs(fit.t_s - before[1]) > GHOST_FOLLOW_HOPS * self.hop_s:
            return
        if hop_index < self.m_hops - 1:
            return
        self.sightings.append(
            BeyondSpan(fit.t_s, int(hop_index), name, self.max_speed_mps, fit.speed_mps(self.c))
        )

    def _held(self, t_s: float, speed_mps: float) -> bool:
        """Whether an echo fitted near the edge within :data:`INSIDE_HOPS` hops before
        ``t_s`` (s), within one Doppler cell of ``speed_mps`` (m/s), was found not outshone:
        the same echo, checked once while it is followed (a check costs a scan)."""
        return any(
            t_s - t <= INSIDE_HOPS * self.hop_s and abs(v - speed_mps) <= self.cell_mps
            for t, v in self._inside
        )

    def _outshone(
        self, t_s: float, alpha: float, hop_index: int, side: int, fit: Refinement
    ) -> bool:
        """Whether the likelihood ``|C|²`` somewhere in the guard band past the ``side``
        edge exceeds the likelihood at ``fit``, an echo fitted inside the span within the
        guard band's width of that edge (detected at ``t_s``, ``alpha``, hop ``hop_index``):
        something beyond the span (an echo, or the ghost one tone spacing out of a slow echo
        the reverberation band hides) explains the detection better than the fit, which
        stopped short of it. A target inside the span near its edge outshines its own
        sidelobes beyond it."""
        at_fit = self.refiner.correlation(
            fit.t_s, fit.alpha, hop_index, np.array([fit.t_s]), np.array([fit.alpha])
        )
        if at_fit is None:
            return False
        peak = self._guard_peak(t_s, alpha, hop_index, side)
        if peak is None:
            return False
        power, _, a_peak = peak
        apart = abs(self.c * (a_peak - 1.0) / (a_peak + 1.0) - fit.speed_mps(self.c))
        return apart > self.resolution_mps and power > OUTSHINE * float(np.abs(at_fit[0]) ** 2)

    def _guard_peak(
        self, t_s: float, alpha: float, hop_index: int, side: int
    ) -> tuple[float, float, float] | None:
        """The guard band's best point past the ``side`` edge for a detection at ``t_s``
        (s), ``alpha``, hop ``hop_index``: ``(|C|², t_rx s, α)``; None where the input does
        not cover its hops."""
        c, ref = self.c, self.refiner
        half_v = ref.speed_span_mps
        v_edge = side * self.max_speed_mps
        lobe = 1.0 / (alpha * ref.spacing_hz)
        n_chunks = max(1, int(math.ceil(self.guard_mps / (2.0 * half_v))))
        n_v = max(3, int(math.ceil(2.0 * half_v / (0.5 * self.resolution_mps))) + 1)
        offsets_v = np.linspace(-half_v, half_v, n_v)
        offsets_t = np.linspace(-0.5 * lobe, 0.5 * lobe, SCAN_TIME_POINTS)
        best, best_t, best_a = -1.0, t_s, alpha
        for i in range(n_chunks):
            v_c = v_edge + side * half_v * (2 * i + 1)
            a_c = (c + v_c) / (c - v_c)
            # The comb of the edge hypothesis peaks (M − 1)/2 hops of the two time scales'
            # drift after the boundary of an echo at a_c.
            t_c = t_s - 0.5 * (self.m_hops - 1) * self.hop_s * (1.0 / alpha - 1.0 / a_c)
            vv = v_c + offsets_v[:, None] + 0.0 * offsets_t[None, :]
            tt = t_c + offsets_t[None, :] + 0.0 * offsets_v[:, None]
            corr = ref.correlation(t_c, a_c, hop_index, tt, (c + vv) / (c - vv))
            if corr is None:
                return None
            power = np.abs(corr) ** 2
            k = int(np.argmax(power))
            if power.flat[k] > best:
                best, best_t = float(power.flat[k]), float(tt.flat[k])
                best_a = float((c + vv.flat[k]) / (c - vv.flat[k]))
        return best, best_t, best_a

    def _outshines_inside(self, fit: Refinement, hop_index: int, side: int) -> bool:
        """Whether ``fit``, beyond the ``side`` edge (the boundary ending hop ``hop_index``),
        holds more likelihood ``|C|²`` than every speed inside the span within the guard
        band's width of that edge at its boundary (±½ grating lobe): else it is a lobe of an
        echo inside the span, one Doppler cell of a hop out (the ``M`` hops' phases advance
        by whole cycles there; ``att``, 28 m/s fitted at 30.46 m/s) or noise on its tail."""
        c, ref = self.c, self.refiner
        at_fit = ref.correlation(
            fit.t_s, fit.alpha, hop_index, np.array([fit.t_s]), np.array([fit.alpha])
        )
        if at_fit is None:
            return False
        power_fit = float(np.abs(at_fit[0]) ** 2)
        half_v = ref.speed_span_mps
        lobe = 1.0 / (fit.alpha * ref.spacing_hz)
        n_chunks = max(1, int(math.ceil(self.guard_mps / (2.0 * half_v))))
        n_v = max(3, int(math.ceil(2.0 * half_v / (0.5 * self.resolution_mps))) + 1)
        offsets_v = np.linspace(-half_v, half_v, n_v)[:, None]
        offsets_t = np.linspace(-0.5 * lobe, 0.5 * lobe, SCAN_TIME_POINTS)[None, :]
        for i in range(n_chunks):
            v_c = side * (self.max_speed_mps - half_v * (2 * i + 1))
            a_c = (c + v_c) / (c - v_c)
            vv = v_c + offsets_v + 0.0 * offsets_t
            tt = fit.t_s + offsets_t + 0.0 * offsets_v
            corr = ref.correlation(fit.t_s, a_c, hop_index, tt, (c + vv) / (c - vv))
            if corr is not None and float(np.max(np.abs(corr) ** 2)) >= power_fit:
                return False
        return True

    def _scan(self, t_s: float, alpha: float, hop_index: int, side: int) -> Refinement | None:
        """The guard band's best point past the ``side`` edge, refined; the fit if it is one
        echo beyond the span, else None."""
        c, ref = self.c, self.refiner
        peak = self._guard_peak(t_s, alpha, hop_index, side)
        if peak is None:
            return None
        _, best_t, best_a = peak
        fit = ref.refine(best_t, best_a, hop_index)
        if fit is None or not fit.is_echo(self.test) or not self.beyond(fit.speed_mps(c)):
            return None
        if side * fit.speed_mps(c) < 0 or not self._outshines_inside(fit, hop_index, side):
            return None
        return fit
