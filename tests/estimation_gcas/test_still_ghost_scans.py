"""A detection at the still water's ghost speed (a whole number of tone spacings from rest)
where its window holds still water is not scanned for a source beyond the span
(:meth:`hil.estimation.gcas.beyond_span.BeyondSpanCheck._ghost_of_still`): the same
estimates, fewer scans."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hil.estimation.gcas import beyond_span
from tests.estimation_gcas.conftest import count_calls


def _trial(monkeypatch: pytest.MonkeyPatch, rule: bool) -> tuple[dict[str, Any], int]:
    """Scene ``two-apart`` in volume reverberation at 0 dB SRR, 0 dB per-sample SNR, 1.2 s:
    the scored result and the number of ghost-source scans (each band of a side one)."""
    from hil.evaluation.trials_scene import scene_trial

    if not rule:
        monkeypatch.setattr(beyond_span.BeyondSpanCheck, "_ghost_of_still", lambda *a: False)
    scans = count_calls(monkeypatch, beyond_span.BeyondSpanCheck, "_scan_ghost")
    params = {"scene": "two-apart", "snr_db": 0.0, "srr_db": 0.0, "duration_s": 1.2}
    out = scene_trial(params, np.random.SeedSequence(41000))
    return out, scans[0]


@pytest.mark.slow
def test_the_still_waters_ghosts_cost_no_scan_and_change_no_estimate(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The reverberation's ghosts one tone spacing from rest (±27.5 m/s on att, detected on
    # the span's edge hypotheses at -30..-25 m/s) are refused as not one echo; each refusal
    # the scans' waits let through was a scan of every band of a side beyond the span.
    without, scans_without = _trial(monkeypatch, rule=False)
    monkeypatch.undo()
    with_rule, scans_with = _trial(monkeypatch, rule=True)
    for key in ("expected", "detected", "n_false", "range_errors_m", "speed_errors_mps"):
        assert with_rule[key] == without[key], key
    assert with_rule["detected"] == with_rule["expected"]
    assert with_rule["n_false"] == 0
    assert (scans_without, scans_with) == (29, 17)
