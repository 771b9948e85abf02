"""The copies a still-water background leaves of a moving echo, told from targets.

Behind :class:`~hil.estimation.still_water.StillWaterBackground` the input is
``y = x − mean of the last K still periods``; that mean holds, besides the still water, each
moving echo of those periods at ``1/K`` of its amplitude. So ``y`` carries, for every echo
received ``j`` still periods ago (``j = 1 .. K``), a sign-flipped copy at the range and speed
it was received with then, ``20·log10 K`` dB under it (18 dB at K = 8): an echo of the
target's own past, which GCAS fits like any echo. A strong target at 0 dB per-sample SNR
lifts them over the threshold (``second-10db-weaker`` in reverberation: 10–22 false
estimates per 2 s trial at the strong target's earlier ranges, measured on 4 seeds).

:class:`CopyVeto` drops an estimate that is such a copy: within :data:`COPY_GATE_M` and
:data:`COPY_GATE_MPS` of where an estimate it passed puts its target ``j`` still periods
earlier (the boundary ``j·Q`` hops back, whose echo the copy repeats; an estimate up to M + 2
hops from that boundary, moved to it at its speed: GCAS gives none in its first M hops), more
than :data:`COPY_GATE_M` from where that target is now, and at least :data:`COPY_MARGIN_DB`
weaker than that estimate (an estimate without an SNR of its own, NaN, is judged by position
alone). A target is never taken for its own copy: it is where it is now. A copy within
:data:`COPY_GATE_M` of its target (``v·j·Q`` ≤ 1 m: below 5.9 m/s at j = 1 on ``att``) is
kept. The cost: a second target at least 3 dB weaker at a stronger one's speed (to 1 m/s),
within 1 m of a range the stronger one held in the last K periods (``v·K·Q``: 13.6 m at
10 m/s), is dropped with the copies.
"""

from __future__ import annotations

import collections
import math

from hil.estimation.base import Estimate

#: Gates (m, m/s) within which an estimate sits on a copy: 1 m, one and a half grating lobes
#: (1/Δf of delay, 0.68 m on ``att``), and 1 m/s, 0.4 of a hop's Doppler cell. A copy is weak
#: and lies among the other copies of its target (``vQ`` apart, 1.7 m at 10 m/s): on
#: ``second-10db-weaker`` its fits sat 0.3 (its own lobe's side) to 0.85 m and up to 0.64 m/s
#: from where its source was.
COPY_GATE_M = 1.0
COPY_GATE_MPS = 1.0
#: A copy is weaker than the echo it repeats by ``20·log10 K_j`` in power, but GCAS's
#: ``snr_db`` is compressed (a copy 12 dB down read 6 dB under its source): an estimate at
#: least this much (dB) under the one it would copy is taken for the copy.
COPY_MARGIN_DB = 3.0


class CopyVeto:
    """Drop the copies of earlier estimates (module docstring): still period ``period_hops``
    (hops) of ``period_s`` (s), ``still_periods`` K, ``warmup`` (periods held before the mean
    is subtracted), GCAS's correlator length ``m_hops``."""

    def __init__(
        self, period_hops: int, period_s: float, still_periods: int, warmup: int, m_hops: int
    ) -> None:
        self.period_hops, self.period_s = int(period_hops), float(period_s)
        self.still_periods, self.warmup = int(still_periods), int(warmup)
        #: Hops either side of a copied boundary searched for an estimate of its target:
        #: GCAS gives none in its first M hops, nor where it missed one.
        self.reach_hops = int(m_hops) + 2
        # Estimates passed, by hop index; kept for K still periods.
        self._passed: dict[int, list[Estimate]] = collections.defaultdict(list)
        #: Estimates dropped as copies so far.
        self.dropped = 0

    def reset(self) -> None:
        """Forget the estimates passed (the background restarts)."""
        self._passed.clear()

    def filter(self, estimates: list[Estimate]) -> list[Estimate]:
        """``estimates`` less the copies (the background began at t = 0: at receive time
        ``t`` it holds ``floor(t / period_s)`` periods, at most K)."""
        out: list[Estimate] = []
        for e in estimates:
            if self._is_copy(e):
                self.dropped += 1
                continue
            out.append(e)
            self._passed[e.hop_index].append(e)
        if out:
            keep = (self.still_periods + 1) * self.period_hops + self.reach_hops
            oldest = max(e.hop_index for e in out) - keep
            for h in [h for h in self._passed if h < oldest]:
                del self._passed[h]
        return out

    def _is_copy(self, e: Estimate) -> bool:
        held = min(self.still_periods, math.floor(e.t_s / self.period_s + 1e-9))
        if held < self.warmup:
            return False  # nothing subtracted yet: no copies
        hop_s = self.period_s / self.period_hops
        for j in range(1, held + 1):
            then = e.hop_index - j * self.period_hops  # the boundary the copy repeats
            for h in range(then - self.reach_hops, then + self.reach_hops + 1):
                for old in self._passed.get(h, ()):
                    if abs(e.speed_mps - old.speed_mps) > COPY_GATE_MPS:
                        continue
                    # The passed estimate's target at the copied boundary, and now.
                    range_then = old.range_m - old.speed_mps * (then - h) * hop_s
                    range_now = old.range_m - old.speed_mps * (e.hop_index - h) * hop_s
                    if abs(e.range_m - range_then) > COPY_GATE_M:
                        continue
                    if abs(e.range_m - range_now) <= COPY_GATE_M:
                        continue  # the target itself (or its copy on it): kept
                    if not e.snr_db > old.snr_db - COPY_MARGIN_DB:  # weaker, or no SNR
                        return True
        return False
