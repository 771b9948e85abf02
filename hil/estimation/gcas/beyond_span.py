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

The guard band only serves this test; nothing beyond the span is ever reported as an
estimate. A target further than the guard band past the edge leaves no edge detection that
fits an echo there: it is refused (ghosts, edge leaks) without a sighting.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hil.estimation.refine import CoherentRefiner, EchoTest, Refinement

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

#: Hops after a fit beyond the span within which an edge detection is checked by fitting
#: that echo again where it puts the detection's boundary, before a scan.
FOLLOW_HOPS = 3

#: Longest wait, in hops, between two scans of an edge for detections not fitted as one echo
#: after scans that found nothing (module docstring): an echo beyond the span that appears
#: then is said at most this many hops late (0.3 s on ``att``).
MAX_SCAN_GAP_HOPS = 64

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
        self.reset()

    @staticmethod
    def guard_width_mps(sound_speed_mps: float, center_hz: float, hop_s: float) -> float:
        """The guard band's width past the edge, :data:`GUARD_CELLS` Doppler cells of one
        hop, m/s."""
        return GUARD_CELLS * sound_speed_mps / (2.0 * center_hz * hop_s)

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

    def beyond(self, speed_mps: float) -> bool:
        """Whether a fitted speed (m/s) lies beyond the span (by more than half the
        resolution of the ``M`` hops)."""
        return abs(speed_mps) > self.max_speed_mps + 0.5 * self.resolution_mps

    def near_edge(self, speed_mps: float, within_mps: float) -> bool:
        """Whether a fitted speed (m/s) lies within ``within_mps`` of the edge or past it."""
        return abs(speed_mps) > self.max_speed_mps - within_mps

    def _seen_on(self, side: int) -> bool:
        """Whether an echo beyond the ``side`` edge (+1 closing, −1 opening) was seen."""
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
        self, t_s: float, alpha: float, hop_index: int, side: int, fit: Refinement | None
    ) -> bool:
        """Whether a detection at ``t_s`` (s), time scale ``alpha``, ending hop
        ``hop_index`` on the ``side`` edge (+1 closing, −1 opening, 0 not on an edge) with
        its own ``fit`` is the leak of an echo beyond the span, or is fitted past it
        (refused either way, counted; the first sighting per side kept)."""
        echo = fit is not None and fit.is_echo(self.test)
        own = math.nan if fit is None else fit.speed_mps(self.c)
        if echo and self.beyond(own):
            self._seen(fit, hop_index, 1 if own > 0 else -1)  # type: ignore[arg-type]
            self.count += 1
            return True
        if echo:
            if not self.near_edge(own, self.guard_mps):
                return False
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
        elif side == 0 or self._inside_echo_at(t_s, side):
            # An edge detection not fitted as an echo is checked unless an echo inside the
            # span near that edge holds its detections.
            return False
        found = self._follow(hop_index, side)
        if found is None and (echo or hop_index >= self._next_scan.get(side, hop_index)):
            found = self._scan(t_s, alpha, hop_index, side)
            if not echo:
                self._scanned(hop_index, side, found is not None)
        if found is None:
            return False
        self._seen(found, hop_index, side)
        self.count += 1
        return True

    def _follow(self, hop_index: int, side: int) -> Refinement | None:
        """The echo beyond the ``side`` edge fitted within :data:`FOLLOW_HOPS` hops before
        ``hop_index``, fitted again where it puts this boundary (the refinement's warm
        start: a few evaluations, where a scan costs hundreds); None where there is none or
        the fit is not one echo beyond the span. Each fit is one of the echoes the
        refinement takes out of other detections (its ghosts then collect what noise
        does)."""
        last = self._last.get(side)
        if last is None or not 1 <= hop_index - last[0] <= FOLLOW_HOPS:
            return None
        hop, t_fit, a_fit = last
        t_pred = t_fit + (hop_index - hop) * self.hop_s / a_fit
        fit = self.refiner.refine(t_pred, a_fit, hop_index)
        if fit is None or not fit.is_echo(self.test) or not self.beyond(fit.speed_mps(self.c)):
            return None
        return fit

    def _scanned(self, hop_index: int, side: int, found: bool) -> None:
        """After a scan of the ``side`` edge at ``hop_index`` for a detection not fitted as
        one echo: the waits start again where it ``found`` the echo, else the next is
        doubled (module docstring)."""
        if found:
            self._next_scan.pop(side, None)
            self._scan_gap.pop(side, None)
            return
        gap = self._scan_gap.get(side, 1)
        self._next_scan[side] = hop_index + gap
        self._scan_gap[side] = min(2 * gap, MAX_SCAN_GAP_HOPS)

    def _seen(self, fit: Refinement, hop_index: int, side: int) -> None:
        self._last[side] = (hop_index, fit.t_s, fit.alpha)
        name = CLOSING if side > 0 else OPENING
        if all(s.side != name for s in self.sightings):
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
        if side * fit.speed_mps(c) < 0:
            return None
        return fit
