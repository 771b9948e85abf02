"""The shipped JSON Schemas and the parsers agree: the schemas are what the code generates,
every shipped and documented config file is valid for both, and bad files are refused by
both (the schema cannot check what spans tables; the parser does)."""

from __future__ import annotations

import copy
import json
import re
import tomllib
from pathlib import Path
from typing import Any

import jsonschema
import pytest

from hil.cli.main import main
from hil.cli.schema import SCHEMAS, schema, schema_path, schema_text
from hil.errors import ConfigError, ConfigErrors
from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from sim_devices.acoustics.scenario import parse_scenario

ROOT = Path(__file__).resolve().parents[2]


def _toml_blocks(path: Path) -> list[str]:
    """The ```toml blocks of a Markdown file."""
    return re.findall(r"```toml\n(.*?)```", path.read_text(encoding="utf-8"), flags=re.S)


def _kind(doc: dict[str, Any]) -> str | None:
    """Which config file a TOML document is: an experiment has [devices] or [tow]."""
    if "devices" in doc or "tow" in doc:
        return "experiment"
    if "preset" in doc:
        return "scenario"
    return None


def _documented() -> list[tuple[str, str, str]]:
    """(where, kind, text) of every shipped and documented config file."""
    files = [("DEFAULT_EXPERIMENT", "experiment", DEFAULT_EXPERIMENT)]
    for toml in sorted((ROOT / "hil" / "data" / "scenarios").glob("*.toml")):
        files.append((f"hil/data/scenarios/{toml.name}", "scenario", toml.read_text("utf-8")))
    for md in sorted((ROOT / "docs").glob("*.md")):
        for i, text in enumerate(_toml_blocks(md)):
            kind = _kind(tomllib.loads(text))
            if kind is not None:
                files.append((f"{md.name}[{i}]", kind, text))
    return files


def _parse(kind: str, text: str) -> object:
    if kind == "experiment":
        return parse_experiment(text)
    return parse_scenario(tomllib.loads(text))


def _validator(kind: str) -> jsonschema.protocols.Validator:
    shipped = json.loads(schema_path(kind).read_text(encoding="utf-8"))
    cls = jsonschema.validators.validator_for(shipped)
    cls.check_schema(shipped)
    return cls(shipped)


@pytest.mark.parametrize("kind", sorted(SCHEMAS))
def test_the_shipped_schema_is_the_one_the_code_generates(kind: str) -> None:
    assert schema_path(kind).read_text(encoding="utf-8") == schema_text(kind), (
        "regenerate it: hil schema --write"
    )


def test_the_documented_files_include_whole_experiments_and_scenarios() -> None:
    kinds = [(k, w.split("[")[0]) for w, k, _ in _documented()]
    assert ("experiment", "tank-run.md") in kinds
    # docs/tank-run.md shows the built-in file as "a whole file".
    assert DEFAULT_EXPERIMENT in _toml_blocks(ROOT / "docs" / "tank-run.md")
    assert kinds.count(("scenario", "scenarios.md")) == 3
    assert len([w for k, w in kinds if k == "scenario" and w.startswith("hil/data")]) == 3


@pytest.mark.parametrize(("where", "kind", "text"), _documented(), ids=lambda v: str(v)[:40])
def test_every_shipped_and_documented_file_is_valid_for_schema_and_parser(
    where: str, kind: str, text: str
) -> None:
    errors = list(_validator(kind).iter_errors(tomllib.loads(text)))
    assert errors == [], f"{where}: {[e.message for e in errors]}"
    _parse(kind, text)


