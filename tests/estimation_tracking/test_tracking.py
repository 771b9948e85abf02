"""The tracker (hil.estimation.tracking) on scripted estimates: crossing targets, birth,
death after misses, clutter that never confirms, a braking target, chunking, bad settings."""

from __future__ import annotations

import dataclasses
import itertools
import math
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.estimation.tracking import Tracker, TrackerSettings, _with_track

C = 1500.0
HOP_S = 0.01

#: Closing speed (m/s) of a scripted target at time t (s).
SpeedProfile = Callable[[float], float]


def target_estimates(
    r0: float,
    speed: float | SpeedProfile,
    hops: range | list[int],
    *,
    seed: int,
    sigma_r: float = 0.005,
    sigma_v: float = 0.01,
    bounds: bool = True,
) -> list[Estimate]:
    """One estimate per hop boundary in ``hops`` of a target at ``r0`` m at t = 0 closing at
    ``speed`` (m/s, or a function of time), with seeded Gaussian errors."""
    rng = np.random.default_rng(seed)
    profile: SpeedProfile = speed if callable(speed) else (lambda t, v=float(speed): v)
    # Range at time t: r0 minus the integral of the closing speed (trapezoids of 1 ms; exact
    # for a constant or piecewise-linear speed).
    grid = np.linspace(0.0, 10.0, 10_001)
    v_grid = np.array([profile(t) for t in grid]) if callable(speed) else np.full(grid.size, speed)
    travelled = np.concatenate([[0.0], np.cumsum(0.5 * (v_grid[1:] + v_grid[:-1]) * np.diff(grid))])
    out = []
    for k in hops:
        t_tx = (k + 1) * HOP_S
        t_b = t_tx + r0 / C
        for _ in range(3):  # fixed point: the bounce instant is t_tx + r(t_b)/c
            r = r0 - float(np.interp(t_b, grid, travelled))
            t_b = t_tx + r / C
        v = profile(t_b)
        out.append(
            Estimate(
                t_s=t_tx + 2.0 * r / C,
                range_m=r + sigma_r * float(rng.standard_normal()),
                speed_mps=v + sigma_v * float(rng.standard_normal()),
                hop_index=k,
                score=10.0,
                snr_db=20.0,
                alpha=(C + v) / (C - v),
                t_tx_s=t_tx,
                codeword=k % 17,
                receiver="scripted",
                crlb_range_m=0.003 if bounds else math.nan,
                crlb_speed_mps=0.008 if bounds else math.nan,
            )
        )
    return out


def emitted(*targets: list[Estimate]) -> list[Estimate]:
    """The targets' estimates in receive-time order, as a receiver emits them."""
    return sorted((e for t in targets for e in t), key=lambda e: e.t_s)


def ids_of(tracked: list[Estimate], source: list[Estimate]) -> list[int]:
    """Track ids of the estimates of ``source`` (one target) in ``tracked``."""
    by_key = {(e.hop_index, e.t_s, e.range_m): e.track_id for e in tracked}
    return [by_key[(e.hop_index, e.t_s, e.range_m)] for e in source]


def test_two_crossing_targets_keep_their_own_tracks() -> None:
    # A closes from 30 m at 5 m/s, B opens from 20 m at 3 m/s: equal range at t = 1.25 s.
    a = target_estimates(30.0, 5.0, range(250), seed=1)
    b = target_estimates(20.0, -3.0, range(250), seed=2)
    crossing = [k for k in range(250) if abs(a[k].range_m - b[k].range_m) < 0.05]
    assert crossing  # the ranges do cross inside the run
    out = Tracker(HOP_S).update(emitted(a, b))
    ids_a, ids_b = ids_of(out, a), ids_of(out, b)
    # Birth: 3 of 5, so each target's first two estimates are unconfirmed.
    assert ids_a[:2] == [-1, -1] and ids_b[:2] == [-1, -1]
    assert set(ids_a[2:]) == {ids_a[2]} and set(ids_b[2:]) == {ids_b[2]}
    assert {ids_a[2], ids_b[2]} == {0, 1}


def test_birth_takes_three_of_five_and_ids_count_in_order_of_confirmation() -> None:
    late = target_estimates(50.0, 2.0, range(100, 140), seed=3)
    early = target_estimates(10.0, -1.0, range(140), seed=4)
    out = Tracker(HOP_S).update(emitted(late, early))
    assert ids_of(out, early) == [-1, -1] + [0] * 138
    assert ids_of(out, late) == [-1, -1] + [1] * 38


