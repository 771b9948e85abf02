"""How the beyond-span check uses its guard band (hil.estimation.gcas.beyond_span): for
detections not fitted as one echo, after scans that found nothing, each edge waits 1, 2, 4 …
up to MAX_SCAN_GAP_HOPS hops; a scan that finds the echo starts the waits again; an echo fit
near the edge after a sighting is scanned every time (there the scan decides what is
reported); an echo fit near the edge that the guard band outshines is refused, one that
outshines it is kept and not checked again while followed. The refiner here is a stand-in
that only answers the scan's questions."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from hil.estimation.gcas.beyond_span import MAX_SCAN_GAP_HOPS, BeyondSpanCheck
from hil.estimation.refine import CoherentRefiner, EchoTest

from .conftest import FS, att_schedule

C = 1500.0
TEST = EchoTest(fraction=0.5, run_fraction=0.5, min_e_over_n0_db=12.0)


@dataclass
class _Fit:
    alpha: float
    t_s: float = 1.0
    echo: bool = True

    def speed_mps(self, c: float) -> float:
        return c * (self.alpha - 1.0) / (self.alpha + 1.0)

    def is_echo(self, test: EchoTest) -> bool:
        return self.echo


def _alpha(v: float) -> float:
    return (C + v) / (C - v)


class _Refiner:
    """Answers the scan: a flat likelihood, and (where ``beyond_at`` is set) one echo at that
    speed for the fit started from the scan's best point."""

    c, m_hops, speed_span_mps, spacing_hz = C, 10, 2.0, 100.0
    schedule = att_schedule()

    def __init__(self) -> None:
        self.scans: list[int] = []
        self.beyond_at: float | None = None
        self.hop = 0
        #: ``|C|²`` at a fit (a one-point call), over the guard band and inside the span
        #: near its edge (grids about a speed past the 30 m/s edge, or inside it).
        self.at_fit, self.in_guard, self.inside = 1.0, 1.0, 0.5

    def correlation(self, t_c: float, a_c: float, hop: int, tt: Any, aa: Any) -> np.ndarray:
        if np.size(tt) == 1:
            return np.full(np.shape(tt), np.sqrt(self.at_fit))
        if abs(C * (a_c - 1.0) / (a_c + 1.0)) < 30.0:
            return np.full(np.shape(tt), np.sqrt(self.inside))
        if not self.scans or self.scans[-1] != hop:
            self.scans.append(hop)
        return np.full(np.shape(tt), np.sqrt(self.in_guard))

    def refine(self, t_s: float, alpha: float, hop: int) -> _Fit | None:
        return None if self.beyond_at is None else _Fit(_alpha(self.beyond_at))


def _check(refiner: _Refiner) -> BeyondSpanCheck:
    return BeyondSpanCheck(
        refiner,
        30.0,
        TEST,
        hop_s=0.01,
        center_hz=30_000.0,
        f_max_hz=35_000.0,  # type: ignore[arg-type]
    )


def test_a_fruitless_edge_is_scanned_with_doubling_waits() -> None:
    refiner = _Refiner()
    check = _check(refiner)
    for hop in range(300):
        assert not check.check(
            1.0 + hop * 0.01, _alpha(30.0), hop, 1, _Fit(_alpha(29.9), echo=False)
        )
    expected, hop, gap = [], 0, 1
    while hop < 300:
        expected.append(hop)
        hop, gap = hop + gap, min(2 * gap, MAX_SCAN_GAP_HOPS)
    assert refiner.scans == expected
    assert expected[:9] == [0, 1, 3, 7, 15, 31, 63, 127, 191]
    # The other edge has its own waits.
    assert not check.check(4.0, _alpha(-30.0), 300, -1, None)
    assert refiner.scans[-1] == 300


def test_a_scan_that_finds_the_echo_starts_the_waits_again() -> None:
    refiner = _Refiner()
    check = _check(refiner)
    not_echo = _Fit(_alpha(29.9), echo=False)
    for hop in range(8):
        check.check(1.0, _alpha(30.0), hop, 1, not_echo)
    assert refiner.scans == [0, 1, 3, 7]
    refiner.beyond_at = 33.0  # an echo beyond the span appears: the next scan finds it
    assert check.check(1.0, _alpha(30.0), 15, 1, not_echo)
    assert check.sightings == [] and check.count == 1  # said once a second fit follows
    # Followed from that fit while it lasts (no scan), and said then; once it cannot be
    # followed, scanned at once: the waits started again.
    assert check.check(1.01, _alpha(30.0), 16, 1, not_echo)
    assert [s.side for s in check.sightings] == ["closing"] and check.count == 2
    assert check.sightings[0].hop_index == 16
    refiner.beyond_at = None
    assert not check.check(1.0, _alpha(30.0), 30, 1, not_echo)
    assert refiner.scans == [0, 1, 3, 7, 15, 30]


