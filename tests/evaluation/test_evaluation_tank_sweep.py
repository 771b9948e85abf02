"""The tank trial (``tank_run``), the shipped ``tank-mc`` sweep, ``--quick`` and shipped sweep
names, the tank report, batched hand-out; and, slow, docs/tank-run.md's command as written."""

from __future__ import annotations

import csv
import json
import re
import shlex
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil.cli.main import main
from hil.errors import ConfigError
from hil.evaluation.report_tank import tank_rows, write_tank_report
from hil.evaluation.runners import BatchSizer
from hil.evaluation.spec import SweepSpec
from hil.evaluation.sweep_file import (
    find_sweep_file,
    load_sweep_file,
    quick_document,
    sweep_from_dict,
)
from hil.evaluation.trials_tank import build_experiment, experiment_text, simulation_seed
from hil.experiments.experiment import DEFAULT_EXPERIMENT
from hil.toml_table import parse_toml

ROOT = Path(__file__).resolve().parents[2]
TANK_DOC = ROOT / "docs" / "tank-run.md"


def _sweep(grid: dict[str, Any], fixed: dict[str, Any] | None = None) -> SweepSpec:
    doc = {"sweep": {"name": "t", "trial": "tank_run", "seed": 1}, "grid": grid}
    return sweep_from_dict({**doc, "fixed": fixed or {}})


# ----------------------------------------------------------------------------- the experiment
def test_no_parameter_gives_the_built_in_run_with_the_drawn_seed() -> None:
    exp = build_experiment({}, 1234)
    base = parse_toml(DEFAULT_EXPERIMENT, "experiment")
    assert exp.tank_size_m == tuple(base["tank"]["size_m"])
    assert (exp.tow.start_m, exp.tow.end_m, exp.tow.speed_mps) == (-2.0, -5.0, 1.5)
    assert exp.simulation.seed == 1234
    assert exp.receiver == "gcas-bg"  # the built-in file's
    assert exp.calibration_required == ()


def test_parameters_land_in_their_experiment_fields() -> None:
    exp = build_experiment(
        {"tow_speed_mps": 1.0, "noise_level_db": 70.0, "image_order": 2, "tow_repeats": 3,
         "m_hops": 8},
        7,
    )  # fmt: skip
    assert exp.tow.speed_mps == 1.0
    assert exp.tow.repeats == 3
    assert exp.simulation.noise_level_db == 70.0
    assert exp.simulation.image_order == 2
    assert exp.m_hops == 8
    # 3 passes of 4.2 m at 1 m/s: 12.6 s at least; the 120 s of the file is kept.
    assert exp.max_duration_s == 120.0


def test_slow_long_tows_get_room_in_max_duration() -> None:
    exp = build_experiment({"tow_speed_mps": 0.1, "tow_repeats": 4}, 0)
    # 4 passes x (3 + 0.6 + 0.6) m / 0.1 m/s = 168 s; twice that plus 30 s.
    assert exp.max_duration_s == pytest.approx(366.0)


def test_tank_size_keeps_the_end_wall_distances_and_the_depth_at_mid_width() -> None:
    exp = build_experiment({"tank_size_m": [14.0, 6.0, 4.0]}, 0)
    assert exp.tank_size_m == (14.0, 6.0, 4.0)
    assert exp.transducer_m == (0.5, 3.0, -1.2)
    assert exp.stage_origin_m == (13.0, 3.0, -1.2)  # 1 m from the far wall, as in 12 m
    # The tow's ranges are the built-in ones: same distance from the transducer.
    assert exp.range_at(np.array([-2.0, -5.0])) == pytest.approx([10.5, 7.5])


@pytest.mark.parametrize(("direction", "start", "end"), [("closing", -2.0, -5.0),
                                                          ("opening", -5.0, -2.0)])  # fmt: skip
def test_direction_orders_the_tow(direction: str, start: float, end: float) -> None:
    exp = build_experiment({"direction": direction}, 0)
    assert (exp.tow.start_m, exp.tow.end_m) == (start, end)
    r_start, r_end = exp.range_at(np.array([exp.tow.start_m, exp.tow.end_m]))
    assert (r_end < r_start) == (direction == "closing")


