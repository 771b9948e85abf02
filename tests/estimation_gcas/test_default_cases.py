"""GCAS with its default options on constant-velocity targets closing and opening, both
HFC-CW families, −20 … 0 dB per-sample SNR, and in volume reverberation at 0 dB SRR
(the chapter-6 trial: exact time-scaled echo, white noise, hop-boundary scoring)."""

from __future__ import annotations

import numpy as np
import pytest

from hil.evaluation.trials_ch6 import ch6_receiver_trial

TRIALS = 3


def _pooled(params: dict[str, object], seed: int) -> dict[str, float]:
    """Pd, false estimates per scored boundary and range RMSE (m) over TRIALS trials."""
    outs = [
        ch6_receiver_trial(params, np.random.SeedSequence(seed, spawn_key=(0, k)))
        for k in range(TRIALS)
    ]
    n_truth = sum(o["n_truth"] for o in outs)
    sse = sum(o["range_sse_m2"] for o in outs)
    n_det = sum(o["n_detected"] for o in outs)
    return {
        "pd": n_det / n_truth,
        "false_per_hop": sum(o["n_false"] for o in outs) / n_truth,
        "rmse": float(np.sqrt(sse / max(n_det, 1))),
    }


#: The fast tier runs the random-cyclic family; three-state (0.5 CPU s a case on constant
#: velocity, 1.6 in reverberation) is left to ``--all`` (test_gcas_receiver runs it fast).
FAMILIES = ["random-cyclic", pytest.param("three-state", marks=pytest.mark.slow)]


@pytest.mark.slow
@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("speeds", [(8.0, 25.0), (-25.0, -8.0)], ids=["closing", "opening"])
@pytest.mark.parametrize(
    ("snr_db", "pd_min", "rmse_max"),
    # Measured (3 trials each): Pd 1 and 0.014-0.036 m at 0 and -10 dB; at -20 dB Pd 0.76-1
    # and 0.11-0.54 m (a detection may be up to c·T_h/4 off in range: a few such pull it up).
    [(0.0, 0.97, 0.05), (-10.0, 0.95, 0.07), (-20.0, 0.7, 0.6)],
)
def test_default_options_on_constant_velocity_targets(
    family: str, speeds: tuple[float, float], snr_db: float, pd_min: float, rmse_max: float
) -> None:
    got = _pooled(
        {"family": family, "speed_mps": list(speeds), "snr_db": snr_db, "m_hops": 10}, seed=41
    )
    assert got["pd"] >= pd_min, got
    # At most 0.05 false estimates per hop (issue 18: at -20 dB with M = 10).
    assert got["false_per_hop"] <= 0.05, got
    assert got["rmse"] <= rmse_max, got


@pytest.mark.slow
@pytest.mark.parametrize("family", FAMILIES)
def test_default_options_in_reverberation_at_0_db_srr(family: str) -> None:
    # -10 dB per-sample SNR on top; targets clear of the clutter band (10-25 m/s closing).
    base = {"family": family, "speed_mps": [10.0, 25.0], "snr_db": -10.0, "srr_db": 0.0}
    banded = _pooled(base, seed=43)
    off = _pooled({**base, "reverb_speed_mps": 0.0}, seed=43)
    assert banded["pd"] >= 0.95 and banded["false_per_hop"] <= 0.02, banded
    # Without the band the clutter costs detections and brings false estimates.
    assert off["false_per_hop"] > 5 * banded["false_per_hop"], (off, banded)


@pytest.mark.slow
def test_three_state_range_rmse_in_line_with_random_cyclic_at_minus_10_db() -> None:
    # Issue 18: 7 cm for three-state against 4-6 cm for random-cyclic before; now alike.
    rmse = {
        family: _pooled(
            {"family": family, "speed_mps": [5.0, 25.0], "snr_db": -10.0, "m_hops": 10}, seed=47
        )["rmse"]
        for family in ("random-cyclic", "three-state")
    }
    assert rmse["three-state"] <= 1.3 * rmse["random-cyclic"], rmse
    assert max(rmse.values()) < 0.05, rmse
