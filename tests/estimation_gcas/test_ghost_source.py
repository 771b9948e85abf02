"""Where the source of a ghost may be beyond the span (hil.estimation.gcas.ghost_source), on
att (tones 28.35-31.65 kHz, 1.1 kHz apart; a 30 m/s span)."""

from __future__ import annotations

import numpy as np
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
    return GhostSources(refiner, 30.0, inside_mps=0.5 * res, step_mps=res, cell_mps=2.5)


def test_the_sources_of_a_ghost_lie_one_two_or_three_tone_spacings_out() -> None:
    g = _sources()
    assert g.spacing_mps == pytest.approx([27.5, 55.0, 82.5])
    # 35 m/s: its tones read as their neighbours at 6.5-8.5 m/s, as the tones two apart at
    # -21.2 to -19.2 m/s; from either, the nearest closing band reaches 35 m/s.
    for ghost in (7.5, -20.0):
        side, lo, hi = g.bands(_alpha(ghost))[0]
        assert side == 1 and lo < 35.0 < hi and lo > 30.0
    # The neighbours' ratios give 34.02-36.04 m/s from 7.5 m/s, widened by half a cell; then
    # two and three spacings out (the tones' ratios), each side, beyond the span only (the
    # opening source one spacing out, -20 m/s, is inside it).
    bands = [(side, round(lo, 3), round(hi, 3)) for side, lo, hi in g.bands(_alpha(7.5))]
    assert bands == [
        (1, 32.774, 37.293), (1, 60.249, 64.765), (1, 88.725, 91.225),
        (-1, -49.786, -45.268), (-1, -76.271, -73.771),
    ]  # fmt: skip
    [(side, lo, hi), *_] = [b for b in g.bands(_alpha(-7.5)) if b[0] < 0]
    assert side == -1 and (lo, hi) == pytest.approx((-37.293, -32.774), abs=0.001)
    # Past the guard band (37.5 m/s): 45 m/s from its ghost at 17.5 m/s, 55 m/s from its
    # ghost three spacings in, at -27.6 m/s.
    assert g.bands(_alpha(17.5))[0] == (
        1,
        pytest.approx(42.76, abs=0.01),
        pytest.approx(47.28, abs=0.01),
    )
    assert g.bands(_alpha(-27.6))[0] == (
        1,
        pytest.approx(53.706, abs=0.001),
        pytest.approx(56.206, abs=0.001),
    )
    # From the span's edge plus half the M hops' resolution on.
    assert g.bands(_alpha(2.0))[0] == (
        1, pytest.approx(30.118, abs=0.001), pytest.approx(31.796, abs=0.001)
    )  # fmt: skip
    # Sources inside the span are not looked for: a ghost at 0 m/s has none one spacing out
    # on either side inside 52.76 m/s.
    assert [round(b[1], 2) for b in g.bands(_alpha(0.0))] == [52.76, 81.25, -57.28, -83.75]
    # The farthest source: a ghost on the edge three spacings in, plus the margin.
    assert GhostSources.farthest_mps(att_schedule().tones_hz, 30.0, C, 2.5) == pytest.approx(
        113.626, abs=0.001
    )


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
        _, lo, hi = g.bands(a_g)[0]  # the closing source one tone spacing out
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


def test_a_source_boundary_after_the_ghosts_is_moved_back_by_whole_hops() -> None:
    # An opening source's boundary that its ghost aligns with comes after the ghost's: at
    # -113 m/s (three spacings out of a ghost at -28 m/s) by 4.5 hops times the two time
    # scales' drift, 5.62 ms; read there, its fit would need input past the ghost's own.
    g = _sources()
    a_g, a_s = _alpha(-28.0), _alpha(-113.0)
    t_s = 0.5
    t_b = g.boundary(t_s, a_g, a_s)
    assert t_b - t_s == pytest.approx(0.00562, abs=1e-5)
    # Moved back by one hop of the source (10 ms / alpha), to the boundary before it.
    assert g.not_after(t_b, a_s, t_s) == pytest.approx(t_b - 0.01 / a_s, abs=1e-12)
    # A closing source's boundary comes before the ghost's and is kept.
    t_c = g.boundary(t_s, _alpha(7.5), _alpha(35.0))
    assert t_c < t_s and g.not_after(t_c, _alpha(35.0), t_s) == t_c


