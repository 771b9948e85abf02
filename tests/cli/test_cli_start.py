"""``hil`` starts without the commands' heavy imports; every command's parser is reachable."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pytest

from hil.cli.main import COMMANDS, build_parser, main

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("numpy", "scipy", "matplotlib", "h5py", "numba", "sim_devices", "serial", "usb")


def _modules_after(argv: list[str]) -> set[str]:
    """Top-level modules imported by ``hil ARGV`` in a fresh interpreter."""
    code = (
        "import json, sys\n"
        "from hil.cli.main import main\n"
        "try:\n"
        f"    main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    return set(json.loads(proc.stdout.strip().splitlines()[-1]))


def test_help_imports_none_of_the_heavy_modules() -> None:
    loaded = _modules_after(["--help"])
    assert "hil" in loaded
    assert loaded.isdisjoint(HEAVY), sorted(loaded & set(HEAVY))


def test_a_command_imports_only_its_own_module() -> None:
    loaded = _modules_after(["sim-serve", "--help"])
    assert loaded.isdisjoint(HEAVY), sorted(loaded & set(HEAVY))


@pytest.mark.parametrize("argv", [["estimate"], ["replay"], ["calibrate", "latency"], ["tank-run"]])
def test_heavy_commands_build_their_parser_without_numba_scipy_or_h5py(argv: list[str]) -> None:
    # Their runs import numba, scipy and h5py (about 1-2 s of CPU); their --help needs none of
    # them (the receivers' names in the help come from the registry, which needs numpy only).
    loaded = _modules_after([*argv, "--help"])
    assert "hil" in loaded
    assert loaded.isdisjoint({"numba", "scipy", "h5py", "matplotlib"}), sorted(loaded)


def _subparsers(parser: argparse.ArgumentParser) -> argparse._SubParsersAction:  # type: ignore[type-arg]
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))


def test_summaries_equal_what_each_command_registers() -> None:
    registered = {a.dest: a.help for a in _subparsers(build_parser())._choices_actions}
    assert registered == {name: summary for name, (_, summary) in COMMANDS.items()}


@pytest.mark.parametrize("name", list(COMMANDS))
def test_every_command_has_a_description_and_help(
    name: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as stop:
        main([name, "--help"])
    assert stop.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: hil {name}")
    sub = _subparsers(build_parser([name])).choices[name]
    assert sub.description and len(sub.description) > 40


def test_unknown_command_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["simulat"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'simulat'" in err


def _help(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    with pytest.raises(SystemExit) as stop:
        main([*argv, "--help"])
    assert stop.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("kind", ["latency", "response", "level", "sound-speed", "stage"])
def test_calibrate_kinds_have_descriptions_and_defaults(
    kind: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out = " ".join(_help(capsys, "calibrate", kind).split())
    assert "stores the result apart, in STORE/simulated/" in out
    assert "$HIL_CALIBRATION_DIR" in out
    assert "(default" in out.split("options:")[1]
    assert "%%" not in out


def test_defaults_are_shown_once(capsys: pytest.CaptureFixture[str]) -> None:
    out = " ".join(_help(capsys, "estimate").split())
    assert (
        "correlator length M, hops (as hil waveform --m-hops; --M is the same) (default: 10)" in out
    )
    assert "input channel" not in out  # estimate has none; calibrate shows its 0 below
    assert "output channel (0-based) (default: 0)" in " ".join(
        _help(capsys, "calibrate", "latency").split()
    )
    assert out.count("(default") == out.count("default") - out.count("defaults")


def test_sim_serve_help_is_plain_text_and_says_how_to_use_it(
    capsys: pytest.CaptureFixture[str],
) -> None:
    out = _help(capsys, "sim-serve")
    assert "``" not in out and ":class:" not in out
    assert 'board = "/dev/pts/5"' in out and "$ hil tank-run my-experiment.toml" in out


def test_tank_run_help_says_where_outputs_go(capsys: pytest.CaptureFixture[str]) -> None:
    out = " ".join(_help(capsys, "tank-run").split())
    assert "run.output_dir/NAME-YYYYmmdd-HHMMSS" in out and "$HIL_RUNS_DIR" in out
    assert "run.h5 (the recording), run.log, summary.json" in out