def test_an_echo_fit_near_the_edge_after_a_sighting_is_scanned_every_time() -> None:
    refiner = _Refiner()
    check = _check(refiner)
    refiner.beyond_at = 33.0
    for hop in (9, 10):  # a fit, and a second one that says it
        assert check.check(1.0, _alpha(30.0), hop, 1, _Fit(_alpha(29.9), echo=False))
    assert len(check.sightings) == 1
    refiner.beyond_at = None
    near = _Fit(_alpha(29.95))  # one echo, within a Doppler cell of the edge
    for hop in range(20, 30):
        assert not check.check(1.0, _alpha(30.0), hop, 1, near)
    assert refiner.scans == [9, *range(20, 30)]


def test_an_echo_fit_short_of_something_stronger_beyond_the_edge_is_refused() -> None:
    """The ghost of a slow echo one tone spacing out lies beyond the span; refined from the
    edge, its fit stops inside (24.5-25.3 m/s on a ±25.72 m/s span, docs/results.md): the
    guard band past the edge holds more than the fit does."""
    refiner = _Refiner()
    check = _check(refiner)
    refiner.at_fit, refiner.in_guard = 1.0, 5.0
    assert check.check(1.0, _alpha(28.0), 3, 0, _Fit(_alpha(28.0)))
    assert check.count == 1 and check.sightings == []  # refused, not said: nothing fitted
    # A target near the edge outshines its own sidelobes beyond it: kept, checked once
    # while it is followed hop by hop, checked again once it was lost for longer.
    refiner.at_fit, refiner.in_guard = 5.0, 1.0
    for hop in range(10, 16):
        assert not check.check(1.0 + hop * 0.01, _alpha(28.0), hop, 0, _Fit(_alpha(28.0)))
    assert refiner.scans == [3, 10]
    assert not check.check(1.2, _alpha(28.0), 20, 0, _Fit(_alpha(28.0)))
    assert refiner.scans == [3, 10, 20]
    # Further inside than the guard band's width (7.5 m/s here) nothing is checked.
    assert not check.check(1.3, _alpha(20.0), 30, 0, _Fit(_alpha(20.0)))
    assert refiner.scans == [3, 10, 20] and check.count == 1


def test_a_fit_beyond_the_edge_short_of_the_inside_is_refused_and_not_said() -> None:
    """A fit one Doppler cell past the edge is a lobe of an echo inside the span where the
    likelihood inside near the edge holds more than it: refused (as any fit beyond the span)
    but no sighting; a fit that outshines the inside is said at the second fit."""
    refiner = _Refiner()
    check = _check(refiner)
    refiner.inside = 2.0
    for hop in (10, 11, 12):
        assert check.check(1.0, _alpha(30.0), hop, 1, _Fit(_alpha(30.5)))
    assert check.sightings == [] and check.count == 3
    refiner.inside = 0.5
    for hop in (13, 14):
        assert check.check(1.0, _alpha(30.0), hop, 1, _Fit(_alpha(30.5)))
    assert [(s.side, s.hop_index) for s in check.sightings] == [("closing", 14)]
    # Fits of hops partly before the schedule's first (hop < M - 1) are not said.
    early = _check(refiner)
    for hop in (5, 6, 7, 8):
        assert early.check(1.0, _alpha(30.0), hop, 1, _Fit(_alpha(30.5)))
    assert early.sightings == [] and early.count == 4
    assert early.check(1.0, _alpha(30.0), 9, 1, _Fit(_alpha(30.5)))
    assert [s.hop_index for s in early.sightings] == [9]
    assert check.sightings[0].speed_mps == pytest.approx(30.5)


@pytest.mark.parametrize(
    ("spacings", "cells", "still", "ghost"),
    [(1, 0.0, True, True), (-1, 1.9, True, True), (2, -1.5, True, True), (1, 0.0, False, False),
     (1, 2.5, True, False), (-1, -3.0, True, False), (0, 1.0, True, False)],
)  # fmt: skip
def test_the_still_waters_ghost_is_told_by_its_speed_and_the_still_water(
    spacings: int, cells: float, still: bool, ghost: bool
) -> None:
    # The refiner's rule for a still echo's ghost speeds (within two Doppler cells of a hop
    # of a whole number of tone spacings' speed from rest: 27.5 m/s spacings, 2.5 m/s cells
    # on att), where the window holds still water; not the still water's own cells.
    refiner = _Refiner()
    att = CoherentRefiner(att_schedule(), FS, 10, C, 0.5, 30.0)
    refiner.ghost_of_rest = att.ghost_of_rest  # type: ignore[attr-defined]
    refiner.in_still_water = lambda t_s, alpha: still  # type: ignore[attr-defined]
    check = _check(refiner)
    speed = spacings * 27.5 + cells * 2.5
    assert check._ghost_of_still(1.0, _alpha(speed)) is ghost