def test_hits_spread_wider_than_n_hops_never_confirm() -> None:
    # Hops 0, 2 and 5 of one target: the third is 5 boundaries after the first (N = 5).
    est = target_estimates(20.0, 1.0, [0, 2, 5, 10, 15], seed=5)
    out = Tracker(HOP_S).update(est)
    assert [e.track_id for e in out] == [-1] * 5
    # Three within N: hops 0, 2, 4 confirm on the third.
    est = target_estimates(20.0, 1.0, [0, 2, 4], seed=5)
    assert [e.track_id for e in Tracker(HOP_S).update(est)] == [-1, -1, 0]


def test_a_track_survives_five_missed_hops_and_dies_after_six() -> None:
    # Gap of 5 missed hops (40 -> 46): the same track. Gap of 6 (80 -> 87): a new one.
    hops = list(range(41)) + list(range(46, 81)) + list(range(87, 120))
    est = target_estimates(40.0, 4.0, hops, seed=6)
    out = Tracker(HOP_S).update(est)
    ids = [e.track_id for e in out]
    assert ids[:2] == [-1, -1]
    first = hops.index(87)
    assert set(ids[2:first]) == {0}
    assert ids[first : first + 2] == [-1, -1] and set(ids[first + 2 :]) == {1}
    # max_missed_hops = 6 keeps it one track.
    out = Tracker(HOP_S, TrackerSettings(max_missed_hops=6)).update(est)
    assert {e.track_id for e in out[2:]} == {0}


def test_clutter_never_confirms_beside_a_target() -> None:
    # One clutter estimate every other hop at a random range and speed (seeded) beside a
    # steady target: the clutter stays unconfirmed, the target is one track.
    rng = np.random.default_rng(7)
    target = target_estimates(35.0, 6.0, range(200), seed=8)
    clutter = []
    for k in range(0, 200, 2):
        clutter += target_estimates(
            float(rng.uniform(2.0, 90.0)), float(rng.uniform(-30.0, 30.0)), [k], seed=k
        )
    out = Tracker(HOP_S).update(emitted(target, clutter))
    assert set(ids_of(out, clutter)) == {-1}
    assert ids_of(out, target) == [-1, -1] + [0] * 198
    # Fed 7 at a time (the track table grows between calls): the same ids.
    tracker, est = Tracker(HOP_S), emitted(target, clutter)
    assert [e for i in range(0, len(est), 7) for e in tracker.update(est[i : i + 7])] == out


def test_a_braking_target_stays_one_track() -> None:
    # 10 m/s braking at 5 m/s² from t = 0.5 s to rest at t = 2.5 s; estimates while |v| > 0.2.
    def speed(t: float) -> float:
        return 10.0 - 5.0 * min(max(t - 0.5, 0.0), 2.0)

    hops = [k for k in range(300) if speed((k + 1) * HOP_S) > 0.2]
    est = target_estimates(60.0, speed, hops, seed=9)
    out = Tracker(HOP_S).update(est)
    assert [e.track_id for e in out] == [-1, -1] + [0] * (len(hops) - 2)
    # With no acceleration allowed, the braking target breaks into several tracks.
    stiff = Tracker(HOP_S, TrackerSettings(accel_mps2=0.0)).update(est)
    assert max(e.track_id for e in stiff) >= 1


def test_a_reversing_target_through_the_blind_band_stays_one_track() -> None:
    # +8 m/s to -8 m/s at 16 m/s² from t = 0.5 s; no estimate while |v| < 0.3 m/s (a blind
    # band): a gap of 3 hop boundaries, fewer than the 5 misses a track survives.
    def speed(t: float) -> float:
        return 8.0 - 16.0 * min(max(t - 0.5, 0.0), 1.0)

    hops = [k for k in range(200) if abs(speed((k + 1) * HOP_S + 30.0 / C)) >= 0.3]
    assert len(hops) == 197
    est = target_estimates(30.0, speed, hops, seed=19)
    assert [e.track_id for e in Tracker(HOP_S).update(est)] == [-1, -1] + [0] * 195


