"""Clutter notices (:mod:`hil.estimation.gcas.clutter_seen`): said once per range."""

from __future__ import annotations

import json

from hypothesis import given
from hypothesis import strategies as st

from hil.estimation.gcas.clutter_seen import CLUTTER_NOTICE_M, ClutterLog, ClutterSeen


def test_a_notice_says_where_and_what_was_done() -> None:
    seen = ClutterSeen(t_s=0.1135, hop_index=10, range_m=2.634, speed_mps=0.02)
    assert seen.text() == (
        "diffuse reverberation (clutter) at 2.63 m at t = 0.1135 s (hop 10): counted as "
        "clutter, not reported as a target"
    )
    assert json.loads(json.dumps(seen.to_dict())) == {
        "notice": "clutter", "t_s": 0.1135, "hop_index": 10, "range_m": 2.634,
        "speed_mps": 0.02,
    }  # fmt: skip


def test_clutter_is_said_again_only_away_from_every_range_said() -> None:
    log = ClutterLog()
    said = [log.add(ClutterSeen(0.1 * i, i, r, 0.0)) for i, r in enumerate([2.6, 3.2, 1.1, 3.7])]
    assert said == [True, False, True, True]
    assert [s.range_m for s in log.sightings] == [2.6, 1.1, 3.7]
    log.reset()
    assert log.sightings == [] and log.add(ClutterSeen(0.0, 0, 2.6, 0.0))


@given(st.lists(st.floats(0.5, 100.0), min_size=1, max_size=60))
def test_notices_are_more_than_the_notice_range_apart(ranges: list[float]) -> None:
    log = ClutterLog()
    for i, r in enumerate(ranges):
        log.add(ClutterSeen(0.01 * i, i, r, 0.0))
    kept = [s.range_m for s in log.sightings]
    assert kept[0] == ranges[0]
    assert all(abs(a - b) > CLUTTER_NOTICE_M for i, a in enumerate(kept) for b in kept[:i])
    # Every range refused is within the notice range of one said.
    assert all(min(abs(r - k) for k in kept) <= CLUTTER_NOTICE_M for r in ranges)
