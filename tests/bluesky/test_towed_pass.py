"""A towed pass as a bluesky plan: the RunEngine runs :func:`hil.bluesky.towed_pass` (and
bluesky's own ``count``) on the built-in simulated tank on virtual time (the simulated GRBL
stage and board in this process, the acoustic world between them) and the documents carry the
run's recording, its stage telemetry and its estimates; a pause stops the run in flight, a
resume runs it again and an abort leaves it stopped, its recording closed with its stop event."""

from __future__ import annotations

import dataclasses
import json
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
    run = TankRunDetector(exp, runs_dir=tmp_path, report=False, virtual_time=True, name="tank")
    from bluesky.run_engine import call_in_bluesky_event_loop

    call_in_bluesky_event_loop(run.connect())
    docs: list[tuple[str, dict[str, Any]]] = []
    run_engine(towed_pass(run, md={"operator": "ci"}), _collect(docs))

    start, stop = docs[0][1], docs[-1][1]
    descriptors = {d["name"]: d for n, d in docs if n == "descriptor"}
    assert sorted(descriptors) == ["estimates", "primary", "telemetry"]
    events = {
        name: [d["data"] for n, d in docs if n == "event" and d["descriptor"] == desc["uid"]]
        for name, desc in descriptors.items()
    }
    assert start["plan_name"] == "towed_pass" and start["operator"] == "ci"
    assert start["tow"]["start_m"] == -2.0 and start["tow"]["end_m"] == -3.5
    assert start["tow"]["speed_mps"] == 1.5 and start["simulated"] is True
    assert stop["exit_status"] == "success"
    assert stop["num_events"] == {
        "primary": 1,
        "estimates": len(events["estimates"]),
        "telemetry": len(events["telemetry"]),
    }
    descriptor = descriptors["primary"]
    keys = descriptor["data_keys"]
    assert keys["tank-range_rmse_m"]["units"] == "m" and keys["tank-range_rmse_m"]["shape"] == []
    assert descriptors["telemetry"]["data_keys"]["tank-stage_position_m"]["units"] == "m"
    assert descriptors["telemetry"]["data_keys"]["tank-stage_position_m"]["shape"] == []
    config = descriptor["configuration"]["tank"]["data"]
    assert config["tank-stage_url"] == "sim://stage" and config["tank-tow_speed_mps"] == 1.5
    # The figures a live table shows, not the long recording path.
    assert sorted(descriptor["hints"]["tank"]["fields"]) == [
        "tank-detection_rate",
        "tank-estimates",
        "tank-range_rmse_m",
        "tank-speed_rmse_mps",
    ]

    (data,) = events["primary"]
    # The recording exists where the event says, and holds what the event reports.
    h5 = Path(data["tank-recording"])
    assert h5.name == "run.h5" and h5.parent.parent == tmp_path
    assert (h5.parent / "summary.json").exists()
    assert "tank run 'bluesky-pass'" in (h5.parent / "run.log").read_text()
    assert data["tank-error"] == "" and data["tank-interrupted"] is False
    assert data["tank-dropped_samples"] == 0
    assert data["tank-latency_samples"] == 64  # the simulated converters
    rec = RunRecording.open(h5)
    live = rec.estimates()
    assert data["tank-estimates"] == len(live) >= 50
    np.testing.assert_array_equal(
        [e["tank-estimate_range_m"] for e in events["estimates"]], [e.range_m for e in live]
    )
    # The towed target is tracked (the tank run's own test holds the same bounds).
    assert data["tank-scored_estimates"] >= 50
    assert data["tank-range_rmse_m"] < 0.08 and data["tank-speed_rmse_mps"] < 0.1
    assert data["tank-detection_rate"] > 0.9
    # The stage moved: homed (0), to start - run-up (-1.4 m), through the pass at 1.5 m/s,
    # to end + run-down (-4.1 m).
    telemetry = events["telemetry"]
    x = np.array([e["tank-stage_position_m"] for e in telemetry])
    t = np.array([e["tank-stage_time_s"] for e in telemetry])
    assert x.shape == t.shape and x.size > 10
    assert np.all(np.diff(t) > 0)
    assert x.max() >= -1.4 - 1e-3 and x[-1] == pytest.approx(-4.1, abs=1e-3)
    assert x.min() == pytest.approx(-4.1, abs=1e-3)
    # At the tow speed inside the pass, as GRBL reported it (1 mm/min resolution). Not from
    # differences of positions over report times: a report's time is uncertain by its reply
    # delay, which a loaded machine stretches (the run's scoring filters those reports).
    v = np.array([e["tank-stage_velocity_mps"] for e in telemetry])
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
    # (about 2.5 s): late enough that the recording has started (0.05 s of capture). The file
    # refuses a max_duration_s shorter than the tow, so the limit is set on the parsed
    # experiment: what it stands for here is a tow that takes longer than planned.
    exp = dataclasses.replace(parse_experiment(SHORT), max_duration_s=1.5)
    run = TankRunDetector(exp, runs_dir=tmp_path, report=False, virtual_time=True, name="tank")
    call_in_bluesky_event_loop(run.connect())
    docs: list[tuple[str, dict[str, Any]]] = []
    with pytest.raises(FailedStatus) as err:
        run_engine(towed_pass(run), _collect(docs))
    assert isinstance(err.value.__cause__, TankRunError)
    names = [n for n, _ in docs]
    assert names[:3] == ["start", "descriptor", "event"] and names[-1] == "stop"
    data, stop = docs[2][1]["data"], docs[-1][1]
    assert data["tank-error"] == "RuntimeError: run.max_duration_s = 1.5 s exceeded"
    assert Path(data["tank-recording"]).exists()  # what was recorded until the error
    assert stop["exit_status"] == "fail"
    assert "run.max_duration_s = 1.5 s exceeded" in stop["reason"]


