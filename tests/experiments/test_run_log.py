"""Every tank run writes a complete run.log into its folder; --log-file and --log-level
apply to the whole command."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hil.cli.main import main
from hil.experiments.experiment import DEFAULT_EXPERIMENT

SHORT = DEFAULT_EXPERIMENT.replace("end_m = -5.0", "end_m = -3.5")


@pytest.mark.slow
def test_tank_run_writes_run_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    exp_file = tmp_path / "short.toml"
    exp_file.write_text(SHORT)
    folder, log_file = tmp_path / "run", tmp_path / "hil.log"
    # On virtual time: what is logged is the same as on ptys, in a few seconds.
    argv = ["--log-level", "warning", "--log-file", str(log_file),
            "tank-run", str(exp_file), "--out", str(folder), "--no-live", "--json",
            "--virtual-time"]  # fmt: skip
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    run_log = (folder / "run.log").read_text()
    lines = run_log.splitlines()
    assert f"INFO    hil.cli.tank_run: tank run 'sim-towed-pass' into {folder}" in lines[0]
    assert f"hil.recording.writer: recording {folder / 'run.h5'}: 192000 Hz" in run_log
    assert f"hil.run: summary scored_estimates = {summary['scored_estimates']}" in run_log
    assert lines[-1].endswith(f"hil.run: run folder: {folder}")
    # --log-level warning: the command's own log holds no INFO line of the run.
    assert " INFO " not in (log_file.read_text() if log_file.exists() else "")
