"""Echoes in the still reverberation's cells that have shown themselves as one point echo.

With the reverberation band off, an echo slower than one Doppler resolution cell shares its
Doppler cells with the still reverberation. Its hops' coherence is then judged against the
interference measured on the other tones of its windows
(:func:`~hil.estimation.reverb_band.reverberation_coherence`), not against white noise: the
reverberation sits at the tones, and a still target's coherence falls short of one echo's in
white noise on the hops whose tones it loads (0.74-0.87 of it, att at 0 dB SRR). A patch of
near reverberation that one fit takes for an echo (a few scatterers in one range cell, each
tone answered with its own complex gain) passes that relative test too: its neighbours load
the other tones as much as it loads its own. What tells them apart is the white-noise test
itself, on the hops whose tones the reverberation leaves clear: a point echo passes it there,
on about half of its hops or more (measured: a still target at 40 m, 0 and −10 dB per-sample
SNR in reverberation at 0 dB SRR: on 93 of 181 and 99 of 156 fits, never more than 10 hops
apart); a patch of scatterers does not (sim-03's near water at 5-17 m: 1 of about 60 fits).

So :class:`PointEchoes` keeps the echoes in those cells that passed the white-noise test
(:meth:`PointEchoes.note`), and the relative test keeps a detection only where one of them
predicts it (:meth:`PointEchoes.predicts`): the same echo, at most :data:`CONFIRM_PERIODS`
code periods after it last passed (the hops whose tones the reverberation loads recur with
the code period).

Sparse volume reverberation also holds scatterers resolved one by one: each is a point echo
at rest, which no test of one echo tells from a still target (sim-03's near water, 0.01
scatterers/m³ from 5 m: still echoes at 5.8, 7.2, 7.9, 9.3, 10.0 and 10.8 m in one trial,
each passing the white-noise test). A still echo among :data:`CROWD` or more other still
echoes confirmed within :data:`CROWD_RANGE_M` of it, and not :data:`CROWD_LEVEL` times
stronger than their median, is that field (:meth:`PointEchoes.crowded`): clutter, as a
clutter map of the still water would say. A still target alone, or standing out of the
field, is kept. The field's echoes are counted wherever they lie outside the echo's own
main lobe, its grating lobes (``1/Δf`` apart, Δf the tone spacing) included: in near
reverberation the fits land on grating lobes of the scatterers (sim-03: still echoes 0.67-0.73 m
apart, one lobe on att), a range no better than a scatterer's; a still target alone keeps its
lobe (seeded scenes at 40 m: every fit within 0.03 m).
"""

from __future__ import annotations

from dataclasses import dataclass

#: Code periods a point echo stays confirmed after it last passed the white-noise test.
CONFIRM_PERIODS = 2

#: Doppler resolution cells (:func:`~hil.estimation.reverb_band.doppler_resolution_mps`)
#: a detection's speed may differ from the confirmed echo's: the fits of one still target
#: in reverberation read within ±0.11 m/s (att, 0.25 m/s cells).
SPEED_CELLS = 2.0

#: Other still echoes around a still echo that make it part of a field of scatterers.
CROWD = 2
#: How far (m, in range) those others are counted: two thirds of the range a hop's echoes
#: span (``c T_h/2``, 7.5 m on att). Sparse near water held scatterers 3.7-4.3 m apart in
#: sim-03 (two of them and their grating lobes at 5.1-5.8 and 8.7-9.4 m).
CROWD_RANGE_M = 5.0
#: A still echo this many times the field's median amplitude (6 dB) stands out of it.
CROWD_LEVEL = 2.0


@dataclass(frozen=True)
class _Confirmed:
    hop_index: int
    t_s: float
    alpha: float
    amplitude: float