def test_each_trigger_gets_a_new_run_folder_under_runs_dir(tmp_path: Path) -> None:
    from hil.bluesky import TankRunDetector
    from hil.outputs import CLAIM

    run = TankRunDetector(parse_experiment(SHORT), runs_dir=tmp_path, name="tank")
    first = run.new_run_folder()
    second = run.new_run_folder()
    # New and empty but its claim, under runs_dir; two stamped in the same second get a
    # suffix.
    assert first.parent == tmp_path and first.name.startswith("bluesky-pass-")
    assert first.is_dir() and [p.name for p in first.iterdir()] == [CLAIM]
    assert second != first and second.parent == tmp_path


def _validated(docs: list[tuple[str, dict[str, Any]]]) -> None:
    """Every document valid against event-model's schemas, and every event's values of the
    shape and type its descriptor declares."""
    from event_model import DocumentNames, schema_validators

    descriptors: dict[str, dict[str, Any]] = {}
    for name, doc in docs:
        schema_validators[DocumentNames(name)].validate(doc)
        if name == "descriptor":
            descriptors[doc["uid"]] = doc
        if name == "event":
            keys = descriptors[doc["descriptor"]]["data_keys"]
            assert set(doc["data"]) == set(keys)
            for key, value in doc["data"].items():
                assert list(np.shape(value)) == keys[key]["shape"], key
                kind = {"number": (int, float), "integer": int, "string": str}
                if keys[key]["dtype"] in kind:
                    assert isinstance(value, kind[keys[key]["dtype"]]), key


@pytest.mark.slow
def test_count_of_three_tank_runs_gives_documents_valid_for_event_model(
    run_engine: Any, tmp_path: Path
) -> None:
    import bluesky.plans as bp
    from bluesky.run_engine import call_in_bluesky_event_loop

    from hil.bluesky import TankRunDetector, tank_shot

    # Three different passes (lengths differ, so do the numbers of estimates and reports).
    text = SHORT.replace("end_m = -3.5", "end_m = -2.9")
    run = TankRunDetector(
        parse_experiment(text), runs_dir=tmp_path, report=False, virtual_time=True, name="tank"
    )
    call_in_bluesky_event_loop(run.connect())
    docs: list[tuple[str, dict[str, Any]]] = []
    run_engine(bp.count([run], num=3, per_shot=tank_shot), _collect(docs))

    _validated(docs)
    stop = docs[-1][1]
    assert stop["exit_status"] == "success"
    descriptors = [d["name"] for n, d in docs if n == "descriptor"]
    assert descriptors == ["primary", "estimates", "telemetry"]  # one each, for 3 runs
    primary = [d["data"] for n, d in docs if n == "event" and "tank-recording" in d["data"]]
    assert len(primary) == 3 == stop["num_events"]["primary"]
    assert stop["num_events"]["estimates"] == sum(p["tank-estimates"] for p in primary)
    folders = sorted(tmp_path.iterdir())
    assert len(folders) == 3
    for folder, data in zip(folders, primary, strict=True):
        assert data["tank-recording"] == str(folder / "run.h5")
        assert (folder / "run.log").exists()
        assert json.loads((folder / "summary.json").read_text())["interrupted"] is False