def test_a_lab_file_is_read_its_devices_simulated_and_calibrations_dropped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    lab = DEFAULT_EXPERIMENT.replace('board = "sim://board"', 'board = "serial:///dev/ttyACM0"')
    lab = lab.replace('stage = "sim://stage"', 'stage = "serial:///dev/ttyUSB0"')
    lab = lab.replace("required = []", 'required = ["latency"]')
    lab = lab.replace("speed_mps = 1.5", "speed_mps = 0.8")
    (tmp_path / "lab.toml").write_text(lab, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    exp = build_experiment({"experiment": "lab.toml"}, 3)
    assert (exp.board_url, exp.stage_url) == ("sim://board", "sim://stage")
    assert exp.calibration_required == ()
    assert exp.tow.speed_mps == 0.8
    text, source = experiment_text({"experiment": "lab.toml"}, 3)
    assert source == "lab.toml"
    assert "serial://" not in text


def test_simulation_seed_is_32_bits_of_the_trial_seed() -> None:
    seeds = {simulation_seed(np.random.SeedSequence(3030, spawn_key=(p, 0))) for p in range(4)}
    assert len(seeds) == 4
    assert all(0 <= s < 2**32 for s in seeds)
    assert simulation_seed(np.random.SeedSequence(3030, spawn_key=(0, 0))) == 2178472088


# ----------------------------------------------------------------------------- bad inputs
@pytest.mark.parametrize(
    ("grid", "message"),
    [
        ({"direction": ["up"]}, "grid.direction = 'up' is not allowed: must be one of closing, "
                                "opening"),
        ({"tank_size_m": [[12.0, 4.0]]}, "grid.tank_size_m = [12.0, 4.0] is not allowed: must be "
                                         "[L, W, D]: three lengths > 0, m"),
        ({"tow_speed_mps": [1.0, 3.5]}, "grid.tow_speed_mps = 3.5 is not allowed: must be <= "
                                        "receiver.max_speed_mps = 3.0 m/s"),
        ({"image_order": [9]}, "grid.image_order = 9 is not allowed: must be an integer >= 0 "
                               "and <= 4"),
        ({"tank_size_m": [[6.0, 4.0, 2.5]]}, "grid.tank_size_m = [6.0, 4.0, 2.5] is not "
                                             "allowed: must be a tow that fits the tank"),
        ({"receiver": ["nope"]}, "grid.receiver = 'nope' is not allowed"),
        ({"speed": [1.0]}, "grid.speed = 1.0 is not allowed: must be a parameter of tank_run: "
                           "experiment, tank_size_m"),
    ],
)  # fmt: skip
def test_bad_points_are_refused_naming_the_sweep_parameter(
    grid: dict[str, Any], message: str
) -> None:
    with pytest.raises(ConfigError) as info:
        _sweep(grid)
    assert str(info.value).startswith(message), str(info.value)


def test_a_missing_experiment_file_is_refused_naming_it(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"^fixed.experiment = '.*nope.toml' is not allowed: "
                       r"must be an existing experiment file, or \"built-in\""):  # fmt: skip
        _sweep({"tow_speed_mps": [1.0]}, {"experiment": str(tmp_path / "nope.toml")})


# ----------------------------------------------------------------------------- sweep files
def test_tank_mc_is_shipped_and_found_by_name() -> None:
    path = find_sweep_file("tank-mc")
    assert path.name == "tank-mc.toml"
    full = load_sweep_file("tank-mc")
    assert (full.trial, full.n_points, full.trials_per_point) == ("tank_run", 48, 4)
    assert set(full.grid) == {"tank_size_m", "tow_speed_mps", "direction", "noise_level_db",
                              "image_order"}  # fmt: skip
    quick = load_sweep_file("tank-mc", quick=True)
    assert quick.n_trials == 2
    assert quick.points() == [
        {"tank_size_m": [12.0, 4.0, 2.5], "tow_speed_mps": 1.5, "direction": d,
         "noise_level_db": 55.0, "image_order": 1}
        for d in ("closing", "opening")
    ]  # fmt: skip


def test_an_unknown_name_is_refused_listing_the_shipped_sweeps(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"^SWEEP = 'tank-mx' is not allowed: must be a sweep "
                       r"file, or a shipped sweep: one of .*tank-mc"):  # fmt: skip
        find_sweep_file("tank-mx")


def test_quick_replaces_grid_values_and_trial_count() -> None:
    doc = {"sweep": {"name": "q", "trial": "waveform_af_sidelobe", "seed": 1,
                     "trials_per_point": 5},
           "grid": {"n_tones": [4, 5], "code_length": [17, 19]},
           "quick": {"trials_per_point": 1, "grid": {"code_length": [17]}}}  # fmt: skip
    assert sweep_from_dict(doc).n_trials == 20
    quick = sweep_from_dict(quick_document(doc))
    assert (quick.n_trials, quick.grid) == (2, {"n_tones": [4, 5], "code_length": [17]})


@pytest.mark.parametrize(
    ("quick", "message"),
    [
        ({"grid": {"window": [3]}}, "quick.grid.window = [3] is not allowed: must be a parameter "
                                    "swept in [grid]"),
        ({"trials_per_point": 0}, "quick.trials_per_point = 0 is not allowed: must be an "
                                  "integer >= 1"),
        ({"reps": 1}, "quick.reps = 1 is not allowed: must be a known key of [quick]"),
    ],
)  # fmt: skip
def test_bad_quick_tables_are_refused(quick: dict[str, Any], message: str) -> None:
    doc = {"sweep": {"name": "q", "trial": "waveform_af_sidelobe", "seed": 1},
           "grid": {"n_tones": [4, 5]}, "quick": quick}  # fmt: skip
    with pytest.raises(ConfigError) as info:
        sweep_from_dict(doc)
    assert str(info.value).startswith(message)


def test_quick_without_a_quick_table_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('[sweep]\nname = "s"\ntrial = "waveform_af_sidelobe"\nseed = 1\n')
    with pytest.raises(ConfigError, match=r"^--quick = True is not allowed: must be a sweep "
                       r"file with a \[quick\] table"):  # fmt: skip
        load_sweep_file(path, quick=True)


# ----------------------------------------------------------------------------- the report
def _record(point: int, rep: int, detected: int, false: int, errors: list[float]) -> dict:
    result = {"expected_boundaries": 10, "detected_boundaries": detected,
              "scored_estimates": len(errors), "false_alarms": false, "range_errors_m": errors,
              "speed_errors_mps": [0.01 * e for e in errors]}  # fmt: skip
    return {"trial_id": 2 * point + rep, "point": point, "rep": rep, "status": "ok",
            "result": result}  # fmt: skip


def test_tank_rows_pool_every_run_of_a_point() -> None:
    spec = SweepSpec("t", "tank_run", "m:t", 2, 0, {"direction": ["closing", "opening"]})
    records = [
        _record(0, 0, 10, 0, [0.01, -0.01, 0.02]),
        _record(0, 1, 8, 1, [0.03]),
        _record(1, 0, 0, 2, [-0.3, -0.25]),
        {"trial_id": 3, "point": 1, "rep": 1, "status": "error", "error": {}},
    ]
    rows = tank_rows(spec, records)
    assert rows[0]["detection_rate"] == 0.9
    assert rows[0]["false_alarm_rate"] == 0.25
    errors = np.array([0.01, -0.01, 0.02, 0.03])
    assert rows[0]["range_rmse_m"] == pytest.approx(np.sqrt(np.mean(errors**2)))
    assert rows[0]["range_bias_m"] == pytest.approx(0.0125)
    assert rows[0]["range_median_m"] == pytest.approx(0.015)
    assert rows[0]["speed_rmse_mps"] == pytest.approx(0.01 * np.sqrt(np.mean(errors**2)))
    assert (rows[1]["n_ok"], rows[1]["n_failed"]) == (1, 1)
    assert rows[1]["detection_rate"] == 0.0
    assert rows[1]["false_alarm_rate"] == 1.0
    assert rows[1]["range_p95_m"] == pytest.approx(-0.2525)


def test_the_report_writes_its_table_figures_and_markdown(tmp_path: Path) -> None:
    spec = SweepSpec("t", "tank_run", "m:t", 1, 0, {"direction": ["closing", "opening"]})
    records = [_record(0, 0, 10, 0, [0.01, -0.01]), _record(1, 0, 0, 2, [-0.3, -0.25])]
    records[1]["trial_id"] = 1
    paths = write_tank_report(spec, records, tmp_path)
    assert [p.name for p in paths] == ["report.md", "tank_points.csv", "tank_range_errors.png",
                                       "tank_speed_errors.png", "tank_rates.png"]  # fmt: skip
    for png in paths[2:]:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with (tmp_path / "tank_points.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["direction"], r["detection_rate"], r["false_alarm_rate"]) for r in rows] == [
        ("closing", "1", "0"), ("opening", "0", "1")
    ]  # fmt: skip
    report = (tmp_path / "report.md").read_text()
    assert "| closing | 1 | 0 | 0.01 | 0 |" in report
    # The opening point's signed errors -0.3 and -0.25 m: its 5th and 95th percentiles both
    # stand in the table, so a one-sided error reads as one.
    assert "range_p05_m | range_p95_m" in report
    assert "| opening | 0 | 1 | 0.2761 | -0.275 | -0.2975 | -0.2525 |" in report
    assert "![range errors](figures/tank_range_errors.png)" in report


# ----------------------------------------------------------------------------- batches
def test_batches_start_at_one_trial_then_fill_a_second() -> None:
    sizer = BatchSizer()
    assert sizer.size == 1
    sizer.observe([{"elapsed_s": 0.004}] * 10)
    assert sizer.size == 250
    sizer.observe([{"elapsed_s": 0.0001}] * 1000)
    assert sizer.size == 256  # at most MAX_BATCH
    slow = BatchSizer()
    slow.observe([{"elapsed_s": 10.0}])
    assert slow.size == 1
    tiny = BatchSizer(most=8)
    tiny.observe([{"elapsed_s": 0.0}])
    assert tiny.size == 8


# ----------------------------------------------------------------------------- the documented run
def _documented_quick_command() -> list[str]:
    """``hil sweep tank-mc ... --quick`` as docs/tank-run.md writes it (the hil word dropped)."""
    lines = [
        line.split("#", 1)[0].strip()
        for line in TANK_DOC.read_text(encoding="utf-8").splitlines()
        if re.match(r"^hil sweep tank-mc .*--quick", line)
    ]
    assert len(lines) == 1, lines
    return shlex.split(lines[0])[1:]


def test_the_documented_own_tank_sweep_file_validates(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    text = TANK_DOC.read_text(encoding="utf-8")
    block = re.search(r'```toml\n(\[sweep\]\nname = "my-tank".*?)```', text, re.S)
    assert block is not None
    (tmp_path / "my-tank.sweep.toml").write_text(block.group(1), encoding="utf-8")
    (tmp_path / "my-tank.toml").write_text(DEFAULT_EXPERIMENT, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    spec = load_sweep_file(tmp_path / "my-tank.sweep.toml")
    assert (spec.trial, spec.n_points, spec.trials_per_point) == ("tank_run", 4, 8)
    assert spec.fixed == {"experiment": "my-tank.toml"}


@pytest.mark.slow
def test_the_documented_quick_tank_sweep_runs_and_reports(tmp_path: Path) -> None:
    args = _documented_quick_command()
    out = tmp_path / "tank-mc"
    args[args.index("--out") + 1] = str(out)
    assert main([*args, "--quiet"]) == 0
    records = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    assert sorted(r["trial_id"] for r in records) == [0, 1]
    by_dir = {r["params"]["direction"]: r["result"] for r in records}
    # The built-in tank's closing and opening passes: every expected boundary found, none
    # wrong (the empty-tank background reads a receding target as it reads a closing one).
    for direction in ("closing", "opening"):
        run = by_dir[direction]
        assert run["expected_boundaries"] > 150, direction
        assert run["detection_rate"] >= 0.95, direction
        assert run["false_alarms"] == 0, direction
        assert run["range_rmse_m"] < 0.02 and run["speed_rmse_mps"] < 0.02, direction
        assert len(run["range_errors_m"]) == run["scored_estimates"]
        errs = np.array(run["range_errors_m"])
        assert np.sqrt(np.mean(errs**2)) == pytest.approx(run["range_rmse_m"], abs=1e-5)
    # The report's table pools the records it came from.
    with (out / "tank_points.csv").open() as fh:
        rows = {r["direction"]: r for r in csv.DictReader(fh)}
    for direction, result in by_dir.items():
        expected = result["detected_boundaries"] / result["expected_boundaries"]
        assert float(rows[direction]["detection_rate"]) == pytest.approx(expected, abs=1e-5)
    for name in ("report.md", "figures/tank_range_errors.png", "figures/tank_speed_errors.png",
                 "figures/tank_rates.png", "summary.csv", "manifest.json"):  # fmt: skip
        assert (out / name).is_file(), name
