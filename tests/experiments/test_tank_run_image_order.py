"""The built-in tank run at image order 2 on virtual time: the receiver (``gcas-bg``, its
first-arrival readout) against the target's images to two reflections per round trip.

The carriage slowing to rest at the end of the pass (4.9 m) is where the previous boundary's
late images (far end wall and one more boundary, 0.9 hop behind their direct path) switch tones
about 1.1 ms before the first arrival: the readout steps over that pedestal
(:mod:`hil.estimation.first_arrival`); before it, 6.6 % of the estimates there were 0.8-1.7 m
short. Seeded, so the figures are exact; a change to the tank or the receiver that moves them
changes this run."""

from __future__ import annotations

import numpy as np
import pytest

from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from hil.experiments.run_scoring import summarize, telemetry_truth
from hil.experiments.tank_run import LiveView, RunOutcome, run_experiment

ORDER_2 = DEFAULT_EXPERIMENT.replace("image_order = 1", "image_order = 2")


@pytest.fixture(scope="module")
def order_2_run(tmp_path_factory: pytest.TempPathFactory) -> RunOutcome:
    assert ORDER_2 != DEFAULT_EXPERIMENT
    return run_experiment(
        parse_experiment(ORDER_2),
        folder=tmp_path_factory.mktemp("order2") / "run",
        view=LiveView(enabled=False),
        virtual_time=True,
    )


@pytest.mark.slow
def test_order_2_meets_the_tank_targets(order_2_run: RunOutcome) -> None:
    """Issue 31 item 6 on the built-in tank at image order 2: range |bias| and RMSE <= 0.05 m,
    <= 5 % of the estimates more than 1 m off (over every estimate with a truth: the run-up
    and the stop too), speed RMSE <= 0.02 m/s; and the figures themselves."""
    summary = summarize(order_2_run)
    truth = telemetry_truth(order_2_run)
    r = np.array([e.range_m for e in order_2_run.estimates])
    with_truth = np.isfinite(truth["range_m"]) & np.isfinite(r)
    far = int(np.count_nonzero(np.abs(r - truth["range_m"])[with_truth] > 1.0))
    counts = (
        summary["estimates"],
        int(np.count_nonzero(with_truth)),
        far,
        summary["wrong_estimates"],
        summary["scored_estimates"],
    )
    assert counts == GOLDEN_COUNTS
    assert far <= 0.05 * np.count_nonzero(with_truth)
    assert abs(summary["range_bias_m"]) <= 0.05 and summary["range_rmse_m"] <= 0.05
    assert summary["speed_rmse_mps"] <= 0.02
    golden = {
        "detection_rate": GOLDEN["detection_rate"],
        "range_bias_m": GOLDEN["range_bias_m"],
        "range_rmse_m": GOLDEN["range_rmse_m"],
        "speed_rmse_mps": GOLDEN["speed_rmse_mps"],
    }
    assert {k: summary[k] for k in golden} == pytest.approx(golden, abs=1e-9)


#: Estimates, those with a truth, more than 1 m off, more than the 0.124 m gate off (all in the
#: carriage's stop, the first arrival read 0.15-0.25 m late on the pedestal), scored.
GOLDEN_COUNTS = (410, 391, 2, 54, 200)
GOLDEN = {
    "detection_rate": 1.0,
    "range_bias_m": 0.0033913506174724174,
    "range_rmse_m": 0.008453991350902497,
    "speed_rmse_mps": 0.011533754731056797,
}


def test_the_order_2_experiment_differs_from_the_built_in_one_by_its_order_only() -> None:
    """The run above is the built-in experiment with one change."""
    a = parse_experiment(DEFAULT_EXPERIMENT)
    b = parse_experiment(ORDER_2)
    assert (a.simulation.image_order, b.simulation.image_order) == (1, 2)
    assert ORDER_2.replace("image_order = 2", "image_order = 1") == DEFAULT_EXPERIMENT