class _PauseAtFirstEstimates:
    """``on_estimates`` that, at the first estimates, asks the RunEngine to pause and holds
    the run's thread until the detector is told to stop: the pause lands at a known instant
    of the run (the first estimates' time), whatever the threads' timing."""

    def __init__(self, run_engine: Any) -> None:
        self.run_engine = run_engine
        self.detector: Any = None
        self.first_t_s: float | None = None

    def __call__(self, batch: list[Any]) -> None:
        if batch and self.first_t_s is None:
            self.first_t_s = max(e.t_s for e in batch)
            self.run_engine.request_pause()
            self.detector.stop_requested.wait()


def _paused_count(run_engine: Any, tmp_path: Path) -> tuple[Any, _PauseAtFirstEstimates, list]:
    import bluesky.plans as bp
    from bluesky.run_engine import call_in_bluesky_event_loop
    from bluesky.utils import RunEngineInterrupted

    from hil.bluesky import TankRunDetector, tank_shot

    pauser = _PauseAtFirstEstimates(run_engine)
    run = TankRunDetector(
        parse_experiment(SHORT),
        runs_dir=tmp_path,
        report=False,
        virtual_time=True,
        on_estimates=pauser,
        name="tank",
    )
    pauser.detector = run
    call_in_bluesky_event_loop(run.connect())
    docs: list[tuple[str, dict[str, Any]]] = []
    with pytest.raises(RunEngineInterrupted):
        run_engine(bp.count([run], num=1, per_shot=tank_shot), _collect(docs))
    assert run_engine.state == "paused"
    return run, pauser, docs


def _assert_stopped_safely(folder: Path, first_t_s: float) -> None:
    """The run in ``folder`` was interrupted within 1 s of signal after the pause, and its
    recording is closed, readable, with its stop event."""
    from hil.recording.reader import RunRecording

    summary = json.loads((folder / "summary.json").read_text())
    assert summary["interrupted"] is True
    assert summary["error"] == "interrupted (stopped by the caller)"
    assert first_t_s < summary["signal_s"] < first_t_s + 1.0
    last = RunRecording.open(folder / "run.h5").events()[-1]
    assert last.kind == "alarm" and last.text == "stop: interrupted (stopped by the caller)"


@pytest.mark.slow
def test_an_abort_while_paused_leaves_the_tank_run_stopped_and_its_recording_closed(
    run_engine: Any, tmp_path: Path
) -> None:
    run, pauser, docs = _paused_count(run_engine, tmp_path)
    run_engine.abort()
    assert [n for n, _ in docs] == ["start", "stop"]
    assert docs[-1][1]["exit_status"] == "abort"
    (folder,) = tmp_path.iterdir()
    assert pauser.first_t_s is not None
    _assert_stopped_safely(folder, pauser.first_t_s)
    assert run.outcome is not None and run.outcome.interrupted


@pytest.mark.slow
def test_a_resume_after_a_pause_runs_the_tank_run_again_to_its_end(
    run_engine: Any, tmp_path: Path
) -> None:
    _, pauser, docs = _paused_count(run_engine, tmp_path)
    run_engine.resume()
    _validated(docs)
    stop = docs[-1][1]
    assert stop["exit_status"] == "success" and stop["num_events"]["primary"] == 1
    interrupted, complete = sorted(tmp_path.iterdir())
    assert pauser.first_t_s is not None
    _assert_stopped_safely(interrupted, pauser.first_t_s)
    (primary,) = [d["data"] for n, d in docs if n == "event" and "tank-recording" in d["data"]]
    assert primary["tank-recording"] == str(complete / "run.h5")
    assert primary["tank-interrupted"] is False and primary["tank-error"] == ""
    assert json.loads((complete / "summary.json").read_text())["interrupted"] is False