def test_an_echo_whose_range_does_not_move_as_its_speed_says_never_confirms() -> None:
    # A still echo read at 27 m/s (a ghost): every hop at 40 m. Its range would fall 0.27 m
    # per hop at that speed, so no second estimate enters a track's gate.
    ghost = target_estimates(40.0, 0.0, range(100), seed=20)
    ghost = [Estimate(**{**e.to_dict(), "speed_mps": 27.0}) for e in ghost]
    target = target_estimates(40.0, 27.0, range(100), seed=21)  # the same at its true speed
    out = Tracker(HOP_S).update(emitted(ghost, target))
    assert set(ids_of(out, ghost)) == {-1}
    assert ids_of(out, target) == [-1, -1] + [0] * 98


def test_one_estimate_per_track_per_hop() -> None:
    # A second echo of every hop 1 mm beside the target (a multipath twin): the two are
    # never put on one track in one hop; they form two tracks.
    target = target_estimates(25.0, 3.0, range(50), seed=10)
    twin = target_estimates(25.0, 3.0, range(50), seed=11)
    twin = [
        Estimate(**{**e.to_dict(), "t_s": e.t_s + 1e-6, "range_m": e.range_m + 0.001}) for e in twin
    ]
    out = Tracker(HOP_S).update(emitted(target, twin))
    ids_per_hop: dict[int, list[int]] = {}
    for e in out:
        ids_per_hop.setdefault(e.hop_index, []).append(e.track_id)
    assert all(sorted(ids_per_hop[k]) == [-1, -1] for k in (0, 1))
    assert all(sorted(ids_per_hop[k]) == [0, 1] for k in range(2, 50))


def test_estimates_without_bounds_use_the_default_noise() -> None:
    est = target_estimates(30.0, -8.0, range(100), seed=12, sigma_r=0.03, sigma_v=0.1,
                           bounds=False)  # fmt: skip
    assert [e.track_id for e in Tracker(HOP_S).update(est)] == [-1, -1] + [0] * 98


def test_golden_ids_of_a_scene() -> None:
    # Three targets, one of them leaving at hop 60, and clutter; the ids are fixed numbers.
    a = target_estimates(12.0, 2.0, range(100), seed=13)
    b = target_estimates(45.0, -4.0, range(5, 60), seed=14)
    c = target_estimates(80.0, 15.0, range(30, 100, 1), seed=15)
    d = target_estimates(45.5, -4.0, range(70, 100), seed=16)  # returns as a new track
    out = Tracker(HOP_S).update(emitted(a, b, c, d))
    got = [sorted(set(ids_of(out, t))) for t in (a, b, c, d)]
    assert got == [[-1, 0], [-1, 1], [-1, 2], [-1, 3]]
    assert sum(e.track_id == -1 for e in out) == 8


def test_a_non_finite_estimate_joins_no_track() -> None:
    est = target_estimates(20.0, 1.0, range(10), seed=17)
    est[5] = Estimate(**{**est[5].to_dict(), "range_m": math.nan})
    out = Tracker(HOP_S).update(est)
    assert [e.track_id for e in out] == [-1, -1, 0, 0, 0, -1, 0, 0, 0, 0]


def test_a_tracked_estimate_keeps_every_other_field() -> None:
    # The tracker copies each estimate with its track id; dataclasses.replace is the
    # reference for that copy (NaN, infinities and the receiver's name included).
    base = target_estimates(20.0, 1.0, range(3), seed=5)[1]
    odd = Estimate(**{**base.to_dict(), "snr_db": -math.inf, "crlb_speed_mps": math.nan})
    for e in (base, odd):
        out = _with_track(e, 7)
        assert out.track_id == 7 and type(out) is type(e)
        assert out == dataclasses.replace(e, track_id=7)
        assert repr(out) == repr(dataclasses.replace(e, track_id=7))
    assert _with_track(base, base.track_id) is base


