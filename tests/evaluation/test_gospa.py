"""GOSPA (hil.evaluation.gospa): golden values, the metric's properties against a brute-force
optimum, bad input, track switches, and the scene scoring's use of it."""

from __future__ import annotations

import itertools
import math
from types import SimpleNamespace as NS

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.evaluation.gospa import gospa, state_distances, track_switches
from hil.evaluation.trials_scene import scene_gospa

C = 0.5


def test_golden_two_targets_one_found_one_missed_one_false() -> None:
    g = gospa([[40.0, 10.0], [60.0, -6.0]], [[40.3, 10.1], [75.0, -6.0]], cutoff=C)
    # 0.3 m and 0.1 m/s: d² = 0.1; a miss and a false estimate cost c²/2 each.
    assert g.pairs == ((0, 0),) and (g.missed, g.false) == (1, 1)
    assert g.localisation == pytest.approx(0.1)
    assert g.distance == pytest.approx(math.sqrt(0.1 + 0.25))


def test_a_pair_beyond_the_cutoff_is_a_miss_and_a_false_estimate() -> None:
    g = gospa([[40.0, 10.0]], [[40.6, 10.0]], cutoff=C)
    assert g.pairs == () and (g.missed, g.false) == (1, 1)
    assert g.distance == pytest.approx(C)  # √(c²/2 + c²/2)


def test_the_assignment_is_the_optimum_not_the_nearest_first() -> None:
    # The nearest pair is target 1 and estimate 0 (0.05 m); taking it first leaves target 0
    # to estimate 1 (0.45 m): 0.205 m² in all. The optimum pairs 0-0 and 1-1: 0.085 m².
    g = gospa([[40.0, 0.0], [40.2, 0.0]], [[40.15, 0.0], [40.45, 0.0]], cutoff=C)
    assert g.pairs == ((0, 0), (1, 1))
    assert g.localisation == pytest.approx(0.15**2 + 0.25**2)


@pytest.mark.parametrize(
    ("kwargs", "field", "says"),
    [({"cutoff": 0.0}, "cutoff", "> 0 m"), ({"cutoff": math.nan}, "cutoff", "> 0 m"),
     ({"cutoff": C, "order": 0.5}, "order", ">= 1")],
)  # fmt: skip
def test_bad_parameters_are_refused_naming_them(
    kwargs: dict[str, float], field: str, says: str
) -> None:
    with pytest.raises(ConfigError) as err:
        gospa([[1.0, 0.0]], [[1.0, 0.0]], **kwargs)
    assert err.value.field == field and says in str(err.value)


def _brute(x: np.ndarray, y: np.ndarray, c: float, p: float) -> float:
    """GOSPA by trying every partial assignment (small sets only)."""
    d = state_distances(x, y)
    best = c**p / 2 * (len(x) + len(y))
    for k in range(1, min(len(x), len(y)) + 1):
        for rows in itertools.combinations(range(len(x)), k):
            for cols in itertools.permutations(range(len(y)), k):
                pairs = [(i, j) for i, j in zip(rows, cols, strict=True) if d[i, j] < c]
                cost = sum(d[i, j] ** p for i, j in pairs) + c**p / 2 * (
                    len(x) + len(y) - 2 * len(pairs)
                )
                best = min(best, cost)
    return float(best ** (1 / p))


