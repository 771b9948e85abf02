"""Echoes the reverberation band hides: never reported, measured when what they leak is near.

A target slower than the band's edge (:mod:`hil.estimation.reverb_band`) is detected only on
the band's edge hypotheses, and those detections are refused: it is never reported, so the
refinement never measures it (:mod:`hil.estimation.refine`). What it leaks elsewhere is then
not known to come from it:

- its **ghost**, every tone read as its neighbour, one tone spacing's speed out
  (``c Δf / (2 f_c)``, 27.5 m/s on ``att``): a target at 2-3.3 m/s leaks into -24.7 to
  -25.5 m/s, inside a ±25.72 m/s span;
- its **Doppler sidelobes** past the opposite edge of the band (a strong 3.1 m/s target,
  +5 dB, fitted at -3.43 m/s about 0.3 m from its range; a unit correlator's response falls
  only as ``sinc`` of the Doppler offset);
- the ghosts of those sidelobes (a 2.6 m/s target at 0 dB: +24.3 m/s, 22 m off its range).

Each of these fits, at low SNR or beside a strong source, can pass the echo test. A still
point echo (a wall) is measured too, at rest (:meth:`HiddenEchoes._fit_still`), where the
fits toward rest find something there but no echo: far above a moving target (att, +13 to
+20 dB at 0 and -10 dB) it otherwise stays in the target's fits and moves them a grating lobe
off. It is measured for, and taken out of, every detection, those where it leaks itself
included (near rest and at its ghosts, a whole tone spacing from rest): left in them, it
hid every target there. A measured
echo's leaks are handled by the refinement (the echo is taken out of every other detection's
input within a few hops, and a detection where its ghost peaks and weaker than it is refused:
:meth:`~hil.estimation.refine.CoherentRefiner.ghost_of_known`). So the band's refused
detections are kept here (:meth:`HiddenEchoes.note`), and before a detection outside the band
is refined, the hidden echoes detected within :data:`~hil.estimation.refine.KNOWN_HOPS` hops
of it are measured (:meth:`HiddenEchoes.measure_near`): refined at their last boundary before
the detection, so that a fit that is one echo of the schedule becomes one of the echoes the
refinement knows. Nothing hidden is ever reported; a fit that is no echo (clutter, the leak
of another echo, noise) changes nothing.

Cost: a refused detection costs a note. A note is fitted at most once, only for a detection
it could outshine and when it is not the ghost of an echo already known; a note within half
a hop of a boundary of a hidden echo fitted lately is that echo's and is not fitted; the fit
of a hidden echo found before starts from where that fit puts it (one fit per
:data:`~hil.estimation.refine.KNOWN_HOPS` + 1 hops for a target the band hides); a side
whose measurement finds no echo waits (:data:`MAX_WAIT_HOPS`), and longer while its
measurements find the same echo there but never one echo (a still echo:
:data:`STILL_WAIT_HOPS`). Refinements per 0.8 s (att, 2 trials each, before → now, of them
here): a target the band hides at +5 dB 142 → 127 (53; its ghosts are then refused without a
fit), the same at 0 dB in reverberation (0 dB SRR) 127 → 120 (48), a 24-25.7 m/s target at 0
dB, whose ghost falls on the band's edge, 113 → 131 (18), a 22-25.7 m/s target at -10 dB in
reverberation (-10 dB SRR) 128 → 173 (45).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hil.estimation.refine import KNOWN_HOPS, STILL_KNOWN_HOPS, CoherentRefiner, EchoTest

#: A hidden echo is measured for a detection when its edge detection's statistic (above the
#: noise mean) is at least LEAK_FRACTION of the detection's: what an echo leaks is weaker
#: than the echo (a ghost collects part of its hops, a sidelobe a fraction of a cell's
#: response), and its edge detection keeps most of it (the edge is within a Doppler cell of
#: it). A strong target's own ghost inside the band is then not fitted at each of its
#: detections (at 0 dB: a fit per note, 5 times the receiver's CPU).
LEAK_FRACTION = 0.5

#: A hidden echo's fit is kept (and taken out of other detections) when its hops' coherence,
#: over all hops or over runs of consecutive hops, is at least HIDDEN_FRACTION of one echo's
#: at its SNR (the refinement's own test asks 0.8 and 0.85: :data:`hil.estimation.gcas.
#: readout.ECHO_TEST`). Inside the band the still reverberation shares the echo's cells: its
#: fits reach 0.80 over all hops and 0.84 over runs (att, 0 dB SRR, -10 dB SNR), and taking
#: such a fit out of the input turns the reverberation's ghosts at 25 m/s into echoes.
#: Targets the band hides measured 0.977-1.02 at -20 to +5 dB (1.5-3.3 m/s, 170 fits).
HIDDEN_FRACTION = 0.9

#: A note within SAME_HOP hops of the boundary of a hidden echo fitted lately is that echo's
#: detection: the edge hypotheses' combs put its time 0.0-0.22 hop from the echo's (att,
#: 1.5-3.3 m/s, +5 dB; the opposite edge's notes, its sidelobe, the furthest).
SAME_HOP = 0.5

#: Longest wait, in hops, between two measurements on one side of the band after
#: measurements that found no echo (a strong echo's leaks into the band: its ghost's Doppler
#: sidelobes, noise): a hidden echo whose fit failed at low SNR is measured again at most
#: this many hops later.
MAX_WAIT_HOPS = 8

#: Longest wait, in hops, between two measurements on one side of the band while they find
#: the same echo there (its notes on one another's boundaries, :data:`SAME_HOP`) and a fit of
#: each collects an echo's E/N0 yet none is one echo, over at least the ``M`` hops of one
#: window: an echo slower than the fits reach (a still echo: a wall, a mooring; its fits
#: from 1.5-3.5 m/s climb toward rest, 17-29 dB at 0 dB per-sample SNR, and stop short of it)
#: or diffuse clutter, which the band hides and the module does not seek (:meth:`HiddenEchoes.
#: _starts`). Measured again every MAX_WAIT_HOPS hops (att, a still echo at 40 m, 0 dB, 2 s:
#: 57 measurements, 174 fits, 0.20 s of CPU, a third of the receiver's) it was never found.
#: A target the band hides fits one echo (0.977-1.02 of one echo's coherence) once its
#: window is full, and a weak one fails short of an echo's E/N0: both keep the shorter wait.
STILL_WAIT_HOPS = 64

#: A still echo found (:meth:`HiddenEchoes._fit_still`) is fitted again at its edge detections
#: once its fit is this many hops old (its amplitude and delay kept up to date; att, a wall
#: 20 dB above a target at -10 dB: no other measurement of it for 60 hops, its fit let go,
#: and the target's fits a grating lobe off).
STILL_REFRESH_HOPS = MAX_WAIT_HOPS


@dataclass
class _Note:
    """A detection refused on the band's edge: boundary receive time ``t_s`` (s), time scale
    ``alpha`` (the edge hypothesis's, with its parabolic offset), the hop it ends
    ``hop_index``; ``measured`` once it has been fitted or found to be a measured echo's."""

    t_s: float
    alpha: float
    hop_index: int
    strength: float
    measured: bool = False


class HiddenEchoes:
    """The band's refused detections of one receiver, measured on demand (module docstring).

    ``refiner`` is the receiver's refinement (each fit here is remembered by it as any fit
    that is one echo); ``hop_s`` the hop length (s)."""

    def __init__(self, refiner: CoherentRefiner, hop_s: float) -> None:
        self.refiner = refiner
        self.hop_s = float(hop_s)
        #: How long (s) the refinement keeps a still echo's fit (:data:`~hil.estimation.
        #: refine.STILL_KNOWN_HOPS`).
        self.still_known_s = STILL_KNOWN_HOPS * self.hop_s
        #: What a hidden echo's fit must reach to be kept (:data:`HIDDEN_FRACTION`).
        usual = refiner.echo_test
        self.test = EchoTest(HIDDEN_FRACTION, HIDDEN_FRACTION, usual.min_e_over_n0_db)
        self.reset()

    def reset(self) -> None:
        """Forget every note and fit (a new input, or a gap)."""
        self._notes: list[_Note] = []
        #: Fits made here that were one echo: (hop index, boundary time s, α).
        self._fits: list[tuple[int, float, float]] = []
        #: Fits made here (each a refinement of a hidden echo), for diagnostics.
        self.fit_count = 0
        #: Per side of the band (+1 closing, −1 opening): the first hop whose notes are
        #: measured again after a measurement that found no echo, and the next wait (hops).
        self._next: dict[int, int] = {}
        self._wait: dict[int, int] = {}
        #: Per side: the latest hidden echo fitted there, (hop index, boundary time s, α).
        self._last: dict[int, tuple[int, float, float]] = {}
        #: The latest still echo fitted (:meth:`_fit_still`): (hop index, boundary time s, 1).
        self._still: tuple[int, float, float] | None = None
        #: Per side: the echoes whose measurements find something there but no one echo
        #: (:data:`STILL_WAIT_HOPS`): (hop index of the first such note, of the latest, the
        #: latest's boundary time s, α) each.
        self._unfound: dict[int, list[tuple[int, int, float, float]]] = {}

    def note(self, t_s: float, alpha: float, hop_index: int, strength: float) -> None:
        """Keep a detection refused on the band's edge (boundary ``t_s`` s, ``alpha``, ending
        hop ``hop_index``, the detector's statistic ``strength`` above its noise mean); notes
        older than :data:`KNOWN_HOPS` hops are dropped."""
        self._forget(t_s)
        self._notes.append(_Note(float(t_s), float(alpha), int(hop_index), float(strength)))

    def measure_near(self, t_s: float, strength: float) -> None:
        """Measure the hidden echoes noted within :data:`KNOWN_HOPS` hops of a detection at
        ``t_s`` (s) of the detector's statistic ``strength`` above its noise mean: each note
        that could outshine it (noted at least :data:`LEAK_FRACTION` of its strength), that
        no fit here explains and that is not itself the ghost of an echo the refinement
        knows, refined at its last boundary at or before ``t_s`` (the refinement keeps a fit
        that is one echo). After a measurement that finds no echo, that side of the band
        waits 1, 2, 4 … up to :data:`MAX_WAIT_HOPS` hops before the next (up to
        :data:`STILL_WAIT_HOPS` while it finds the same echo there and never one echo)."""
        self._forget(t_s)
        for note in self._notes:
            if note.measured or note.strength < LEAK_FRACTION * strength:
                continue
            if self._refresh_still(note, t_s):
                continue
            side = 1 if note.alpha > 1.0 else -1
            if note.hop_index < self._next.get(side, note.hop_index):
                continue
            note.measured = True
            if self._explained(note) or self.refiner.ghost_of_known(
                note.t_s, note.alpha, note.hop_index, strength=note.strength
            ):
                continue
            found, strong = self._measure(note, t_s)
            if found:
                self._next.pop(side, None)
                self._wait.pop(side, None)
                self._unfound.pop(side, None)
            else:
                wait = self._wait.get(side, 1)
                self._next[side] = note.hop_index + wait
                self._wait[side] = min(2 * wait, self._longest_wait(note, side, strong))

    def _refresh_still(self, note: _Note, t_s: float) -> bool:
        """Fit the still echo found before again at its last boundary at or before ``t_s``
        (s) where that fit is :data:`STILL_REFRESH_HOPS` hops old or more, beside ``note``
        (an edge detection strong enough to outshine the detection); whether it did. Its
        edge detections are read as the leaks of an echo the refinement knows and are not
        measured otherwise (their boundaries lie up to 0.65 hop from the still echo's: the
        edge hypothesis's comb, and the hop it names), and the refinement lets its fit go
        after :data:`~hil.estimation.refine.STILL_KNOWN_HOPS`."""
        if self._still is None:
            return False
        hop0, t0, _ = self._still
        k = int(math.floor((t_s - t0) / self.hop_s))
        if k < STILL_REFRESH_HOPS:
            return False
        note.measured = True
        side = 1 if note.alpha > 1.0 else -1
        self._fit_still(t0 + k * self.hop_s, hop0 + k, side)
        return True

    def _longest_wait(self, note: _Note, side: int, strong: bool) -> int:
        """The longest wait (hops) on ``side`` after a measurement of ``note`` that found no
        echo, ``strong`` where a fit of it found its maximum and collected an echo's E/N0:
        :data:`STILL_WAIT_HOPS` where such measurements have found the same echo (its
        boundary within :data:`SAME_HOP` hops of where the latest puts it at rest or at its
        notes' edge speed) over at least
        the ``M`` hops of one window, else :data:`MAX_WAIT_HOPS` (a measurement whose fits
        found nothing leaves that echo's record as it was)."""
        if not strong:
            return MAX_WAIT_HOPS
        first = note.hop_index
        kept = []
        for before in self._unfound.get(side, []):
            if note.hop_index - before[1] > 2 * STILL_WAIT_HOPS:
                continue  # not seen for two of the longest waits: forgotten
            # The echo is slower than its notes' edge speed: its boundary lies between
            # where a still echo and one at the edge's speed put it.
            hops = (note.hop_index - before[1]) * self.hop_s
            still, edge = before[2] + hops, before[2] + hops / before[3]
            tol = SAME_HOP * self.hop_s
            if min(still, edge) - tol <= note.t_s <= max(still, edge) + tol:
                first = min(first, before[0])
            else:
                kept.append(before)
        self._unfound[side] = [*kept, (first, note.hop_index, note.t_s, note.alpha)]
        if note.hop_index - first >= self.refiner.m_hops:
            return STILL_WAIT_HOPS
        return MAX_WAIT_HOPS

    def _measure(self, note: _Note, t_s: float) -> tuple[bool, bool]:
        """Refine the hidden echo of ``note`` at its last boundary at or before ``t_s`` (s)
        from each of :meth:`_starts` until a fit is one echo by :attr:`test`, first from the
        speed of the echo last fitted on its side within :data:`MAX_WAIT_HOPS` hops (the
        same echo, most often: one fit instead of up to four); whether one was, and whether
        a fit found its maximum and collected an echo's E/N0 (something is there). The still
        echo found before is fitted first; where the moving fits find something but no echo,
        a still echo is fitted. A still echo found
        is something there but no moving echo: the side waits as where none is found (its
        notes measured every hop instead, their fits found spurious slow echoes beside it:
        att, a lone 0.05 m/s echo, -3.9 m/s 5 m from it, reported when followed)."""
        period = self.hop_s / note.alpha
        k = max(0, int(math.floor((t_s - note.t_s) / period)))
        t_b, hop = note.t_s + k * period, note.hop_index + k
        side = 1 if note.alpha > 1.0 else -1
        starts = [(t_b, a) for a in self._starts(note.alpha)]
        last = self._last.get(side)
        if last is not None and last[2] != 1.0 and hop - last[0] <= MAX_WAIT_HOPS:
            # Where that echo's fit puts this boundary: the edge's comb moves the note's time
            # by up to a quarter hop, and from there the refinement would take the echo's
            # own recent fit out of its input as another echo's.
            t_pred = last[1] + (hop - last[0]) * self.hop_s / last[2]
            if abs(t_pred - t_b) <= SAME_HOP * self.hop_s:
                starts.insert(0, (t_pred, last[2]))
        # A still echo's boundary: the still water's hops are the transmit's, of length T.
        k_still = max(0, int(math.floor((t_s - note.t_s) / self.hop_s)))
        rest_b = (note.t_s + k_still * self.hop_s, note.hop_index + k_still)
        if self._still is not None:
            # The still echo fitted before, on either side (its edge detections are on
            # both): most often the same (one fit, not five), at its last boundary.
            k_known = int(math.floor((t_s - self._still[1]) / self.hop_s))
            if k_known >= 0:
                t_known = self._still[1] + k_known * self.hop_s
                found, _ = self._fit_still(t_known, self._still[0] + k_known, side)
                if found:
                    return False, True
        # The refinement remembers the fits that pass the test it is given: here this one.
        strong = False
        for t_start, alpha in starts:
            fit = self.refiner.refine(t_start, alpha, hop, self.test)
            self.fit_count += 1
            if fit is None:
                return False, False
            if fit.is_echo(self.test):
                self._fits.append((hop, fit.t_s, fit.alpha))
                self._last[side] = (hop, fit.t_s, fit.alpha)
                return True, True
            strong = strong or (fit.found and fit.e_over_n0_db >= self.test.min_e_over_n0_db)
        if strong:
            # Something there that no moving echo's fit explains: a still point echo?
            self._fit_still(rest_b[0], rest_b[1], side)
        return False, strong

    def _fit_still(self, t_b: float, hop: int, side: int) -> tuple[bool, bool]:
        """Fit a still echo (time scale 1) at the boundary ``t_b`` (s) ending hop ``hop``
        (:meth:`~hil.estimation.refine.CoherentRefiner.refine_still`, which remembers it
        where it is one echo by :attr:`test`): whether it is, and whether something is there
        (the fit found its maximum and collected an echo's E/N0)."""
        fit = self.refiner.refine_still(t_b, hop, self.test)
        self.fit_count += 1
        if fit is None:
            return False, False
        if fit.is_echo(self.test):
            self._fits.append((hop, fit.t_s, 1.0))
            self._last[side] = self._still = (hop, fit.t_s, 1.0)
            return True, True
        return False, fit.found and fit.e_over_n0_db >= self.test.min_e_over_n0_db

    def _starts(self, alpha: float) -> list[float]:
        """Time scales to start a hidden echo's fit from: the edge detection's, then every
        two speed spans (one fit's reach) toward zero speed while at least two spans from it
        (1 m/s on ``att``). An edge detection's speed is the edge's, up to the band's width
        from the echo's, and a fit started there can stop on a sidelobe of the likelihood.
        An echo slower than that is the still water's (a wall, a moored object): these fits
        stop short of it, and it is fitted at rest instead (:meth:`_fit_still`) where they
        find something but no echo (``measure_near``)."""
        c, step = self.refiner.c, 2.0 * self.refiner.speed_span_mps
        v = c * (alpha - 1.0) / (alpha + 1.0)
        n = max(1, int(math.floor(abs(v) / step)))
        speeds = [v - math.copysign(i * step, v) for i in range(n)]
        return [(c + s) / (c - s) for s in speeds]

    def _explained(self, note: _Note) -> bool:
        """Whether an echo fitted here lately puts a boundary within :data:`SAME_HOP` hops
        of the note's (its detection on either edge of the band, whose time the edge
        hypothesis's comb moves by up to a quarter hop)."""
        for hop, t_fit, a_fit in self._fits:
            t_pred = t_fit + (note.hop_index - hop) * self.hop_s / a_fit
            if abs(t_pred - note.t_s) <= SAME_HOP * self.hop_s:
                return True
        return False

    def _forget(self, t_s: float) -> None:
        """Drop notes and fits more than :data:`KNOWN_HOPS` hops before ``t_s`` (s)."""
        oldest = t_s - KNOWN_HOPS * self.hop_s
        self._notes = [n for n in self._notes if n.t_s >= oldest]
        self._fits = [f for f in self._fits if f[1] >= oldest]
