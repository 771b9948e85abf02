"""``hil tank-run``'s plain summary prints a line per track (summary.json's ``tracks``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hil.cli.tank_run import print_summary
from hil.estimation.base import Estimate
from hil.estimation.track_summary import track_figures


def test_the_plain_summary_lists_each_track(capsys: pytest.CaptureFixture[str]) -> None:
    est = [
        Estimate(0.01 * k, 9.0 - 0.01 * k, 1.0, k, 5.0, 10.0, 1.0, 0.0, 0, "gcas", track_id=i)
        for k, i in enumerate([-1, -1, 0, 0, 0, 1, -1, 1, 1])
    ]
    truth_r = np.array([e.range_m for e in est]) + 0.002  # every estimate 2 mm short
    truth_v = np.full(len(est), 1.0)
    truth_v[5] = np.nan  # one truth unknown on track 1
    summary = {"estimates": len(est), "tracks": track_figures(est, truth_r, truth_v)}
    print_summary(summary, Path("run"), as_json=False)
    assert capsys.readouterr().out.splitlines() == [
        "estimates  9",
        "tracks     track 0: 3 estimates, t 0.020–0.040 s, range 8.980 → 8.960 m, speed 1.000 "
        "m/s (median), RMSE 0.0020 m / 0.0000 m/s over 3 with truth",
        "tracks     track 1: 3 estimates, t 0.050–0.080 s, range 8.950 → 8.920 m, speed 1.000 "
        "m/s (median), RMSE 0.0020 m / 0.0000 m/s over 2 with truth",
        "tracks     3 estimates on no confirmed track",
        "run folder: run",
    ]
