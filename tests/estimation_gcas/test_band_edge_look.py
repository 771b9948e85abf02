"""The band-edge look for the ghost of an echo beyond the span (three-state: what it says,
what it costs), the refinement's look at a detection it is not to remember
(:meth:`hil.estimation.refine.CoherentRefiner.refine` with ``remember=False``, used on the
reverberation band's edge by :meth:`hil.estimation.gcas.beyond_span.BeyondSpanCheck.
in_band_ghost`), and whether a window is known to hold no still water
(:meth:`~hil.estimation.refine.CoherentRefiner.in_open_water`)."""

from __future__ import annotations

from typing import Any

import pytest

from hil.estimation.base import Estimate
from hil.estimation.gcas import ghost_source
from hil.estimation.gcas.beyond_span import BAND_LOOK_GAP_HOPS, BeyondSpanCheck
from hil.estimation.gcas.ghost_source import GhostSources
from hil.estimation.refine import CoherentRefiner

from .conftest import FS, C, att_schedule, echo_samples, make_gcas, run_blocks

HOP_S = 0.01


def _refiner_and_boundary(wall: bool = False) -> tuple[CoherentRefiner, float, float]:
    """A refiner fed 1.5 s of one echo at 50 m closing 8 m/s (+ a 20 dB wall at rest at 30 m
    with ``wall``), and the echo's boundary ending hop 90 (s) and time scale."""
    schedule = att_schedule()
    x = echo_samples(schedule, 50.0, 8.0, 1.5, snr_db=0.0, seed=3)
    if wall:
        x = x + echo_samples(schedule, 30.0, 0.0, 1.5, amplitude=10.0)
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(x, 0)
    t_tx = 91 * HOP_S
    return refiner, t_tx + 2.0 * (50.0 - 8.0 * t_tx) / (C + 8.0), (C + 8.0) / (C - 8.0)


def test_a_fit_not_remembered_leaves_no_echo_behind() -> None:
    refiner, t_rx, alpha = _refiner_and_boundary()
    look = refiner.refine(t_rx, alpha, 90, partners=False, remember=False)
    assert look is not None and look.is_echo(refiner.echo_test)
    assert abs(look.speed_mps(C) - 8.0) < 0.05
    assert refiner.known_echoes(t_rx + 2 * HOP_S) == []
    kept = refiner.refine(t_rx, alpha, 90, partners=False)
    assert kept is not None and (kept.t_s, kept.alpha) == (look.t_s, look.alpha)
    assert len(refiner.known_echoes(t_rx + 2 * HOP_S)) == 1


def test_open_water_is_known_only_where_the_still_water_is_measured_and_weak() -> None:
    refiner, t_rx, alpha = _refiner_and_boundary()
    walled, _, _ = _refiner_and_boundary(wall=True)
    assert refiner.in_open_water(t_rx, alpha)
    assert not walled.in_open_water(t_rx, alpha) and walled.in_still_water(t_rx, alpha)
    # Before the still-water streams cover the window (its first code period): not known.
    assert not refiner.in_open_water(0.12, alpha) and not refiner.in_still_water(0.12, alpha)


