"""Trapezoidal and triangular profiles against the closed-form motion equations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_devices.stage.motion import Path, Piece, plan_move, plan_stop


def analytic_trapezoid(t: np.ndarray, d: float, v: float, a: float) -> np.ndarray:
    """Position (mm) of a rest-to-rest move of d > 0 mm (closed form, independent code)."""
    vp = min(v, math.sqrt(a * d))
    ta = vp / a
    tc = d / vp - ta  # cruise duration (0 for a triangle)
    total = 2 * ta + tc
    t = np.clip(t, 0.0, total)
    acc = 0.5 * a * t**2
    cruise = 0.5 * a * ta**2 + vp * (t - ta)
    dec = d - 0.5 * a * (total - t) ** 2
    return np.where(t < ta, acc, np.where(t < ta + tc, cruise, dec))


def test_trapezoid_golden_numbers() -> None:
    # 100 mm at 10 mm/s, 20 mm/s²: 0.5 s ramps of 2.5 mm, 9.5 s cruise, 10.5 s in all.
    pieces = plan_move(2.0, 0.0, 100.0, 10.0, 20.0)
    assert pieces == [
        Piece(2.0, 0.0, 0.0, 20.0),
        Piece(2.5, 2.5, 10.0, 0.0),
        Piece(12.0, 97.5, 10.0, -20.0),
        Piece(12.5, 100.0, 0.0, 0.0),
    ]


def test_triangle_for_a_short_move() -> None:
    # 1 mm at up to 10 mm/s, 25 mm/s²: peak sqrt(25) = 5 mm/s after 0.2 s; no cruise.
    pieces = plan_move(0.0, 5.0, 4.0, 10.0, 25.0)
    assert [p.t for p in pieces] == pytest.approx([0.0, 0.2, 0.4])
    assert pieces[1].v == pytest.approx(-5.0) and pieces[1].x == pytest.approx(4.5)
    path = Path(0.0, 5.0)
    path.replace_from(0.0, pieces)
    assert float(np.max(np.abs(path.velocity(np.linspace(0, 0.4, 101))))) == pytest.approx(5.0)


@settings(max_examples=60, deadline=None)
@given(
    d=st.floats(0.01, 500.0),
    v=st.floats(0.5, 50.0),
    a=st.floats(1.0, 500.0),
    direction=st.sampled_from([-1.0, 1.0]),
)
def test_path_matches_closed_form(d: float, v: float, a: float, direction: float) -> None:
    x0 = -250.0
    path = Path(0.0, x0)
    path.replace_from(0.0, plan_move(0.0, x0, x0 + direction * d, v, a))
    t = np.linspace(-1.0, path.end_time() + 1.0, 257)
    expected = x0 + direction * analytic_trapezoid(t, d, v, a)
    np.testing.assert_allclose(path.position(t), expected, atol=1e-9 * max(d, 1.0))
    assert float(np.max(np.abs(path.velocity(t)))) <= v * (1 + 1e-12)
    assert path.position(path.end_time()) == x0 + direction * d


def test_stop_decelerates_at_the_given_acceleration() -> None:
    pieces = plan_stop(0.0, 10.0, -6.0, 12.0)
    assert pieces[-1] == Piece(0.5, 8.5, 0.0, 0.0)


def test_crossing_times() -> None:
    path = Path(0.0, 0.0)
    path.replace_from(0.0, plan_move(0.0, 0.0, 100.0, 10.0, 20.0))
    assert path.first_crossing(0.0, 50.0, 1.0) == pytest.approx(0.5 + 4.75)
    assert path.first_crossing(0.0, 1.0, 1.0) == pytest.approx(math.sqrt(0.1))
    assert path.first_crossing(0.0, 101.0, 1.0) is None
    assert path.first_crossing(0.0, -1.0, -1.0) is None
    # Once beyond a switch, only moving further in counts as reaching it.
    back = Path(0.0, 5.0)
    back.replace_from(0.0, plan_move(0.0, 5.0, 0.0, 10.0, 20.0))
    assert back.first_crossing(0.0, 2.0, 1.0) is None


def test_stop_at_freezes_the_position() -> None:
    path = Path(0.0, 0.0)
    path.replace_from(0.0, plan_move(0.0, 0.0, 100.0, 10.0, 20.0))
    x = path.stop_at(3.0)
    assert x == pytest.approx(27.5)
    assert np.all(path.position(np.array([3.0, 4.0, 100.0])) == x)
