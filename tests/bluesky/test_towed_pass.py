"""A towed pass as a bluesky plan: the RunEngine runs :func:`hil.bluesky.towed_pass` on the
built-in simulated tank (the simulated GRBL stage and board on ptys, the acoustic world between
them) and the documents carry the run's recording, its stage telemetry and its estimates."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment

# A shorter pass than the built-in run keeps the suite quick (as tests/experiments does).
SHORT = DEFAULT_EXPERIMENT.replace("end_m = -5.0", "end_m = -3.5").replace(
    'name = "sim-towed-pass"', 'name = "bluesky-pass"'
)


def _collect(docs: list[tuple[str, dict[str, Any]]]) -> Any:
    return lambda name, doc: docs.append((name, doc))


@pytest.mark.slow
def test_a_towed_pass_plan_on_the_simulated_tank(run_engine: Any, tmp_path: Path) -> None:
    from hil.bluesky import TankRunDetector, towed_pass
    from hil.recording.reader import RunRecording

    exp = parse_experiment(SHORT)
    run = TankRunDetector(exp, runs_dir=tmp_path, report=False, name="tank")
    from bluesky.run_engine import call_in_bluesky_event_loop

    call_in_bluesky_event_loop(run.connect())
    docs: list[tuple[str, dict[str, Any]]] = []
    run_engine(towed_pass(run, md={"operator": "ci"}), _collect(docs))

    assert [n for n, _ in docs] == ["start", "descriptor", "event", "stop"]
    start, descriptor, event, stop = (d for _, d in docs)
    assert start["plan_name"] == "towed_pass" and start["operator"] == "ci"
    assert start["tow"]["start_m"] == -2.0 and start["tow"]["end_m"] == -3.5
    assert start["tow"]["speed_mps"] == 1.5 and start["simulated"] is True
    assert stop["exit_status"] == "success" and stop["num_events"] == {"primary": 1}
    keys = descriptor["data_keys"]
    assert keys["tank-stage_position_m"]["units"] == "m"
    assert keys["tank-stage_position_m"]["dtype"] == "array"
    assert keys["tank-range_rmse_m"]["units"] == "m"
    config = descriptor["configuration"]["tank"]["data"]
    assert config["tank-stage_url"] == "sim://stage" and config["tank-tow_speed_mps"] == 1.5
    assert descriptor["hints"]["tank"]["fields"] == ["tank-recording"]

    data = event["data"]
    # The recording exists where the event says, and holds what the event reports.
    h5 = Path(data["tank-recording"])
    assert h5.name == "run.h5" and h5.parent.parent == tmp_path
    assert (h5.parent / "summary.json").exists()
    assert data["tank-error"] == ""
    assert data["tank-dropped_samples"] == 0
    assert data["tank-latency_samples"] == 64  # the simulated converters
    rec = RunRecording.open(h5)
    live = rec.estimates()
    assert data["tank-estimates"] == len(live) >= 50
    np.testing.assert_array_equal(data["tank-estimate_range_m"], [e.range_m for e in live])
    # The towed target is tracked (the tank run's own test holds the same bounds).
    assert data["tank-scored_estimates"] >= 50
    assert data["tank-range_rmse_m"] < 0.08 and data["tank-speed_rmse_mps"] < 0.1
    assert data["tank-detection_rate"] > 0.9
    # The stage moved: homed (0), to start - run-up (-1.4 m), through the pass at 1.5 m/s,
    # to end + run-down (-4.1 m).
    x = np.asarray(data["tank-stage_position_m"])
    t = np.asarray(data["tank-stage_time_s"])
    assert x.shape == t.shape and x.size > 10
    assert np.all(np.diff(t) > 0)
    assert x.max() >= -1.4 - 1e-3 and x[-1] == pytest.approx(-4.1, abs=1e-3)
    assert x.min() == pytest.approx(-4.1, abs=1e-3)
    # At the tow speed inside the pass, as GRBL reported it (1 mm/min resolution). Not from
    # differences of positions over report times: a report's time is uncertain by its reply
    # delay, which a loaded machine stretches (the run's scoring filters those reports).
    v = np.asarray(data["tank-stage_velocity_mps"])
    in_pass = (x < -2.05) & (x > -3.45)
    assert in_pass.sum() >= 2
    np.testing.assert_allclose(v[in_pass], -1.5, atol=0.02)


def test_a_run_refused_before_it_starts_fails_the_bluesky_run_with_the_reason(
    run_engine: Any, tmp_path: Path
) -> None:
    from bluesky.run_engine import call_in_bluesky_event_loop
    from bluesky.utils import FailedStatus

    from hil.bluesky import TankRunDetector, towed_pass
    from hil.errors import ConfigError

    text = SHORT.replace("required = []", 'required = ["latency"]').replace(
        'store = "calibration"', f'store = "{tmp_path / "empty-store"}"'
    )
    run = TankRunDetector(parse_experiment(text), runs_dir=tmp_path, name="tank")
    call_in_bluesky_event_loop(run.connect())
    docs: list[tuple[str, dict[str, Any]]] = []
    with pytest.raises(FailedStatus) as err:
        run_engine(towed_pass(run), _collect(docs))
    assert isinstance(err.value.__cause__, ConfigError)
    assert "latency" in str(err.value.__cause__)
    assert [n for n, _ in docs] == ["start", "stop"]
    assert docs[-1][1]["exit_status"] == "fail"
    assert "latency" in docs[-1][1]["reason"]
    assert run.outcome is None  # nothing ran


@pytest.mark.slow
def test_a_run_that_stops_after_it_started_keeps_its_event_and_fails_the_bluesky_run(
    run_engine: Any, tmp_path: Path
) -> None:
    from bluesky.run_engine import call_in_bluesky_event_loop
    from bluesky.utils import FailedStatus

    from hil.bluesky import TankRunDetector, towed_pass
    from hil.bluesky.tank_run import TankRunError

    # The run stops with an error 1.5 s (simulated) into its capture, before the pass ends
    # (about 2.5 s): late enough that the recording has started (0.05 s of capture).
    text = SHORT.replace('output_dir = "runs"', 'output_dir = "runs"\nmax_duration_s = 1.5')
    run = TankRunDetector(parse_experiment(text), runs_dir=tmp_path, report=False, name="tank")
    call_in_bluesky_event_loop(run.connect())
    docs: list[tuple[str, dict[str, Any]]] = []
    with pytest.raises(FailedStatus) as err:
        run_engine(towed_pass(run), _collect(docs))
    assert isinstance(err.value.__cause__, TankRunError)
    assert [n for n, _ in docs] == ["start", "descriptor", "event", "stop"]
    data, stop = docs[2][1]["data"], docs[3][1]
    assert data["tank-error"] == "RuntimeError: run.max_duration_s = 1.5 s exceeded"
    assert Path(data["tank-recording"]).exists()  # what was recorded until the error
    assert stop["exit_status"] == "fail"
    assert "run.max_duration_s = 1.5 s exceeded" in stop["reason"]


def test_each_trigger_gets_a_new_run_folder_under_runs_dir(tmp_path: Path) -> None:
    from hil.bluesky import TankRunDetector

    run = TankRunDetector(parse_experiment(SHORT), runs_dir=tmp_path, name="tank")
    first = run.new_run_folder()
    second = run.new_run_folder()
    # New and empty, under runs_dir; two stamped in the same second get a suffix.
    assert first.parent == tmp_path and first.name.startswith("bluesky-pass-")
    assert first.is_dir() and not any(first.iterdir())
    assert second != first and second.parent == tmp_path