def _three_state_run(
    speed_mps: float, range_m: float, seed: int, monkeypatch: pytest.MonkeyPatch | None = None
) -> tuple[list[Estimate], list[dict[str, object]], list[tuple[int, int]]]:
    """2 s of a three-state echo at ``range_m`` closing at ``speed_mps`` at -10 dB (noise
    seeded by ``seed``) through the receiver (30 m/s span): its estimates, its notices and
    the ``(hop index, shift)`` of each likelihood reading made for a band-edge look."""
    schedule = att_schedule("three-state")
    readings: list[tuple[int, int]] = []
    if monkeypatch is not None:
        best_point = GhostSources.best_point

        def counted(self: GhostSources, *args: Any, **kwargs: Any) -> Any:
            # (t_s, alpha, v_lo, v_hi, ghost, ...): a band-edge look's readings name the ghost.
            if len(args) > 4 and args[4] is not None:
                readings.append(args[4])
            return best_point(self, *args, **kwargs)

        monkeypatch.setattr(GhostSources, "best_point", counted)
    x = echo_samples(schedule, range_m, speed_mps, 2.0, snr_db=-10.0, seed=seed)
    rx = make_gcas(schedule)
    estimates = run_blocks(rx, x)
    return estimates, [n.to_dict() for n in rx.notices()], readings


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_a_three_state_target_whose_only_ghost_is_in_the_band_is_said_once_and_not_estimated(
    seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Three-state (15 ms hops): 35 m/s with a 30 m/s span puts its only ghost at -1.67 m/s,
    # inside the reverberation band; at -10 dB nothing else of it is detected in 2 s.
    estimates, notices, readings = _three_state_run(35.0, 99.0, seed, monkeypatch)
    assert estimates == []
    assert [(n["notice"], n["side"]) for n in notices] == [("beyond_span", "closing")]
    assert abs(float(notices[0]["speed_mps"]) - 35.0) < 0.1  # type: ignore[arg-type]
    # Its source was looked for where a closing source's tones are read one spacing up.
    assert 1 in {shift for _, shift in readings}
    # Without the band-edge look the same input says nothing.
    monkeypatch.setattr(BeyondSpanCheck, "in_band_ghost", lambda *args: False)
    estimates, notices, _ = _three_state_run(35.0, 99.0, seed)
    assert estimates == [] and notices == []


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_a_slow_targets_band_edge_detections_cost_at_most_two_looks_an_edge_in_2_s(
    seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A target at 0.2 m/s is detected on both edges of the band at nearly every hop once
    # its window is known to be open water (a code period in); each edge's
    # look that finds nothing waits BAND_LOOK_GAP_HOPS (32) hops, then twice that: at most
    # two looks an edge in the 2 s, each one likelihood reading per band where a source
    # may lie (four bands: one and two spacings out, each side).
    estimates, notices, readings = _three_state_run(0.2, 40.0, seed, monkeypatch)
    assert notices == [] and estimates == []
    assert 4 <= len(readings) <= 16 and len(readings) % 4 == 0
    assert BAND_LOOK_GAP_HOPS == 32


def test_the_bands_name_their_tone_spacings_and_agree_with_the_plain_bands() -> None:
    schedule = att_schedule("three-state")
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    ghosts = GhostSources(refiner, 30.0, inside_mps=0.1, step_mps=0.15, cell_mps=1.0)
    # The ghost at -1.67 m/s of a closing 35 m/s source, one spacing (36.7 m/s) in.
    v_g = -1.67
    spaced = ghosts.spaced_bands((C + v_g) / (C - v_g))
    assert [(s, lo, hi) for s, _, lo, hi in spaced] == ghosts.bands((C + v_g) / (C - v_g))
    assert {(s, n) for s, n, _, _ in spaced} == {(1, 1), (1, 2), (-1, 1), (-1, 2)}
    (lo, hi) = next((lo, hi) for s, n, lo, hi in spaced if (s, n) == (1, 1))
    assert lo < 35.0 < hi


@pytest.mark.parametrize(
    ("seed", "said_hop", "said_mps", "said_at_four"), [(2, 46, 35.003, [83]), (3, 41, 35.000, [])]
)
def test_a_band_edge_look_reads_every_boundary_matching_the_ghost_on_one_hop(
    seed: int,
    said_hop: int,
    said_mps: float,
    said_at_four: list[int],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Three-state, 35 m/s from 95 m with a 30 m/s span at -10 dB: its only ghost is in the
    # band, and the ghost's codeword holds its source's shifted tones on 1-3 of the 10 hops
    # of the boundaries its source is found at. Read at every boundary matching on one hop
    # (MIN_BEYOND_MATCHES, as the scans read), it is said at its speed; reading only those
    # matching on 4 (the rule inside the span) says it 37 hops later (seed 2) or not at all.
    estimates, notices, _ = _three_state_run(35.0, 95.0, seed)
    assert estimates == []
    assert [(n["notice"], n["side"], n["hop_index"]) for n in notices] == [
        ("beyond_span", "closing", said_hop)
    ]
    assert float(notices[0]["speed_mps"]) == pytest.approx(said_mps, abs=1e-3)  # type: ignore[arg-type]
    monkeypatch.setattr(ghost_source, "MIN_BEYOND_MATCHES", 4)
    _, notices, _ = _three_state_run(35.0, 95.0, seed)
    assert [n["hop_index"] for n in notices] == said_at_four
