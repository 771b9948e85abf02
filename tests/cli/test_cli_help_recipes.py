"""The recipes that ``--help`` texts give, run as written."""

from __future__ import annotations

import json
import re
import selectors
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import pytest

#: Bound on each wait for a served device to print its port, s.
PORT_WAIT_S = 120.0


def _recipe_commands(text: str) -> list[str]:
    """The shell commands of a help text: its ``$ hil ...`` lines, comments dropped."""
    return [
        line.split("$ ", 1)[1].split("  #", 1)[0].strip()
        for line in text.splitlines()
        if line.strip().startswith("$ hil ")
    ]


def _hil(command: str) -> list[str]:
    words = shlex.split(command)
    assert words[0] == "hil"
    return [sys.executable, "-m", "hil.cli.main", *words[1:]]


def _first_line(proc: subprocess.Popen[str]) -> str:
    """The first stdout line of ``proc``, waited for up to :data:`PORT_WAIT_S`."""
    assert proc.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        assert sel.select(PORT_WAIT_S), f"{proc.args} printed nothing in {PORT_WAIT_S} s"
    return proc.stdout.readline().strip()


@pytest.mark.slow
def test_the_sim_serve_help_recipe_runs_a_tank_run_on_served_devices(tmp_path: Path) -> None:
    from hil.cli.sim_serve import DESCRIPTION

    # The first four: the board and stage recipe (tests/experiments/test_tank_run_jack.py
    # runs the JACK tank's).
    serve_board, serve_stage, print_default, tank_run = _recipe_commands(DESCRIPTION)[:4]
    assert serve_board.startswith("hil sim-serve board") and tank_run.startswith("hil tank-run")
    servers = [
        subprocess.Popen(_hil(c), stdout=subprocess.PIPE, text=True, cwd=tmp_path)
        for c in (serve_board, serve_stage)
    ]
    try:
        board, stage = (_first_line(p) for p in servers)
        # `hil tank-run --print-default > my-experiment.toml`
        command, redirect = print_default.split(" > ")
        with (tmp_path / redirect).open("w") as out:
            subprocess.run(_hil(command), stdout=out, check=True, cwd=tmp_path)
        # "put the printed paths in it, give it a receiver that needs no empty-tank capture"
        path = tmp_path / redirect
        text = path.read_text()
        text = re.sub(r'(?m)^board = ".*"$', f'board = "{board}"', text, count=1)
        text = re.sub(r'(?m)^stage = ".*"$', f'stage = "{stage}"', text, count=1)
        text, named = re.subn(r'(?m)^name = "gcas-bg"$', 'name = "gcas-mti"', text, count=1)
        text, dropped = re.subn(r'(?m)^options = \{ background = "simulated" \}\n', "", text)
        assert (named, dropped) == (1, 1)
        # What the recipe runs is its commands, not the tow: the pass shortened to the suite's
        # short one near home (1.5 m from -0.7 m, no positioning out to the default's -1.4 m
        # run-up before it streams), the built-in pass costing seconds more of wall time.
        text, moved = re.subn(r"(?m)^start_m = -2\.0$", "start_m = -0.7", text)
        text, cut = re.subn(r"(?m)^end_m = -5\.0$", "end_m = -2.2", text)
        assert (moved, cut) == (1, 1)
        path.write_text(text)
        run = subprocess.run(_hil(tank_run), cwd=tmp_path, capture_output=True, text=True)
    finally:
        for p in servers:
            p.send_signal(signal.SIGTERM)
        for p in servers:
            p.communicate(timeout=60)
    assert run.returncode == 0, run.stderr
    folder = tmp_path / shlex.split(tank_run)[shlex.split(tank_run).index("--out") + 1]
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["error"] == ""
    # Measured on the DAC monitor input: the served cable's delay (--delay 64).
    assert summary["loopback_latency_samples"] == 64


def test_stage_settings_check_passes_the_built_in_experiment(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``hil tank-run --print-default > exp.toml`` then ``hil stage settings --check
    exp.toml``: the checks of the controller the run drives, every one passed."""
    from hil.cli.main import main

    monkeypatch.delenv("HIL_STAGE_URL", raising=False)
    assert main(["tank-run", "--print-default"]) == 0
    experiment = tmp_path / "exp.toml"
    experiment.write_text(capsys.readouterr().out)
    assert main(["stage", "settings", "--check", str(experiment)]) == 0
    out = capsys.readouterr().out
    checks = [line for line in out.splitlines() if line.split(" ", 1)[0] in ("ok", "FAIL")]
    tow = [line for line in checks if " tow." in line]
    assert len(tow) == 5 and all(line.startswith("ok ") for line in checks)
    assert "ok      tow.speed_mps = 1.5: must be <= the stage max rate 2.500 m/s ($110)" in tow
    assert "soft limits of X: [-10, 0] m" in out


def test_the_default_simulated_stage_powers_up_idle_and_refuses_homing_as_its_help_says(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from hil.cli import stage
    from hil.cli.main import main

    monkeypatch.delenv("HIL_STAGE_URL", raising=False)
    # `hil stage --help` prints the module's docstring.
    assert "it powers up Idle, moves at once, and ``home`` is refused" in " ".join(
        (stage.__doc__ or "").split()
    )
    assert main(["stage", "status"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == "state      Idle"
    assert main(["stage", "home"]) == 2
    assert (
        capsys.readouterr()
        .err.splitlines()[-1]
        .startswith("hil stage: error: homing_enabled ($22) = False is not allowed: must be True")
    )
