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

    serve_board, serve_stage, print_default, tank_run = _recipe_commands(DESCRIPTION)
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
        # "put the printed paths in it"
        path = tmp_path / redirect
        text = path.read_text()
        text = re.sub(r'(?m)^board = ".*"$', f'board = "{board}"', text, count=1)
        text = re.sub(r'(?m)^stage = ".*"$', f'stage = "{stage}"', text, count=1)
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
