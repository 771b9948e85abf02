"""The short built-in run on virtual time shared across modules: one ``hil tank-run`` in this
process, for the tests that check what the command leaves behind (its summary, folder,
figures, run.log, recording) and, through the outcome of its run, for those that check the
run itself. One run serves every test that reads it, since none changes what it left (a test
that edits a recording edits a copy)."""

from __future__ import annotations

import contextlib
import io
import json
import select
import signal
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from hil.cli.main import main
from hil.experiments.experiment import DEFAULT_EXPERIMENT
from hil.experiments.tank_run import RunOutcome

#: The built-in run, its pass shortened to 2.1 m (from -1.4 to -3.5 m) to keep the suite quick.
SHORT_CLI_EXPERIMENT = DEFAULT_EXPERIMENT.replace("end_m = -5.0", "end_m = -3.5")


def near_home(text: str) -> str:
    """``text``'s short pass (from -2.0 to -3.5 m) moved 1.3 m nearer home: from -0.7 m (its
    run-up from -0.1 m) to -2.2 m, the same 1.5 m of tow at the same speed, the target 9.8 to
    8.3 m from the transducer instead of 8.5 to 7.0 m. For the runs in real time whose tow
    is not what they check: such a run streams as soon as it starts instead of after the
    carriage is positioned 1.4 m out (about 3.5 s of wall time at time_scale 0.4, and more
    where the tank is slowed for a loaded machine)."""
    for old, new in (("start_m = -2.0", "start_m = -0.7"), ("end_m = -3.5", "end_m = -2.2")):
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return text


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


def cli_run_keeping_the_outcome(
    exp_file: Path, folder: Path, *options: str
) -> tuple[int, dict[str, Any], RunOutcome]:
    """``hil [OPTIONS] tank-run EXP_FILE --out FOLDER --no-live --json --virtual-time`` in this
    process: its exit status, the JSON summary it printed, and the outcome of its run. The
    command calls :func:`~hil.experiments.tank_run.run_experiment` (kept here as it returns)
    with no live view, as an in-process run of the same text does, then writes the summary,
    figures and run.log of the command."""
    import hil.experiments.tank_run as tank_run

    argv = [*options, "tank-run", str(exp_file), "--out", str(folder), "--no-live", "--json",
            "--virtual-time"]  # fmt: skip
    outcomes: list[RunOutcome] = []
    original = tank_run.run_experiment

    def keep(*args: Any, **kwargs: Any) -> RunOutcome:
        outcomes.append(original(*args, **kwargs))
        return outcomes[-1]

    printed = io.StringIO()
    with pytest.MonkeyPatch.context() as patch, contextlib.redirect_stdout(printed):
        patch.setattr(tank_run, "run_experiment", keep)
        status = main(argv)
    summary = json.loads(printed.getvalue().strip().splitlines()[-1])
    (outcome,) = outcomes
    assert outcome.folder == folder
    return status, summary, outcome


@pytest.fixture(scope="session")
def _short_virtual_cli_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[CliRun, RunOutcome]:
    """The short built-in pass run once through the command line on virtual time, and the
    outcome of its run (:func:`cli_run_keeping_the_outcome`)."""
    base = tmp_path_factory.mktemp("cli-virtual-run")
    exp_file = base / "short.toml"
    exp_file.write_text(SHORT_CLI_EXPERIMENT)
    folder, log_file = base / "run", base / "hil.log"
    status, summary, outcome = cli_run_keeping_the_outcome(
        exp_file, folder, "--log-level", "warning", "--log-file", str(log_file)
    )
    scratch = base / "scratch"
    scratch.mkdir()
    return CliRun(status, summary, folder, log_file, scratch, "sim-towed-pass"), outcome


#: The short pass on the simulated audio interface, its board line as docs/tank-run.md
#: writes it.
SHORT_AUDIO_EXPERIMENT = SHORT_CLI_EXPERIMENT.replace(
    'board = "sim://board"', 'board = "sim://audio?blocksize=256"'
)


@pytest.fixture(scope="session")
def audio_virtual_cli_run(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[int, dict[str, Any], RunOutcome]:
    """:data:`SHORT_AUDIO_EXPERIMENT` run once through the command line on virtual time (no
    log options): its exit status, printed summary and run's outcome (folder ``.../run``),
    for test_tank_run_audio's command and the every-device suite's audio-interface run."""
    base = tmp_path_factory.mktemp("audio-virtual-run")
    exp_file = base / "audio.toml"
    exp_file.write_text(SHORT_AUDIO_EXPERIMENT)
    return cli_run_keeping_the_outcome(exp_file, base / "run")


@pytest.fixture(scope="session")
def cli_virtual_run(_short_virtual_cli_run: tuple[CliRun, RunOutcome]) -> CliRun:
    """The short built-in pass run once through the command line on virtual time."""
    return _short_virtual_cli_run[0]


@pytest.fixture(scope="session")
def short_virtual_outcome(_short_virtual_cli_run: tuple[CliRun, RunOutcome]) -> RunOutcome:
    """The short built-in pass (:data:`SHORT_CLI_EXPERIMENT`, the Python simulated board) on
    virtual time with no live view: the outcome of :func:`cli_virtual_run`'s run, the same
    run for every test that only reads it (test_tank_run_virtual's ``first_run``, the
    every-device suite's python-board run), whose digests test_tank_run_virtual pins bit for
    bit. Its folder also holds what the command wrote (summary, figures, run.log)."""
    return _short_virtual_cli_run[1]


#: Deadlock guard (never asserted on): the served tank prints its file within seconds.
SERVE_TIMEOUT_S = 300.0


@contextlib.contextmanager
def serve_jack_tank(
    command: list[str], env: dict[str, str]
) -> Iterator[tuple[Path, subprocess.Popen[str]]]:
    """Run ``command`` (``hil sim-serve tank --jack --experiment FILE``) as its own process
    with ``env``: the experiment file it printed, and the process; stopped with SIGTERM at the
    end (killed if it has not ended 60 s later)."""
    proc = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], SERVE_TIMEOUT_S)
        line = proc.stdout.readline().strip() if ready else ""
        if not line:
            proc.kill()
            pytest.fail(f"sim-serve tank printed no file: {proc.communicate()[1][-3000:]}")
        yield Path(line), proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