class PointEchoes:
    """The point echoes confirmed lately in the still reverberation's cells (module
    docstring).

    ``hop_s``: the schedule's hop length (s); ``period_hops``: hops per code period;
    ``main_lobe_s``: the likelihood's main peak width in time (``1/B``, s), how far a
    detection may be from where a confirmed echo puts that hop's boundary; ``cell_mps``: one
    Doppler resolution cell (m/s) of the ``M``-hop fit; ``c``: sound speed (m/s).

    >>> echoes = PointEchoes(0.01, 17, 3.0e-4, 0.25, 1500.0)
    >>> echoes.note(40, 0.5, 1.0, 0.3)
    >>> echoes.predicts(45, 0.55, 1.0), echoes.predicts(45, 0.5507, 1.0)
    (True, False)
    >>> echoes.predicts(40 + 2 * 17 + 1, 0.5 + 0.35, 1.0)
    False
    >>> echoes.note(41, 0.5199667, 1.0, 0.3)  # 5.6 m beyond (0.5525, 45): not counted
    >>> echoes.note(42, 0.5226, 1.0, 0.3)  # its own main lobe: itself
    >>> echoes.crowded(45, 0.5525, 1.0, 0.3)  # the first one, 1.9 m short of it: alone
    False
    >>> echoes.note(43, 0.5313, 1.0, 0.3)  # 0.9 m short of it: a second other
    >>> echoes.crowded(45, 0.5525, 1.0, 0.3), echoes.crowded(45, 0.5525, 1.0, 0.8)
    (True, False)
    """

    def __init__(
        self, hop_s: float, period_hops: int, main_lobe_s: float, cell_mps: float, c: float
    ) -> None:
        self._hop_s = hop_s
        self._hops = CONFIRM_PERIODS * period_hops
        self._lobe_s = main_lobe_s
        self._speed_tol = SPEED_CELLS * cell_mps
        self._c = c
        self._echoes: list[_Confirmed] = []

    def reset(self) -> None:
        """Forget every confirmed echo."""
        self._echoes = []

    def note(self, hop_index: int, t_s: float, alpha: float, amplitude: float) -> None:
        """An echo in the reverberation's cells passed the white-noise test: the boundary
        ending hop ``hop_index`` received at ``t_s`` (s), time scale ``alpha``, fitted
        amplitude ``|β|``. It replaces the notes it predicts (the same echo's earlier ones);
        notes too old are dropped."""
        kept = [
            e
            for e in self._echoes
            if hop_index - e.hop_index <= self._hops and not self._same(e, hop_index, t_s, alpha)
        ]
        self._echoes = [*kept, _Confirmed(hop_index, t_s, alpha, amplitude)]

    def crowded(self, hop_index: int, t_s: float, alpha: float, amplitude: float) -> bool:
        """Whether a still echo (within :data:`SPEED_CELLS` cells of rest) at ``t_s`` (s),
        ending hop ``hop_index``, of fitted amplitude ``|β|``, lies in a field of still
        scatterers: :data:`CROWD` other still echoes confirmed lately within
        :data:`CROWD_RANGE_M` of it (outside its main lobe), and it is not
        :data:`CROWD_LEVEL` times their median amplitude (module docstring)."""
        if not self._still(alpha):
            return False
        reach_s = 2.0 * CROWD_RANGE_M / self._c
        others = []
        for e in self._echoes:
            if not (0 <= hop_index - e.hop_index <= self._hops and self._still(e.alpha)):
                continue
            offset = e.t_s + (hop_index - e.hop_index) * self._hop_s / e.alpha - t_s
            if abs(offset) > reach_s or abs(offset) <= self._lobe_s:
                continue
            others.append(e.amplitude)
        if len(others) < CROWD:
            return False
        others.sort()
        mid = len(others) // 2
        median = others[mid] if len(others) % 2 else 0.5 * (others[mid - 1] + others[mid])
        return amplitude < CROWD_LEVEL * median

    def _still(self, alpha: float) -> bool:
        return abs(self._c * (alpha - 1) / (alpha + 1)) <= self._speed_tol

    def predicts(self, hop_index: int, t_s: float, alpha: float) -> bool:
        """Whether a confirmed echo at most :data:`CONFIRM_PERIODS` code periods old puts
        the boundary ending hop ``hop_index`` within one main lobe of ``t_s`` (s) at a speed
        within :data:`SPEED_CELLS` cells of the time scale ``alpha``'s."""
        return any(
            0 <= hop_index - e.hop_index <= self._hops and self._same(e, hop_index, t_s, alpha)
            for e in self._echoes
        )

    def _same(self, e: _Confirmed, hop_index: int, t_s: float, alpha: float) -> bool:
        c = self._c
        speed, speed_e = c * (alpha - 1) / (alpha + 1), c * (e.alpha - 1) / (e.alpha + 1)
        if abs(speed - speed_e) > self._speed_tol:
            return False
        t_pred = e.t_s + (hop_index - e.hop_index) * self._hop_s / e.alpha
        return abs(t_pred - t_s) <= self._lobe_s
