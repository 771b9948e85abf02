"""Sweep files: a good one loads into the expected grid; every bad one is refused before any
trial runs, naming the field by its dotted path and what is allowed."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.cli.main import main
from hil.errors import ConfigError
from hil.evaluation.sweep_file import load_sweep_file

HELPERS = Path(__file__).with_name("evaluation_trials_for_tests.py")

GOOD = """
[sweep]
name = "psl"
trial = "waveform_af_sidelobe"
trials_per_point = 3
seed = 12345
description = "PSL against code length"

[grid]
code_length = [17, 19, 23]
n_tones = [4, 5]

[fixed]
doppler_bins = 2
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "sweep.toml"
    path.write_text(text)
    return path


def test_good_file_loads(tmp_path: Path) -> None:
    spec = load_sweep_file(_write(tmp_path, GOOD))
    assert (spec.name, spec.trial, spec.trials_per_point, spec.seed) == (
        "psl",
        "waveform_af_sidelobe",
        3,
        12345,
    )
    assert spec.target == "hil.evaluation.trials_waveform:waveform_af_sidelobe"
    assert spec.description == "PSL against code length"
    assert (spec.n_points, spec.n_trials) == (6, 18)
    assert spec.points()[:3] == [
        {"code_length": 17, "n_tones": 4},
        {"code_length": 17, "n_tones": 5},
        {"code_length": 19, "n_tones": 4},
    ]
    assert [spec.point_values(p) for p in range(6)] == spec.points()
    tasks = list(spec.tasks(skip={0, 17}))
    assert [t.trial_id for t in tasks] == list(range(1, 17))
    assert tasks[3].params == {"doppler_bins": 2, "code_length": 17, "n_tones": 5}
    assert (tasks[3].point, tasks[3].rep) == (1, 1)


def test_relative_trial_file_is_found_next_to_the_sweep_file(tmp_path: Path) -> None:
    (tmp_path / "my_trials.py").write_text(HELPERS.read_text())
    text = GOOD.replace('"waveform_af_sidelobe"', '"my_trials.py:draw_trial"')
    text = text.split("[grid]")[0]
    spec = load_sweep_file(_write(tmp_path, text))
    assert spec.target == f"{tmp_path.resolve() / 'my_trials.py'}:draw_trial"
    assert spec.n_trials == 3


def _edit(old: str, new: str) -> str:
    assert old in GOOD
    return GOOD.replace(old, new)


