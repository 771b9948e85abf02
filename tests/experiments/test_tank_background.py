"""The built-in tank with receiver gcas-bg on virtual time: the empty-tank background captured
as docs/tank-run.md ("Empty-tank background") says, and both directions of a tow and the
carriage at rest read against it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from hil.experiments.run_scoring import score_run, scored_mask, summarize, telemetry_truth
from hil.experiments.tank_run import LiveView, RunOutcome, run_experiment

SHORT = DEFAULT_EXPERIMENT.replace("end_m = -5.0", "end_m = -3.5")


def _virtual_run(folder: Path, text: str) -> RunOutcome:
    return run_experiment(
        parse_experiment(text), folder=folder, view=LiveView(enabled=False), virtual_time=True
    )


@pytest.mark.slow
def test_the_documented_capture_of_an_empty_tank_equals_the_simulated_one(
    tmp_path: Path,
) -> None:
    from hil.experiments.calibration.background import simulated_background

    # The recipe: a tank run with the target out of the beam (here its echo 68 dB down),
    # recorded; its background from the recording, saved for the experiment file.
    empty = (
        SHORT.replace("target_strength_db = -12.0", "target_strength_db = -80.0")
        .replace('name = "gcas-bg"', 'name = "gcas"')
        .replace('options = { background = "simulated" }', "")
    )
    _virtual_run(tmp_path / "empty-tank", empty)

    # -- as docs/tank-run.md, "Empty-tank background" --
    from hil.experiments.calibration.background import background_from_recording, save_background

    save_background(
        tmp_path / "empty-tank.npy", background_from_recording(tmp_path / "empty-tank/run.h5")
    )
    # --
    captured = np.load(tmp_path / "empty-tank.npy")
    simulated = simulated_background(parse_experiment(SHORT))
    # Within 1 % of the background's RMS (what differs: the noise left after averaging the
    # run's periods, the converter's 16 bits, the target 68 dB down): the simulated capture
    # is what a lab records.
    rms = float(np.sqrt(np.mean(simulated**2)))
    assert float(np.sqrt(np.mean((captured - simulated) ** 2))) < 0.01 * rms
    # The experiment file naming the capture runs the receiver on it.
    text = SHORT.replace(
        'options = { background = "simulated" }',
        f'options = {{ background = "{tmp_path / "empty-tank.npy"}" }}',
    )
    summary = summarize(_virtual_run(tmp_path / "with-capture", text))
    assert summary["wrong_estimates"] == 0 and summary["range_rmse_m"] < 0.01


@pytest.mark.slow
def test_opening_and_closing_passes_and_the_carriage_at_rest_read_alike(tmp_path: Path) -> None:
    text = DEFAULT_EXPERIMENT.replace("repeats = 1", "repeats = 2")
    outcome = _virtual_run(tmp_path / "two-passes", text)
    summary = summarize(outcome)
    truth = telemetry_truth(outcome)
    score = score_run(outcome, truth)
    scored = scored_mask(outcome, truth)
    closing = scored & (truth["speed_mps"] > 0)
    opening = scored & (truth["speed_mps"] < 0)
    assert closing.sum() >= 150 and opening.sum() >= 150

    def rmse(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x**2)))

    # Measured (seed 1, replayed): range RMSE 0.0028 m closing, 0.0030 m opening; speed RMSE
    # against the telemetry 0.010 and 0.008 m/s (its 5 Hz reports interpolated across the
    # segment's ends read the carriage up to 0.06 m/s slow there); live, against the exact
    # carriage, 0.0028 m and 0.0036 m/s.
    for part in (closing, opening):
        assert rmse(score.range_error_m[part]) < 0.01
        assert rmse(score.speed_error_mps[part]) < 0.015
    assert summary["speed_rmse_vs_exact_mps"] < 0.01
    assert summary["range_rmse_vs_exact_m"] < 0.005
    # Every estimate with a truth is inside the gate: the ramps, the turn, and the carriage
    # at rest before, between and after the passes (read to 7 mm).
    assert summary["wrong_estimates"] == 0
    at_rest = np.isfinite(truth["range_m"]) & (np.abs(truth["speed_mps"]) < 0.01)
    assert at_rest.sum() >= 30
    assert np.max(np.abs(score.range_error_m[at_rest])) < 0.05


@pytest.mark.slow
def test_the_board_preset_s_tank_is_read_against_its_background(tmp_path: Path) -> None:
    # tank-board's hops' phase advances by π over a code period: its still water comes back
    # with the opposite sign (hil.estimation.still_period). A background averaged over
    # periods without the sign cancelled to nothing, and the run read the far wall: range
    # RMSE against the exact truth 4.54 m, one track at 11.49 m. With the sign: 0.057 m, the
    # tow's pass on its own track (measured, the built-in run at 1 MS/s on virtual time).
    text = DEFAULT_EXPERIMENT.replace('preset = "tank-audio"', 'preset = "tank-board"')
    outcome = _virtual_run(tmp_path / "board", text)
    summary = summarize(outcome)
    assert summary["range_rmse_vs_exact_m"] < 0.1
    assert summary["speed_rmse_vs_exact_mps"] < 0.05
    # The carriage at rest before and after the pass (9.10 m and 4.90 m), read to 5 cm. At
    # 4.90 m its surface image on one leg comes 0.28 m behind the direct path, 1.6 times as
    # strong: one boundary in three was read on it (5.18 m) while the first arrival's top was
    # searched into the image's own rise. Measured: 1 mm at both ends.
    assert outcome.exact_truth is not None
    exact_r = outcome.exact_truth["range_m"]
    at_rest = np.isfinite(exact_r) & (np.abs(outcome.exact_truth["speed_mps"]) < 1e-3)
    errors = np.array([e.range_m for e in outcome.estimates]) - exact_r
    assert np.count_nonzero(at_rest & (exact_r < 5.0)) >= 50
    assert np.count_nonzero(at_rest & (exact_r > 9.0)) >= 25
    assert np.max(np.abs(errors[at_rest])) < 0.05
    # In the pass at 7.7-8.1 m the target's path of constant length through the far end wall
    # (23.0 m on the tank's axis), one hop late, switches ahead of the direct path and was read
    # for it: 34 estimates 0.1-0.32 m short. An onset standing still while its echo moves is
    # refused, and so is one leaving its echo's track: 2 are left (measured; 10 with the
    # first rule alone; docs/tank-run.md).
    wrong = np.abs(errors) > summary["wrong_gate_m"]
    assert summary["wrong_estimates"] == np.count_nonzero(wrong) <= 2
    assert np.all((exact_r[wrong] > 7.7) & (exact_r[wrong] < 8.1))
