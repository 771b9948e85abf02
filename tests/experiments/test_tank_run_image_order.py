"""The built-in tank run at image order 2 on virtual time: the receiver (``gcas-bg``, its
first-arrival readout) against the target's images to two reflections per round trip.

The carriage slowing to rest at the end of the pass (4.9 m) is where the previous boundary's
late images (far end wall and one more boundary, 0.9 hop behind their direct path) switch tones
about 1.1 ms before the first arrival: the readout steps over that pedestal
(:mod:`hil.estimation.first_arrival`); before it, 6.6 % of the estimates there were 0.8-1.7 m
short. Seeded, so the figures are exact; a change to the tank or the receiver that moves them
changes this run.

Also the 12 x 6 x 4 m tank at order 2 and the built-in tank at order 3 (docs/tank-run.md, the
table against image order and tank size): their figures as measured, and issue 31 item 6 for
each."""

from __future__ import annotations

import numpy as np
import pytest

from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from hil.experiments.run_scoring import summarize, telemetry_truth
from hil.experiments.tank_run import LiveView, RunOutcome, run_experiment

ORDER_2 = DEFAULT_EXPERIMENT.replace("image_order = 1", "image_order = 2")
ORDER_3 = DEFAULT_EXPERIMENT.replace("image_order = 1", "image_order = 3")
#: The 12 x 6 x 4 m tank of docs/tank-run.md: transducer and tow line at mid-width, 2 m deep.
BIG_TANK_ORDER_2 = (
    ORDER_2.replace("size_m = [12.0, 4.0, 2.5]", "size_m = [12.0, 6.0, 4.0]")
    .replace("transducer_position_m = [0.5, 2.0, -1.2]", "transducer_position_m = [0.5, 3.0, -2.0]")
    .replace("stage_origin_m = [11.0, 2.0, -1.2]", "stage_origin_m = [11.0, 3.0, -2.0]")
)


def _run(text: str, tmp_path_factory: pytest.TempPathFactory, name: str) -> RunOutcome:
    return run_experiment(
        parse_experiment(text),
        folder=tmp_path_factory.mktemp(name) / "run",
        view=LiveView(enabled=False),
        virtual_time=True,
    )


@pytest.fixture(scope="module")
def order_2_run(tmp_path_factory: pytest.TempPathFactory) -> RunOutcome:
    assert ORDER_2 != DEFAULT_EXPERIMENT
    return _run(ORDER_2, tmp_path_factory, "order2")


@pytest.fixture(scope="module")
def order_3_run(tmp_path_factory: pytest.TempPathFactory) -> RunOutcome:
    assert ORDER_3 != DEFAULT_EXPERIMENT
    return _run(ORDER_3, tmp_path_factory, "order3")


@pytest.fixture(scope="module")
def big_tank_order_2_run(tmp_path_factory: pytest.TempPathFactory) -> RunOutcome:
    assert BIG_TANK_ORDER_2.count("[12.0, 6.0, 4.0]") == 1 and "3.0, -2.0]" in BIG_TANK_ORDER_2
    return _run(BIG_TANK_ORDER_2, tmp_path_factory, "big2")


def _figures(outcome: RunOutcome) -> tuple[tuple[int, ...], dict[str, float]]:
    """(estimates, with a truth, more than 1 m off, more than the gate off, scored) and the
    scored figures of a run."""
    summary = summarize(outcome)
    truth = telemetry_truth(outcome)
    r = np.array([e.range_m for e in outcome.estimates])
    with_truth = np.isfinite(truth["range_m"]) & np.isfinite(r)
    far = int(np.count_nonzero(np.abs(r - truth["range_m"])[with_truth] > 1.0))
    counts = (
        summary["estimates"],
        int(np.count_nonzero(with_truth)),
        far,
        summary["wrong_estimates"],
        summary["scored_estimates"],
    )
    keys = ("detection_rate", "range_bias_m", "range_rmse_m", "speed_rmse_mps")
    return counts, {k: summary[k] for k in keys}


