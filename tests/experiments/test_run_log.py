"""Every tank run writes a complete run.log into its folder; --log-file and --log-level
apply to the whole command."""

from __future__ import annotations

import pytest

from tests.experiments.conftest import CliRun


@pytest.mark.slow
def test_tank_run_writes_run_log(cli_virtual_run: CliRun) -> None:
    # On virtual time: what is logged is the same as on ptys, in a few seconds. The run is
    # ``hil --log-level warning --log-file LOG tank-run ... --virtual-time`` (the conftest).
    run = cli_virtual_run
    assert run.status == 0
    folder, summary = run.folder, run.summary
    run_log = (folder / "run.log").read_text()
    lines = run_log.splitlines()
    assert f"INFO    hil.cli.tank_run: tank run '{run.experiment_name}' into {folder}" in lines[0]
    assert f"hil.recording.writer: recording {folder / 'run.h5'}: 192000 Hz" in run_log
    assert f"hil.run: summary scored_estimates = {summary['scored_estimates']}" in run_log
    assert lines[-1].endswith(f"hil.run: run folder: {folder}")
    # --log-level warning: the command's own log holds no INFO line of the run.
    log_file = run.log_file
    assert " INFO " not in (log_file.read_text() if log_file.exists() else "")
