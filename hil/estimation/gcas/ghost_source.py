"""The echo beyond the Doppler span whose ghost a detection inside the span may be.

An echo at time scale ``α`` beyond the span reaches the Doppler grid as its ghosts, each
tone ``f_k`` read as the tone ``n`` spacings away, ``f_{k±n}``, at the hypothesis
``α_g = α f_k / f_{k±n}``: ``n`` tone spacings' speed inward (``n c Δf / (2 f_k)``,
27.0-29.1 m/s on ``att`` for ``n`` = 1, where the tones' ratios differ; :data:`SPACINGS`).
Below about 0 dB per-sample SNR such a ghost may be all that is detected of it: the tail of
its Doppler response on the span's edge hypothesis falls as ``sinc²`` of the offset and
stays under the threshold (``att``, 35 m/s with a 30 m/s span at -10 dB: no detection on the
edge in 2 s, 190 of its ghost at 7.3-8.1 m/s). Past the guard band
(:mod:`hil.estimation.gcas.beyond_span`) nothing else of it reaches the grid: its ghosts
are all there is to say it by. Every ``n`` up to the tones' count less one is looked for, as
any of them may be the one the grid holds (``att``, 55 m/s with a 30 m/s span: its ghosts
at 26.5-28.5 m/s (``n`` = 1, taken for the ghosts of its fit once fitted), about 0 m/s
(``n`` = 2, hidden by the reverberation band) and -27.6 m/s (``n`` = 3)).

So the source of a ghost is looked for where the ghost puts it: at the time scales ``α_g
f_{k±n} / f_k`` over the tones' ratios, widened by :data:`SPEED_MARGIN_CELLS` Doppler cells of
one hop (the detector's speed of a ghost, whose tones disagree), wherever they lie beyond the
span (from the edge plus half the ``M`` hops' resolution; the farthest, a ghost on the edge
``n`` spacings in, is :meth:`GhostSources.farthest_mps`). The ghost's comb peaks ``(M − 1)/2``
hops of the two time scales' drift after the boundary of the source's hops that it aligns with
(as :meth:`~hil.estimation.refine.CoherentRefiner. ghost_of_known` reads), but which of the
schedule's hops those are is not the ghost's own codeword: its tones are the source's shifted
by ``n``, which matches another codeword only on some hops. The likelihood ``|C(t_rx, α)|²`` is
therefore read at the hops of one code period whose boundary there puts the delay in ``[0,
period)`` and whose tones, shifted by ``n``, the ghost's codeword holds on at least
:data:`MIN_BEYOND_MATCHES` of its ``M`` hops (:meth:`GhostSources.matching`; on ``att``, M = 10,
91 % of the period's boundaries one spacing out, 74 % two and 37 % three, where fewer tones
have a neighbour that far), over the speeds in steps of the ``M`` hops' Doppler resolution (the
caller's) and ±:data:`TIME_HALF_LOBES` grating lobes about the boundary at :data:`TIME_POINTS`
times (the detector's time of a ghost is a tenth of a hop off at times, measured on ``att``);
its best point seeds the refinement, which finds the maximum from there (its own search spans
±½ lobe and the speed span). A coarse grid: this reading costs a few hundred of the
likelihood's evaluations per hop of the period. Measured on ``att``, M = 10, 35 m/s at -10 dB:
the source's own hop holds 4 times the likelihood of the next best (8987 against 2147).

The same geometry puts the source of a ghost inside the span, one to :data:`SPACINGS` tone
spacings either way (:meth:`GhostSources.inside_bands`, for
:mod:`hil.estimation.gcas.ghost_inside`). There the likelihood is read only at the hops
whose tones, shifted by the spacings, the ghost's codeword holds on at least
:data:`MIN_MATCH_FRACTION` of the ``M`` hops: with few hops and a weak source, noise on
another hop of the period can outdo the source's own.
"""

from __future__ import annotations

import itertools
import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from hil.estimation.refine import CoherentRefiner