def _meets_item_6(counts: tuple[int, ...], figures: dict[str, float]) -> bool:
    """Issue 31 item 6: range |bias| and RMSE <= 0.05 m, <= 5 % of the estimates with a truth
    more than 1 m off, speed RMSE <= 0.02 m/s."""
    return (
        counts[2] <= 0.05 * counts[1]
        and abs(figures["range_bias_m"]) <= 0.05
        and figures["range_rmse_m"] <= 0.05
        and figures["speed_rmse_mps"] <= 0.02
    )


@pytest.mark.slow
def test_order_2_meets_the_tank_targets(order_2_run: RunOutcome) -> None:
    """Issue 31 item 6 on the built-in tank at image order 2: range |bias| and RMSE <= 0.05 m,
    <= 5 % of the estimates more than 1 m off (over every estimate with a truth: the run-up
    and the stop too), speed RMSE <= 0.02 m/s; and the figures themselves."""
    counts, figures = _figures(order_2_run)
    assert counts == GOLDEN_COUNTS
    assert _meets_item_6(counts, figures)
    golden = {k: GOLDEN[k] for k in figures}
    assert figures == pytest.approx(golden, abs=1e-9)


#: Estimates, those with a truth, more than 1 m off, more than the 0.124 m gate off (all in the
#: carriage's stop), scored.
GOLDEN_COUNTS = (404, 386, 2, 12, 200)
GOLDEN = {
    "detection_rate": 1.0,
    "range_bias_m": 0.003385881718189805,
    "range_rmse_m": 0.00763060006182196,
    "speed_rmse_mps": 0.010582820842086291,
}


def test_the_order_2_experiment_differs_from_the_built_in_one_by_its_order_only() -> None:
    """The run above is the built-in experiment with one change."""
    a = parse_experiment(DEFAULT_EXPERIMENT)
    b = parse_experiment(ORDER_2)
    assert (a.simulation.image_order, b.simulation.image_order) == (1, 2)
    assert ORDER_2.replace("image_order = 2", "image_order = 1") == DEFAULT_EXPERIMENT


@pytest.mark.slow
def test_big_tank_order_2_figures(big_tank_order_2_run: RunOutcome) -> None:
    """The 12 x 6 x 4 m tank at image order 2 (seed 1): its figures as measured, so a change
    that moves them is seen (docs/tank-run.md has them against image order and tank size)."""
    counts, figures = _figures(big_tank_order_2_run)
    assert counts == BIG_TANK_COUNTS
    assert figures == pytest.approx(BIG_TANK_GOLDEN, abs=1e-9)


@pytest.mark.slow
def test_big_tank_order_2_meets_the_tank_targets(big_tank_order_2_run: RunOutcome) -> None:
    """Issue 31 item 6 in the 12 x 6 x 4 m tank at image order 2 (the far end wall's images
    pull GCAS's speed 0.15-0.33 m/s slow at 5.5-8 m; the direct path's is read)."""
    assert _meets_item_6(*_figures(big_tank_order_2_run))


@pytest.mark.slow
def test_order_3_figures(order_3_run: RunOutcome) -> None:
    """The built-in tank at image order 3 (seed 1): its figures as measured."""
    counts, figures = _figures(order_3_run)
    assert counts == ORDER_3_COUNTS
    assert figures == pytest.approx(ORDER_3_GOLDEN, abs=1e-9)


@pytest.mark.slow
def test_order_3_meets_the_tank_targets(order_3_run: RunOutcome) -> None:
    """Issue 31 item 6 in the built-in tank at image order 3 (a weak first arrival under its
    images: its onset searched again, with the noise read just before the ramp; the speed
    placed on the summed score where it has been steady)."""
    assert _meets_item_6(*_figures(order_3_run))


#: Measured (seed 1, virtual time): see the tests above.
BIG_TANK_COUNTS = (372, 359, 1, 15, 184)
BIG_TANK_GOLDEN = {
    "detection_rate": 0.9154,
    "range_bias_m": 0.007189987945185111,
    "range_rmse_m": 0.016475647883269783,
    "speed_rmse_mps": 0.009892796545269372,
}
ORDER_3_COUNTS = (381, 365, 5, 91, 191)
ORDER_3_GOLDEN = {
    "detection_rate": 0.9502,
    "range_bias_m": -0.004618636706561599,
    "range_rmse_m": 0.03588198111200729,
    "speed_rmse_mps": 0.011632715065119422,
}