def test_the_boundaries_read_are_those_whose_shifted_tones_match_the_ghosts_on_enough_hops() -> (
    None
):
    # GhostSources.matching against its definition, boundary by boundary: the source's M hops
    # aligned with the ghost's (each boundary `back` hops before), their tones' ranks shifted,
    # equal to the ghost's codeword's on at least `need` hops; the order of `hops` kept.
    g = _sources()
    schedule = att_schedule()
    rank = np.searchsorted(np.unique(schedule.tones_hz), schedule.tones_hz)

    def agree(h: int, back: int, ghost_hop: int, shift: int) -> int:
        src = rank[schedule.hops(h + back - 9, 10).tone_index] + shift
        return int(np.count_nonzero(src == rank[schedule.hops(ghost_hop - 9, 10).tone_index]))

    rng = np.random.default_rng(5)
    for _ in range(400):
        ghost_hop, back = int(rng.integers(-20, 400)), int(rng.integers(-2, 3))
        shift, need = int(rng.integers(-3, 4)), int(rng.integers(0, 6))
        start = int(rng.integers(-30, 400))
        hops = list(range(start, start - 17, -1))
        if rng.random() < 0.3:
            hops = [int(h) for h in rng.permutation(hops)[:5]]
        expected = [h for h in hops if agree(h, back, ghost_hop, shift) >= need]
        assert g.matching(hops, back, ghost_hop, shift, need=need) == expected
    # One spacing out most boundaries of a period hold a matching hop, three out (where only
    # the lowest tone has a neighbour that far) about a third: what a scan reads.
    period = list(range(36, 19, -1))
    read = {n: sum(len(g.matching(period, 0, 36 - i, n, need=1)) for i in range(17)) / 17**2
            for n in (1, 2, 3)}  # fmt: skip
    assert read == pytest.approx({1: 0.907, 2: 0.744, 3: 0.370}, abs=0.001)


def _beyond_span_trial(
    monkeypatch: pytest.MonkeyPatch, need: int
) -> tuple[list[object], list[object], int, int]:
    """40 m/s closing from 90 m with a 30 m/s span at -10 dB, 1.5 s, the beyond-span scans
    reading the boundaries that match the ghost on at least ``need`` hops: the estimates,
    the sightings, the detections refused as the echo's, and the boundaries read."""
    from hil.estimation.gcas import ghost_source

    from .conftest import run_blocks
    from .test_scenes import _receiver

    monkeypatch.setattr(ghost_source, "MIN_BEYOND_MATCHES", need)
    read = [0]
    original = GhostSources.read

    def counted(self: GhostSources, grid: ghost_source.SourceGrid) -> object:
        read[0] += len(grid.hops)
        return original(self, grid)

    monkeypatch.setattr(GhostSources, "read", counted)
    rx = _receiver()
    est = run_blocks(rx, echo_samples(att_schedule(), 90.0, 40.0, 1.5, snr_db=-10.0, seed=4))
    return est, list(rx.beyond_span), rx.beyond_span_count, read[0]


@pytest.mark.slow
def test_a_source_beyond_the_span_is_read_only_where_its_ghost_can_hold_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # A ghost holds its source's energy on the hops where the source's tones, shifted, are
    # its codeword's; at -10 dB one such hop passes the threshold. Reading only the
    # boundaries with one (MIN_BEYOND_MATCHES) says the echo as reading every boundary of
    # the period does, the same estimates and refusals, reading fewer (measured: 64
    # against 102 boundaries).
    every = _beyond_span_trial(monkeypatch, 0)
    monkeypatch.undo()
    one = _beyond_span_trial(monkeypatch, 1)
    monkeypatch.undo()
    assert one[:3] == every[:3]
    [seen] = one[1]
    assert seen.hop_index == 11 and seen.speed_mps == pytest.approx(40.003, abs=1e-3)  # type: ignore[attr-defined]
    assert (one[3], every[3]) == (64, 102)
    # The rule inside the span (MIN_MATCH_FRACTION, 4 of 10 hops) would miss the boundaries
    # of the ghosts that hold 1-3 hops of this source: said 15 hops later.
    four = _beyond_span_trial(monkeypatch, 4)
    assert [s.hop_index for s in four[1]] == [26]  # type: ignore[attr-defined]
