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