@settings(max_examples=25, deadline=None)
@given(cuts=st.lists(st.integers(0, 260), max_size=6), seed=st.integers(0, 1000))
def test_chunks_give_the_same_ids_as_the_whole(cuts: list[int], seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = target_estimates(float(rng.uniform(5, 90)), float(rng.uniform(-20, 20)), range(120),
                         seed=seed)  # fmt: skip
    b = target_estimates(float(rng.uniform(5, 90)), float(rng.uniform(-20, 20)), range(10, 130),
                         seed=seed + 1)  # fmt: skip
    est = emitted(a, b)
    whole = Tracker(HOP_S).update(est)
    tracker = Tracker(HOP_S)
    pieces: list[Estimate] = []
    edges = [0, *sorted(c % (len(est) + 1) for c in cuts), len(est)]
    for lo, hi in itertools.pairwise(edges):
        pieces += tracker.update(est[lo:hi])
    assert pieces == whole
    # The tracker changes nothing but the id.
    assert [e.to_dict() | {"track_id": -1} for e in whole] == [
        e.to_dict() | {"track_id": -1} for e in est
    ]


def test_reset_forgets_the_tracks() -> None:
    est = target_estimates(20.0, 1.0, range(10), seed=18)
    tracker = Tracker(HOP_S)
    first = tracker.update(est)
    tracker.reset()
    assert tracker.update(est) == first and tracker.n_tracks == 1


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"track_confirm_hits": 0}, "track_confirm_hits = 0 is not allowed: must be an integer "
         ">= 1; e.g. track_confirm_hits=3"),
        ({"track_confirm_hops": 2.5}, "track_confirm_hops = 2.5 is not allowed: must be an "
         "integer >= 1; e.g. track_confirm_hops=5"),
        ({"track_confirm_hits": 6}, "track_confirm_hits = 6 is not allowed: must be <= "
         "track_confirm_hops = 5 (M of N); lower track_confirm_hits or raise track_confirm_hops"),
        ({"track_max_missed_hops": -1}, "track_max_missed_hops = -1 is not allowed: must be an "
         "integer >= 0; e.g. track_max_missed_hops=5"),
        ({"track_gate_sigmas": 0.0}, "track_gate_sigmas = 0.0 is not allowed: must be a finite "
         "number > 0; e.g. track_gate_sigmas=4.0"),
        ({"track_accel_mps2": -1.0}, "track_accel_mps2 = -1.0 is not allowed: must be a finite "
         "number >= 0; e.g. track_accel_mps2=10.0"),
        ({"track_min_range_sigma_m": math.inf}, "track_min_range_sigma_m = inf is not allowed: "
         "must be a finite number > 0; e.g. track_min_range_sigma_m=0.01"),
        ({"track_default_speed_sigma_mps": "fast"}, "track_default_speed_sigma_mps = 'fast' is "
         "not allowed: must be a finite number > 0; e.g. track_default_speed_sigma_mps=0.2"),
        ({"track_confirm_hits": True}, "track_confirm_hits = True is not allowed: must be an "
         "integer >= 1"),
        ({"track_gate": 3.0}, "track_gate = 3.0 is not allowed: must be a tracker setting: "
         "track_accel_mps2, track_confirm_hits, "),
    ],
)  # fmt: skip
def test_bad_tracker_settings_name_field_value_and_range(
    options: dict[str, object], message: str
) -> None:
    with pytest.raises(ConfigError) as info:
        TrackerSettings.from_options(options)
    assert str(info.value).startswith(message)


def test_bad_hop_period_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"hop_s = 0.0 is not allowed: must be a finite hop"):
        Tracker(0.0)


def test_the_docs_settings_table_gives_the_code_defaults() -> None:
    text = (Path(__file__).resolve().parents[2] / "docs" / "tracks.md").read_text("utf-8")
    rows = re.findall(r"^\| `track_(\w+)` \| ([0-9.]+) \|", text, flags=re.MULTILINE)
    documented = {name: float(value) for name, value in rows}
    defaults = {f.name: float(f.default) for f in dataclasses.fields(TrackerSettings)}
    assert documented == defaults


@pytest.mark.slow
def test_a_new_tracker_has_its_compiled_association_loaded() -> None:
    """A live run's first estimate must not wait for numba to load (or compile) the
    association: building the tracker does it (in a fresh process, where nothing else did)."""
    import subprocess
    import sys

    code = (
        "from hil.estimation import tracking_kernel as k\n"
        "from hil.estimation.tracking import Tracker\n"
        "before = len(k.associate.signatures)\n"
        "Tracker(0.01)\n"
        "print(before, len(k.associate.signatures))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300
    ).stdout.split()
    assert out == ["0", "1"]