_states = st.lists(st.tuples(st.floats(39.0, 41.0), st.floats(-0.6, 0.6)), min_size=0, max_size=4)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(_states, _states, _states, st.sampled_from([1.0, 2.0]))
def test_it_is_the_optimum_and_a_metric(
    xs: list[tuple[float, float]], ys: list[tuple[float, float]],
    zs: list[tuple[float, float]], p: float,
) -> None:  # fmt: skip
    x, y, z = (np.array(s, dtype=float).reshape(-1, 2) for s in (xs, ys, zs))
    dxy = gospa(x, y, cutoff=C, order=p)
    assert dxy.distance == pytest.approx(_brute(x, y, C, p), abs=1e-9)
    # Its parts add up, it is symmetric, zero on itself, and obeys the triangle inequality.
    assert dxy.distance**p == pytest.approx(
        dxy.localisation + C**p / 2 * (dxy.missed + dxy.false), abs=1e-12
    )
    assert gospa(y, x, cutoff=C, order=p).distance == pytest.approx(dxy.distance, abs=1e-12)
    assert gospa(x, x, cutoff=C, order=p).distance == 0.0
    d_xz = gospa(x, z, cutoff=C, order=p).distance
    d_yz = gospa(y, z, cutoff=C, order=p).distance
    assert d_xz <= dxy.distance + d_yz + 1e-9


def test_track_switches_count_changes_of_a_targets_confirmed_track() -> None:
    assert track_switches([]) == 0
    assert track_switches([[0, 1], [1, 0], [1, 0], [None, 2]]) == 3
    # An estimate of no confirmed track (None) between two of the same track is no switch.
    assert track_switches([[4], [None], [4]]) == 0


# ----------------------------------------------------------------------------- in the scenes
def _truths(hops: range) -> list[dict[int, NS]]:
    return [
        {k: NS(hop_index=k, t_rx_s=0.01 * k, range_m=r, radial_speed_mps=v) for k in hops}
        for r, v in ((40.0, 10.0), (60.0, -6.0))
    ]


def _est(k: int, r: float, v: float, track: int) -> NS:
    return NS(hop_index=k - 1, t_s=0.01 * k, range_m=r, speed_mps=v, track_id=track)


def test_scene_gospa_sums_per_boundary_and_counts_a_swap_of_tracks() -> None:
    by_target = _truths(range(1, 5))
    est = [
        _est(1, 40.0, 10.0, 0), _est(1, 60.0, -6.0, 1),
        _est(2, 40.1, 10.0, 0), _est(2, 60.0, -6.0, 1),
        _est(3, 40.0, 10.0, 1), _est(3, 60.0, -6.0, 0),  # the tracks swap
        _est(4, 40.0, 10.0, 1), _est(4, 80.0, 0.0, -1),  # target 2 missed, one false
    ]  # fmt: skip
    s = scene_gospa(est, by_target, lambda h: True, 0.01, set(range(1, 5)))
    assert s["gospa_times"] == 4 and s["gospa_pairs"] == 7
    assert (s["gospa_missed"], s["gospa_false"]) == (1, 1)
    assert s["gospa_localisation_m2"] == pytest.approx(0.01)
    assert s["gospa_sum_m2"] == pytest.approx(0.01 + 0.25)
    assert s["track_switches"] == 2


def test_a_boundary_with_nothing_expected_and_nothing_reported_counts_as_zero() -> None:
    by_target = _truths(range(1, 5))
    s = scene_gospa([_est(2, 80.0, 0.0, -1)], by_target, lambda h: False, 0.01, set(range(1, 5)))
    # One false estimate in four boundaries: Σd² = c²/2 over 4 boundaries.
    assert (s["gospa_times"], s["gospa_false"], s["gospa_missed"]) == (4, 1, 0)
    assert s["gospa_sum_m2"] == pytest.approx(0.125)


def test_a_target_reported_where_it_is_not_expected_is_not_false() -> None:
    # Target 2 is in the reverberation band (not expected): its estimate is right, so it is
    # neither a false estimate nor a pair; target 1's boundary without estimate is missed.
    by_target = _truths(range(1, 3))
    est = [_est(1, 60.0, -6.0, 3), _est(2, 40.0, 10.0, 0)]
    s = scene_gospa(est, by_target, lambda h: h.radial_speed_mps > 0, 0.01, {1, 2})
    assert (s["gospa_times"], s["gospa_pairs"], s["gospa_missed"], s["gospa_false"]) == (
        2, 1, 1, 0,
    )  # fmt: skip
