"""The wheel carries every data file a command needs (sweep files, scenarios, protocol SPEC
and golden vectors, the watch page) and the ``hil`` entry point."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("hil", "firmware_protocol", "sim_devices")


def _can_build_wheels() -> bool:
    """setuptools can build a wheel without an isolated build environment."""
    if importlib.util.find_spec("setuptools") is None:
        return False
    if importlib.util.find_spec("setuptools.command.bdist_wheel") is not None:
        return True
    return importlib.util.find_spec("wheel") is not None


def _data_files() -> set[str]:
    """Every non-Python file inside the packages, as the wheel would name it."""
    out = set()
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*"):
            if path.is_file() and path.suffix in (".toml", ".json", ".md", ".html"):
                out.add(path.relative_to(ROOT).as_posix())
    return out


@pytest.mark.slow
def test_wheel_holds_every_data_file_and_the_entry_point(tmp_path: Path) -> None:
    if not _can_build_wheels():
        pytest.skip("no wheel support in this environment (pip install -e '.[test]' adds it)")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(tmp_path), str(ROOT)],
        check=True, capture_output=True, cwd=tmp_path,
    )  # fmt: skip
    (wheel,) = tmp_path.glob("cas_hil-*.whl")
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        entry_points = next(n for n in names if n.endswith(".dist-info/entry_points.txt"))
        scripts = zf.read(entry_points).decode()
    expected = _data_files()
    must = {"hil/data/sweeps/sim01_codeword_map.toml", "hil/data/sweeps/tank-mc.toml",
            "hil/data/sweeps/scenes.toml",
            "hil/data/scenarios/att.toml",
            "hil/data/schema/experiment.schema.json", "hil/data/schema/scenario.schema.json",
            "firmware_protocol/SPEC.md", "firmware_protocol/golden_vectors.json"}  # fmt: skip
    assert must <= expected
    assert expected <= names, sorted(expected - names)
    assert "hil/data/__init__.py" in names
    # The documentation (hil docs) and the typing marker travel with the package.
    docs = {f"hil/docs/{p.name}" for p in (ROOT / "docs").glob("*.md")}
    assert docs and docs <= names, sorted(docs - names)
    assert {"hil/py.typed", "sim_devices/py.typed", "firmware_protocol/py.typed"} <= names
    assert not any(n.startswith(("tests/", "benchmarks/", "docs/")) for n in names)
    assert "hil = hil.cli.main:main" in scripts


def test_shipped_data_is_found_through_importlib_resources() -> None:
    from hil.data import scenario_path, shipped_scenarios, sweeps_dir
    from hil.evaluation.reproduce import ITEM_IDS, default_sweeps_dir

    assert default_sweeps_dir() == sweeps_dir()
    # The chapter-6 items, the tank study of `hil sweep tank-mc` and the receiver's scenes of
    # `hil sweep scenes`.
    shipped = sorted(p.stem for p in sweeps_dir().glob("*.toml"))
    assert shipped == sorted([*ITEM_IDS, "tank-mc", "scenes"])
    assert set(shipped_scenarios()) == {"att", "tank-audio", "tank-board"}
    assert scenario_path("tank-board").read_text().startswith(("preset", "#", "["))


def test_unknown_scenario_name_is_refused_with_the_choices() -> None:
    from hil.data import scenario_path
    from hil.errors import ConfigError

    with pytest.raises(ConfigError, match=r"scenario = 'attt' .* one of att, tank-audio"):
        scenario_path("attt")