BAD = [
    (
        _edit("[fixed]", "[fixd]"),
        "fixd = {'doppler_bins': 2} is not allowed: must be a known key of the top level: "
        "one of sweep, grid, fixed, quick; check the spelling",
    ),
    (
        _edit("seed = 12345", "seed = 12345\nrepeats = 4"),
        "sweep.repeats = 4 is not allowed: must be a known key of [sweep]: one of name, trial, "
        "trials_per_point, seed, description; check the spelling",
    ),
    (
        _edit('"waveform_af_sidelobe"', '"waveform_sidelobes"'),
        "sweep.trial = 'waveform_sidelobes' is not allowed: must be a registered trial (one of "
        "ch6_cost, ch6_fmcw, ch6_receiver, scene, tank_run, waveform_af_sidelobe), "
        "'package.module:function' or 'file.py:function'; register the "
        "trial with @register_trial or name its module and function",
    ),
    (
        _edit('"waveform_af_sidelobe"', '"no_such_pkg.trials:f"'),
        "sweep.trial = 'no_such_pkg.trials:f' is not allowed: must be a trial in an importable "
        "module; module 'no_such_pkg' is not installed here (workers need it too)",
    ),
    (
        _edit('"waveform_af_sidelobe"', '"hil.evaluation.trials_waveform:nope"'),
        "sweep.trial = 'hil.evaluation.trials_waveform:nope' is not allowed: must be a function "
        "that exists; hil.evaluation.trials_waveform has no 'nope'",
    ),
    (
        _edit("n_tones = [4, 5]", "n_tones = []"),
        "grid.n_tones = [] is not allowed: must be a non-empty array of values; give at least "
        "one value, or move the parameter to [fixed]",
    ),
    (
        _edit("n_tones = [4, 5]", "n_tones = 4"),
        "grid.n_tones = 4 is not allowed: must be a non-empty array of values; write "
        "n_tones = [4] to sweep over one value",
    ),
    (
        _edit("n_tones = [4, 5]", "n_tones = [4, 5, 4]"),
        "grid.n_tones[2] = 4 is not allowed: must be a value not listed before; remove the "
        "duplicate",
    ),
    (
        _edit("trials_per_point = 3", "trials_per_point = 0"),
        "sweep.trials_per_point = 0 is not allowed: must be an integer >= 1",
    ),
    (
        _edit("trials_per_point = 3", "trials_per_point = 2.5"),
        "sweep.trials_per_point = 2.5 is not allowed: must be an integer >= 1",
    ),
    (
        _edit("seed = 12345", "seed = -1"),
        "sweep.seed = -1 is not allowed: must be an integer >= 0 (the root entropy); "
        "e.g. seed = 20240601",
    ),
    (
        _edit("seed = 12345\n", ""),
        "sweep.seed = None is not allowed: must be given (it is required)",
    ),
    (
        _edit('name = "psl"', 'name = ""'),
        "sweep.name = '' is not allowed: must be a non-empty string",
    ),
    (
        _edit("doppler_bins = 2", "n_tones = 6"),
        "fixed.n_tones = 6 is not allowed: must be a parameter not also swept in [grid]; keep "
        "it in one table",
    ),
    (
        _edit("doppler_bins = 2", "when = 2024-06-01"),
        "fixed.when = datetime.date(2024, 6, 1) is not allowed: must be numbers, strings, "
        "booleans, or arrays/tables of them (no dates, no NaN)",
    ),
    (
        _edit("code_length = [17, 19, 23]", "code_length = [17, nan]"),
        "grid.code_length[1] = nan is not allowed: must be numbers, strings, booleans, or "
        "arrays/tables of them (no dates, no NaN)",
    ),
    (
        _edit("[grid]", "grid = 3\n[grod]"),
        "grod = {'code_length': [17, 19, 23], 'n_tones': [4, 5]} is not allowed: must be a known "
        "key of the top level: one of sweep, grid, fixed, quick; check the spelling",
    ),
    # The trial's own parameter check, on every grid point, named by where the value is.
    (
        _edit("doppler_bins = 2", "doppler_bin = 2"),
        "fixed.doppler_bin = 2 is not allowed: must be a parameter of waveform_af_sidelobe: "
        "n_tones, code_length, window, candidates, m_hops, center_hz, bandwidth_hz, hop_s, "
        "fs_hz, doppler_bins",
    ),
    (
        _edit("n_tones = [4, 5]", "n_tones = [4, 3]"),
        "window (the trial's default) = 3 is not allowed: must be large enough that "
        "N_F·(N_F−1)^(W−1) >= L = 17; with N_F = 3 and W = 3 only 12 distinct windows exist; "
        "at grid point {'code_length': 17, 'n_tones': 3}; set window in [fixed] or [grid]; "
        "increase the window W or the number of tones, or shorten the code",
    ),
    (
        _edit("n_tones = [4, 5]", "n_tones = [4, 1]"),
        "grid.n_tones = 1 is not allowed: must be an integer >= 2; at grid point "
        "{'code_length': 17, 'n_tones': 1}; a no-repeat code needs at least two tones",
    ),
]


@pytest.mark.parametrize(("text", "message"), BAD, ids=[m.split(" = ")[0] for _, m in BAD])
def test_bad_file_is_refused_naming_the_field(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_sweep_file(_write(tmp_path, text))
    assert str(err.value) == message


def test_toml_syntax_error_names_the_file(tmp_path: Path) -> None:
    path = _write(tmp_path, "[sweep\nname = 1")
    with pytest.raises(ConfigError) as err:
        load_sweep_file(path)
    assert str(err.value).startswith(
        f"sweep = '{path}' is not allowed: must be valid TOML (Expected ']' at the end of a "
        "table declaration (at line 1, column 7))"
    )


def test_bad_file_runs_no_trial_and_cli_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    marker = tmp_path / "markers.txt"
    text = f"""
[sweep]
name = "m"
trial = "{HELPERS}:marker_trial"
trials_per_point = 2
seed = 1

[grid]
k = [0, 1]
j = []

[fixed]
marker = "{marker}"
"""
    out = tmp_path / "out"
    status = main(["sweep", str(_write(tmp_path, text)), "--out", str(out), "--serial"])
    assert status == 2
    err = capsys.readouterr().err
    assert err == (
        "hil sweep: error: grid.j = [] is not allowed: must be a non-empty array of values; "
        "give at least one value, or move the parameter to [fixed]\n"
    )
    assert not marker.exists() and not out.exists()


def test_trial_parameter_check_refuses_before_running(tmp_path: Path) -> None:
    text = f"""
[sweep]
name = "m"
trial = "{HELPERS}:marker_trial"
seed = 1

[fixed]
marker = 3
"""
    with pytest.raises(ConfigError) as err:
        load_sweep_file(_write(tmp_path, text))
    assert str(err.value) == "fixed.marker = 3 is not allowed: must be a file path (string)"