#: Doppler cells of one hop (``c/(2 f_c T_h)``) by which the source's speeds predicted from
#: the tones' ratios are widened each way: the detector's speed of a ghost is that of
#: whichever tones it holds (``att``: 35 m/s's ghosts detected at 7.3-8.1 m/s, predicted
#: 6.5-8.5).
SPEED_MARGIN_CELLS = 0.5
#: Ghosts looked for: each tone read as the tone up to SPACINGS tone spacings away (at most
#: the tones' count less one; three on ``att``: 35 m/s's ghosts at 7.5 and -20 m/s, either
#: of which may pass the echo test at -10 dB; 55 m/s's at 27.5, 0 and -27.5 m/s).
SPACINGS = 3
#: Half-width of the time searched about the predicted boundary, in grating lobes
#: (``1/(α Δf)``), and the times read across it.
TIME_HALF_LOBES = 1.0
TIME_POINTS = 17
#: The least fraction of the ``M`` hops on which a source's tones, shifted by the ghost's
#: tone spacings, must be the ghost's codeword's for the ghost to be looked for there
#: (:meth:`GhostSources.matching`): a ghost collects the source's energy of those hops only.
MIN_MATCH_FRACTION = 0.4
#: The least number of the ``M`` hops on which a source beyond the span, its tones shifted by
#: the ghost's tone spacings, must be the ghost's codeword's for the ghost to be looked for
#: there: the ghost's codeword sum holds the source's energy on each hop that matches, and
#: one hop of a source the span does not hold can pass the threshold (``att`` at -10 dB
#: per-sample SNR: a hop's E/N0 about 20 dB). Measured on ``att``, M = 10, every hop of the
#: period read (35-55 m/s either side, 20 and 30 m/s spans, -15 to 0 dB, 1.5 s each): each
#: source found at a boundary matching 1-5 of the ghost's 10 hops (22 at 1 or 2), none at 0.
MIN_BEYOND_MATCHES = 1


class SourceGrid(NamedTuple):
    """Where the likelihood is read for the source of one ghost (:meth:`GhostSources.grid`):
    the middle speed's boundary ``t_c`` (s) and time scale ``a_mid``, the points' receive
    times ``tt`` (s) and time scales ``aa``, both of shape (speeds, times), and the source's
    ``hops`` read (each the last hop of a boundary, latest first)."""

    t_c: float
    a_mid: float
    tt: NDArray[np.float64]
    aa: NDArray[np.float64]
    hops: list[int]


def _ratios(tones_hz: NDArray[np.float64]) -> list[tuple[float, float]]:
    """The ratios ``f_{k+n}/f_k`` of the tones ``n`` = 1 … :data:`SPACINGS` apart (at most
    the tones' count less one), least and greatest, for ``tones_hz`` (Hz, any order)."""
    tones = np.unique(np.asarray(tones_hz, dtype=np.float64))
    return [
        (float(np.min(tones[n:] / tones[:-n])), float(np.max(tones[n:] / tones[:-n])))
        for n in range(1, min(SPACINGS, tones.size - 1) + 1)
    ]


