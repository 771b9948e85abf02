"""A ``hil tank-run`` of a short pass on virtual time, shared by the tests that check what the
command leaves behind (its summary, folder, figures, run.log, recording): one run of the
command serves them all, since each reads its outputs and none changes them."""

from __future__ import annotations

import contextlib
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from hil.cli.main import main
from hil.experiments.experiment import DEFAULT_EXPERIMENT

#: The built-in run, its pass shortened to 2.1 m (from -1.4 to -3.5 m) to keep the suite quick.
SHORT_CLI_EXPERIMENT = DEFAULT_EXPERIMENT.replace("end_m = -5.0", "end_m = -3.5")


@dataclass(frozen=True)
class CliRun:
    """A finished ``hil --log-level warning --log-file LOG tank-run FILE --out FOLDER
    --no-live --json --virtual-time``: its exit status, the JSON summary it printed, its
    run folder, its own log file and a scratch folder beside them for further outputs."""

    status: int
    summary: dict[str, Any]
    folder: Path
    log_file: Path
    scratch: Path
    experiment_name: str


@pytest.fixture(scope="session")
def cli_virtual_run(tmp_path_factory: pytest.TempPathFactory) -> CliRun:
    """The short built-in pass run once through the command line on virtual time."""
    base = tmp_path_factory.mktemp("cli-virtual-run")
    exp_file = base / "short.toml"
    exp_file.write_text(SHORT_CLI_EXPERIMENT)
    folder, log_file = base / "run", base / "hil.log"
    argv = ["--log-level", "warning", "--log-file", str(log_file),
            "tank-run", str(exp_file), "--out", str(folder), "--no-live", "--json",
            "--virtual-time"]  # fmt: skip
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        status = main(argv)
    summary = json.loads(printed.getvalue().strip().splitlines()[-1])
    scratch = base / "scratch"
    scratch.mkdir()
    return CliRun(status, summary, folder, log_file, scratch, "sim-towed-pass")