def _edit(doc: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    """``doc`` with the dotted ``path`` set to ``value`` (None deletes it)."""
    out = copy.deepcopy(doc)
    *parents, last = path.split(".")
    node = out
    for p in parents:
        node = node.setdefault(p, {})
    if value is None:
        del node[last]
    else:
        node[last] = value
    return out


def _dumps(doc: dict[str, Any]) -> str:
    """A TOML document of tables of scalars and lists (what these files hold)."""

    def value(v: Any) -> str:
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        return json.dumps(v)

    lines = [f"{k} = {value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    for name, table in doc.items():
        if isinstance(table, dict):
            lines.append(f"[{name}]")
            lines += [f"{k} = {value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


EXPERIMENT = tomllib.loads(DEFAULT_EXPERIMENT)
BAD_EXPERIMENTS = [
    ("tow.speed_mp", 1.5, r"tow\.speed_mp = 1\.5 .*did you mean speed_mps\?"),
    ("tow.speed_mps", -1.5, r"tow\.speed_mps = -1\.5 .*must be > 0 and <= 5 m/s"),
    ("tow.start_m", None, r"tow\.start_m = None .*it is required"),
    ("tank.size_m", [12.0, 4.0], r"tank\.size_m = \[12\.0, 4\.0\] .*a list of 3 finite"),
    ("simulation.reverberation", "false", r"simulation\.reverberation = 'false' .*TOML boolean"),
    ("receiver.name", "gcass", r"receiver\.name = 'gcass' .*must be one of gcas, gcas-mti"),
    ("devices.board_channel", 16, r"devices\.board_channel = 16 .*an integer >= 0 and <= 15"),
    ("waveform.overrides", {"hop": 0.01}, r"waveform\.overrides\.hop = 0\.01 .*did you mean"),
    ("tank.size_m", [5000.0, 4.0, 2.5], r"tank\.size_m\[0\] = 5000\.0 .*<= 1000 m"),
    ("colour", {"red": 1}, r"colour = \{'red': 1\} .*one of the tables run, devices"),
]


@pytest.mark.parametrize(("path", "value", "message"), BAD_EXPERIMENTS)
def test_a_bad_experiment_is_refused_by_both(path: str, value: Any, message: str) -> None:
    doc = _edit(EXPERIMENT, path, value)
    assert list(_validator("experiment").iter_errors(doc)), "the schema accepted it"
    with pytest.raises(ConfigError, match=message):
        parse_experiment(_dumps(doc))


SCENARIO = tomllib.loads((ROOT / "hil" / "data" / "scenarios" / "tank-audio.toml").read_text())
BAD_SCENARIOS = [
    ("preset", None, r"^preset = None .*it is required"),
    ("preset", "tank", r"^preset = 'tank' .*one of att, tank-audio, tank-board"),
    ("duration_s", 0.0, r"^duration_s = 0\.0 .*> 0 and <= 86400 s"),
    ("sonar.speed", 3.0, r"^sonar\.speed = 3\.0 .*one of the keys position_m"),
    ("tank.image_order", 5, r"^tank\.image_order = 5 .*<= 4"),
    ("noise.enabled", "yes", r"^noise\.enabled = 'yes' .*TOML boolean"),
    ("output.channels", ["recieved"], r"^output\.channels = \['recieved'\] .*a list of received"),
    ("waveform.hop", 0.01, r"^waveform\.hop = 0\.01 .*did you mean hop_s\?"),
    ("targets", [{"trajectory": "radial"}], r"^targets\[0\]\.range_m = None .*a radial"),
    ("sonar.beam", {"type": "piston"}, r"^sonar\.beam\.radius_m = None .*\(or ka\)"),
    ("sonar.beam", {"type": "table"}, r"^sonar\.beam\.angles_deg = None .*a list of numbers"),
]


@pytest.mark.parametrize(("path", "value", "message"), BAD_SCENARIOS)
def test_a_bad_scenario_is_refused_by_both(path: str, value: Any, message: str) -> None:
    doc = _edit(SCENARIO, path, value)
    assert list(_validator("scenario").iter_errors(doc)), "the schema accepted it"
    with pytest.raises(ConfigError, match=message):
        parse_scenario(doc)


def test_a_scenario_with_several_problems_names_each_once() -> None:
    doc = _edit(_edit(_edit(SCENARIO, "seed", -1), "sonar.gain_db", 500.0), "tank.size_m", [1, 2])
    with pytest.raises(ConfigErrors) as err:
        parse_scenario(doc)
    assert [e.field for e in err.value.errors] == ["seed", "sonar.gain_db", "tank.size_m"]


def test_the_schema_command_prints_and_lists(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["schema", "experiment"]) == 0
    assert json.loads(capsys.readouterr().out) == schema("experiment")
    assert main(["schema"]) == 0
    assert f"experiment  {schema_path('experiment')}" in capsys.readouterr().out
    assert main(["schema", "experimnt"]) == 2
    assert capsys.readouterr().err == (
        f"hil schema: error: KIND = 'experimnt' is not allowed: must be one of"
        f" {', '.join(SCHEMAS)}; hil schema lists them (did you mean experiment?)\n"
    )


def test_the_editor_recipe_a_schema_line_first_is_a_comment_the_parser_ignores(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """docs/tank-run.md: ``#:schema PATH`` as the first line, PATH from ``hil schema``."""
    from hil.experiments.experiment import load_experiment

    assert main(["schema"]) == 0
    listed = dict(line.split(maxsplit=1) for line in capsys.readouterr().out.splitlines())
    assert Path(listed["experiment"]).is_file() and Path(listed["scenario"]).is_file()
    path = tmp_path / "lab.experiment.toml"
    path.write_text(f"#:schema {listed['experiment']}\n{DEFAULT_EXPERIMENT}", encoding="utf-8")
    exp, plain = load_experiment(path), parse_experiment(DEFAULT_EXPERIMENT)
    assert (exp.tow, exp.simulation, exp.board_url) == (
        plain.tow,
        plain.simulation,
        plain.board_url,
    )


def test_hil_simulate_prints_every_problem_of_a_scenario_one_per_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = (ROOT / "hil" / "data" / "scenarios" / "tank-audio.toml").read_text("utf-8")
    assert "\nseed = 2\n" in text and "\nimage_order = 1\n" in text
    path = tmp_path / "bad.toml"
    bad = text.replace("\nseed = 2\n", "\nseed = -1\n").replace(
        "image_order = 1", "image_order = 5"
    )
    path.write_text(bad, encoding="utf-8")
    out = tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(out)]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "hil simulate: error: seed = -1 is not allowed: must be an integer >= 0 and <= 4294967295",
        "hil simulate: error: tank.image_order = 5 is not allowed: must be an integer >= 0 and"
        " <= 4",
    ]
    assert not out.exists()