class GhostSources:
    """Where the source of a ghost may be (module docstring) for ``refiner``'s schedule: the
    span ``max_speed_mps`` (m/s), beyond each edge from the edge plus ``inside_mps`` (m/s) on,
    searched with speed steps ``step_mps`` (m/s); ``cell_mps``, one Doppler cell of a hop
    (m/s), sets the margin (:data:`SPEED_MARGIN_CELLS`)."""

    def __init__(
        self, refiner: CoherentRefiner, max_speed_mps: float, *, inside_mps: float,
        step_mps: float, cell_mps: float,
    ) -> None:  # fmt: skip
        self.refiner = refiner
        self.c = refiner.c
        self.max_speed_mps = float(max_speed_mps)
        self.inside_mps = float(inside_mps)
        self.step_mps, self.margin_mps = float(step_mps), SPEED_MARGIN_CELLS * float(cell_mps)
        schedule = refiner.schedule
        tones = np.unique(np.asarray(schedule.tones_hz, dtype=np.float64))
        #: The ratios ``f_{k+n}/f_k`` of tones ``n`` = 1 … :data:`SPACINGS` apart, least and
        #: greatest.
        self.ratios = _ratios(tones)
        #: The ghosts' speed offsets, ``n c Δf / (2 f_c)`` for ``n`` = 1 … :data:`SPACINGS`
        #: (m/s; ``Δf`` the least tone spacing, ``f_c`` the tones' centre).
        f_c = 0.5 * float(tones[0] + tones[-1])
        self.spacing_mps = [
            n * self.c * refiner.spacing_hz / (2.0 * f_c) for n in range(1, len(self.ratios) + 1)
        ]
        self.schedule = schedule
        #: Each tone's rank by frequency (the schedule's tone index → rank), shape (K,).
        self._rank = np.searchsorted(tones, np.asarray(schedule.tones_hz, dtype=np.float64))
        self.m_hops = refiner.m_hops
        self.hop_s = float(schedule.hop_s)

    @staticmethod
    def farthest_mps(
        tones_hz: NDArray[np.float64], max_speed_mps: float, sound_speed_mps: float,
        cell_mps: float,
    ) -> float:  # fmt: skip
        """The fastest source (m/s) of a ghost inside the span ``±max_speed_mps`` (m/s) on
        tones ``tones_hz`` (Hz): a ghost on the edge, :data:`SPACINGS` tone spacings in (at
        the tones' greatest ratio), widened by the margin (``cell_mps``, one Doppler cell of
        a hop, m/s). The refinement's windows must reach it."""
        c = float(sound_speed_mps)
        a_edge = (c + max_speed_mps) / (c - max_speed_mps)
        a = a_edge * _ratios(np.asarray(tones_hz, dtype=np.float64))[-1][1]
        return c * (a - 1.0) / (a + 1.0) + SPEED_MARGIN_CELLS * float(cell_mps)

    def _speed(self, alpha: float) -> float:
        return self.c * (alpha - 1.0) / (alpha + 1.0)

    def bands(self, alpha: float) -> list[tuple[int, float, float]]:
        """The speeds (m/s) where the source of a ghost detected at time scale ``alpha`` may
        be beyond the span: ``(side, v_lo, v_hi)`` per edge (+1 closing, −1 opening) and
        tone spacings ``n`` (ascending), ``v_lo < v_hi``; none where no source lies there."""
        return [(side, lo, hi) for side, _, lo, hi in self.spaced_bands(alpha)]

    def spaced_bands(self, alpha: float) -> list[tuple[int, int, float, float]]:
        """:meth:`bands` with each band's tone spacings: ``(side, n, v_lo, v_hi)``. The
        ghost's tones' rank less its source's is ``side * n`` (a closing source's tone
        ``f_k`` is read as ``f_{k+n}``), the ``shift`` of :meth:`peak`'s ``ghost``."""
        out = []
        for side, (n, (ratio_lo, ratio_hi)) in itertools.product(
            (1, -1), enumerate(self.ratios, start=1)
        ):
            # Closing source: its tone f_k read as f_{k+n}, α = α_g f_{k+n} / f_k.
            r_lo, r_hi = (ratio_lo, ratio_hi) if side > 0 else (1.0 / ratio_hi, 1.0 / ratio_lo)
            v_lo = self._speed(alpha * r_lo) - self.margin_mps
            v_hi = self._speed(alpha * r_hi) + self.margin_mps
            edge_in = side * (self.max_speed_mps + self.inside_mps)
            lo, hi = (max(v_lo, edge_in), v_hi) if side > 0 else (v_lo, min(v_hi, edge_in))
            if lo < hi:
                out.append((side, n, lo, hi))
        return out

    def inside_bands(self, alpha: float, still_mps: float) -> list[tuple[int, float, float]]:
        """The speeds (m/s) where the source of a ghost detected at time scale ``alpha`` may
        be inside the span: ``(shift, v_lo, v_hi)`` for each tone spacings ``n`` and
        direction, ``shift`` the ghost's tone's rank less the source's (``+n``: the source's
        tones read ``n`` spacings up, the source the faster), cut to the span ``±max_speed_mps``
        and to outside the still reverberation's cells ``|v| < still_mps`` (m/s; a source
        there is hidden by the reverberation band: :mod:`hil.estimation.gcas.hidden_echoes`),
        nearest the ghost first; none where no source lies there."""
        v_max, ghost = self.max_speed_mps, self._speed(alpha)
        out = []
        for n, (ratio_lo, ratio_hi) in enumerate(self.ratios, start=1):
            for shift, r_lo, r_hi in (
                (n, ratio_lo, ratio_hi),
                (-n, 1.0 / ratio_hi, 1.0 / ratio_lo),
            ):
                v_lo = max(self._speed(alpha * r_lo) - self.margin_mps, -v_max)
                v_hi = min(self._speed(alpha * r_hi) + self.margin_mps, v_max)
                # A band across rest keeps its parts outside the reverberation's cells.
                for lo, hi in ((v_lo, min(v_hi, -still_mps)), (max(v_lo, still_mps), v_hi)):
                    if lo < hi:
                        out.append((shift, lo, hi))
        return sorted(out, key=lambda b: abs(0.5 * (b[1] + b[2]) - ghost))

    def boundary(self, t_s: float, alpha: float, alpha_source: float) -> float:
        """The source's boundary (s) that a ghost detected at ``t_s`` (s) and time scale
        ``alpha`` aligns with, for a source at ``alpha_source``: its comb peaks ``(M − 1)/2``
        hops of the two time scales' drift after it."""
        return t_s - 0.5 * (self.m_hops - 1) * self.hop_s * (1.0 / alpha - 1.0 / alpha_source)

    def not_after(self, t_b: float, alpha_source: float, t_s: float) -> float:
        """The source's boundary ``t_b`` (s, time scale ``alpha_source``) moved back by whole
        hops of the source until it is no later than ``t_s`` (s), the ghost's boundary: an
        opening source's boundary that the ghost aligns with comes after the ghost's
        (:meth:`boundary`; 5.6 ms at -113 m/s for a ghost at -28 m/s), its hops' windows in
        input the receiver may not have read when the ghost is decided (the refinement reads
        each hop's window about the boundary it starts from, as far past it as past the
        ghost's). The source's boundaries before it are the same echo, and so the fit does
        not depend on how the input was cut."""
        late = t_b - t_s
        return (
            t_b - math.ceil(late * alpha_source / self.hop_s) * self.hop_s / alpha_source
            if late > 0
            else t_b
        )

    def peak(
        self, t_s: float, alpha: float, v_lo: float, v_hi: float,
        ghost: tuple[int, int] | None = None,
    ) -> tuple[float, float, int] | None:  # fmt: skip
        """:meth:`best_point` without its likelihood, for a source inside the span (hops
        matching on :data:`MIN_MATCH_FRACTION` of the ``M`` hops): ``(t_rx s, α, hop
        index)``."""
        need = math.ceil(MIN_MATCH_FRACTION * self.m_hops)
        best = self.best_point(t_s, alpha, v_lo, v_hi, ghost, need)
        return None if best is None else best[1:]

    def best_point(
        self, t_s: float, alpha: float, v_lo: float, v_hi: float,
        ghost: tuple[int, int] | None = None, need: int | None = None,
        time_points: int = TIME_POINTS,
    ) -> tuple[float, float, float, int] | None:  # fmt: skip
        """The likelihood's best point over the source's speeds ``[v_lo, v_hi]`` (m/s) for
        a ghost detected at ``t_s`` (s) and ``alpha``: ``(|C|², t_rx s, α, hop index)``
        (the likelihood the refinement maximises), over the hops of :meth:`grid` (every hop
        of one code period, or with ``ghost`` only those whose tones match on at least
        ``need`` of the ``M`` hops; default :data:`MIN_BEYOND_MATCHES`, a source beyond the
        span); None where the input covers none of them."""
        return self.read(self.grid(t_s, alpha, v_lo, v_hi, ghost, need, time_points))

    def grid(
        self, t_s: float, alpha: float, v_lo: float, v_hi: float,
        ghost: tuple[int, int] | None = None, need: int | None = None,
        time_points: int = TIME_POINTS,
    ) -> SourceGrid:  # fmt: skip
        """Where :meth:`best_point` reads the likelihood for a ghost detected at ``t_s`` (s)
        and ``alpha``, its source at speeds ``[v_lo, v_hi]`` (m/s): the points over the
        speeds in steps of ``step_mps`` and ``time_points`` times across
        ±:data:`TIME_HALF_LOBES` grating lobes (module docstring), at every hop of one code
        period. With ``ghost`` = ``(hop index, shift)``, the ghost's boundary and its tones'
        rank less the source's (:meth:`spaced_bands`, :meth:`inside_bands`), only the hops
        whose boundary the ghost aligns with holds the ghost's tones shifted on at least
        ``need`` of the ``M`` hops (:meth:`matching`; default :data:`MIN_BEYOND_MATCHES`): a
        ghost holds only those hops of its source, so where none match it cannot be that
        boundary's ghost."""
        c, ref = self.c, self.refiner
        n_v = max(2, int(math.ceil((v_hi - v_lo) / self.step_mps)) + 1)
        speeds = np.linspace(v_lo, v_hi, n_v)
        alphas = (c + speeds) / (c - speeds)
        a_mid = float(alphas[n_v // 2])
        t_c = self.boundary(t_s, alpha, a_mid)
        lobe = 1.0 / (a_mid * ref.spacing_hz)
        offsets = TIME_HALF_LOBES * lobe * np.linspace(-1.0, 1.0, time_points)
        # Each speed's boundary drifts with its own time scale about the middle one's.
        t_v = np.array([self.boundary(t_s, alpha, float(a)) for a in alphas]) - t_c
        t_c = self.not_after(t_c + float(np.max(t_v)) + TIME_HALF_LOBES * lobe, a_mid, t_s) - (
            float(np.max(t_v)) + TIME_HALF_LOBES * lobe
        )  # fmt: skip
        tt = t_c + t_v[:, None] + offsets[None, :]
        aa = np.repeat(alphas[:, None], time_points, axis=1)
        hops: list[int] = list(self._hops_ending_before(t_c))
        if ghost is not None:
            # The boundary the ghost aligns with lies whole hops of the source after t_c.
            back = round((self.boundary(t_s, alpha, a_mid) - t_c) * a_mid / self.hop_s)
            need = MIN_BEYOND_MATCHES if need is None else need
            hops = self.matching(hops, back, *ghost, need=need)
        return SourceGrid(t_c, a_mid, tt, aa, hops)

    def read(self, grid: SourceGrid) -> tuple[float, float, float, int] | None:
        """The likelihood's best point on ``grid`` (:meth:`grid`): ``(|C|², t_rx s, α, hop
        index)``, the first hop's where two are equal; None where the input covers none of
        its hops."""
        best: tuple[float, float, float, int] | None = None
        for hop in grid.hops:
            corr = self.refiner.correlation(grid.t_c, grid.a_mid, hop, grid.tt, grid.aa)
            if corr is None:
                continue
            power: NDArray[np.float64] = np.abs(corr) ** 2
            k = int(np.argmax(power))
            if best is None or power.flat[k] > best[0]:
                best = (float(power.flat[k]), float(grid.tt.flat[k]), float(grid.aa.flat[k]), hop)
        return best

    def matching(
        self, hops: list[int], back: int, ghost_hop: int, shift: int, *, need: int | None = None
    ) -> list[int]:
        """Those of ``hops`` (the source's boundaries, each ``back`` hops before the one the
        ghost aligns with) whose aligned ``M`` hops' tones, ranked and shifted by ``shift``,
        are the tones of the ghost's ``M`` hops (ending ``ghost_hop``) on at least ``need``
        of them (default :data:`MIN_MATCH_FRACTION` of ``M``): where fewer agree the ghost
        holds too little of the source to be detected and pass the echo test. Order kept."""
        if not hops:
            return []
        m = self.m_hops
        if need is None:
            need = math.ceil(MIN_MATCH_FRACTION * m)
        ghost_tones = self._rank[self.schedule.hops(ghost_hop - m + 1, m).tone_index]
        # One read of the schedule over every boundary's M hops; window i ends hop lo + i.
        lo, hi = min(hops) + back, max(hops) + back
        shifted = self._rank[self.schedule.hops(lo - m + 1, hi - lo + m).tone_index] + shift
        windows = np.lib.stride_tricks.sliding_window_view(shifted, m)
        agree = np.count_nonzero(windows == ghost_tones, axis=1)
        keep = agree[np.asarray(hops) + back - lo] >= need
        return [h for h, k in zip(hops, keep.tolist(), strict=True) if k]

    def _hops_ending_before(self, t_s: float) -> range:
        """The hops of one code period whose transmit end is at most ``t_s`` (s) and more
        than one period before it (a delay in ``[0, period)``), latest first."""
        sch = self.schedule
        after = int(sch.locate(np.array([t_s]))[0])  # the hop transmitted at t_s
        return range(after - 1, after - 1 - sch.period_hops, -1)
