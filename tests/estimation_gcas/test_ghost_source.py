"""Where the source of a ghost may be beyond the span (hil.estimation.gcas.ghost_source), on
att (tones 28.35-31.65 kHz, 1.1 kHz apart; a 30 m/s span, its guard band to 37.5 m/s)."""

from __future__ import annotations

import pytest

from hil.estimation.gcas.ghost_source import GhostSources
from hil.estimation.refine import CoherentRefiner

from .conftest import FS, C, att_schedule, echo_samples


def _alpha(v: float) -> float:
    return (C + v) / (C - v)


def _speed(a: float) -> float:
    return C * (a - 1.0) / (a + 1.0)


def _sources(refiner: CoherentRefiner | None = None) -> GhostSources:
    refiner = refiner or CoherentRefiner(att_schedule(), FS, 10, C, 0.5, 37.5)
    res = C / (2.0 * 31_650.0 * 10 * 0.01)  # the M hops' Doppler resolution, m/s
    return GhostSources(
        refiner, 30.0, inside_mps=0.5 * res, guard_mps=7.5, step_mps=res, cell_mps=2.5
    )


def test_the_sources_of_a_ghost_lie_one_or_two_tone_spacings_out() -> None:
    g = _sources()
    assert g.spacing_mps == pytest.approx([27.5, 55.0])
    # 35 m/s: its tones read as their neighbours at 6.5-8.5 m/s, as the tones two apart at
    # -21.2 to -19.2 m/s; from either, the source's band reaches 35 m/s.
    for ghost in (7.5, -20.0):
        [(side, lo, hi)] = g.bands(_alpha(ghost))
        assert side == 1 and lo < 35.0 < hi and lo > 30.0 and hi <= 37.5
    # The neighbours' ratios give 34.02-36.04 m/s from 7.5 m/s, widened by half a cell.
    [(side, lo, hi)] = g.bands(_alpha(7.5))
    assert (lo, hi) == pytest.approx((32.774, 37.293), abs=0.001)
    [(side, lo, hi)] = g.bands(_alpha(-7.5))
    assert side == -1 and (lo, hi) == pytest.approx((-37.293, -32.774), abs=0.001)
    # Up to the guard band's end, from the span's edge plus half the M hops' resolution.
    assert g.bands(_alpha(12.0)) == [(1, pytest.approx(37.272, abs=0.001), 37.5)]
    assert g.bands(_alpha(2.0)) == [
        (1, pytest.approx(30.118, abs=0.001), pytest.approx(31.796, abs=0.001))
    ]
    # Sources inside the span or past the guard band are not looked for.
    for ghost in (0.0, 15.0, -15.0):
        assert g.bands(_alpha(ghost)) == []


def test_the_likelihood_finds_the_source_and_its_hop_from_a_ghost() -> None:
    # A 35 m/s echo at -10 dB: from a ghost at 7.5 m/s where its comb peaks, the scan over a
    # code period's hops returns the source's own hop, its boundary and its speed.
    schedule = att_schedule()
    r0, v = 50.0, 35.0
    x = echo_samples(schedule, r0, v, 1.0, snr_db=-10.0, seed=2)
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 37.5)
    refiner.push(x, 0)
    g = _sources(refiner)
    a_g, a_v = _alpha(7.5), _alpha(v)
    for hop in (60, 61, 75):
        h = schedule.hops(hop, 1)
        t_end = float(h.start_s[0] + h.duration_s[0])
        t_true = (t_end * (C - v) + 2.0 * r0) / (C + v)  # the boundary of hop `hop`, s
        t_ghost = t_true + 0.5 * 9 * 0.01 * (1.0 / a_g - 1.0 / a_v)
        [(_, lo, hi)] = g.bands(a_g)
        peak = g.peak(t_ghost, a_g, lo, hi)
        assert peak is not None
        t_b, a_b, hop_b = peak
        # On the grid's nearest point (its steps: a quarter lobe, 0.24 m/s); refined, the
        # source itself.
        lobe = 1.0 / (a_v * 1100.0)
        assert hop_b == hop and abs(t_b - t_true) <= 0.125 * lobe
        assert _speed(a_b) == pytest.approx(v, abs=0.12)
        fit = refiner.refine(t_b, a_b, hop_b)
        assert fit is not None and fit.speed_mps(C) == pytest.approx(v, abs=0.05)
        assert abs(fit.t_s - t_true) < 0.02 * lobe
    # No input yet: nothing.
    assert _sources().peak(0.5, a_g, 33.0, 37.5) is None
