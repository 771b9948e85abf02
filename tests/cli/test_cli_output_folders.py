"""Output folders are never overwritten: ``hil simulate`` refuses a used folder as ``hil
tank-run`` does, a folder is claimed atomically (of two commands started at once into it, one
is refused before it does anything), and ``hil report`` writes beside a live summary."""

from __future__ import annotations

import json
import multiprocessing
from pathlib import Path

import pytest

from hil.cli.main import main
from hil.errors import ConfigError
from hil.outputs import CLAIM, claim_output_folder


def test_simulate_refuses_a_folder_holding_another_simulation(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "sim"
    assert main(["simulate", "att", "--duration", "0.2", "--out", str(out), "--quiet"]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    capsys.readouterr()
    assert main(["simulate", "att", "--duration", "0.1", "--out", str(out), "--quiet"]) == 2
    assert capsys.readouterr().err == (
        f"hil simulate: error: --out = '{out}' is not allowed: must be a new or empty folder;"
        " it holds a simulation already, which is never overwritten; choose another folder\n"
    )
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_a_folder_claimed_by_another_process_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / CLAIM).write_text("999999999\n")  # a PID that is not this process
    with pytest.raises(ConfigError, match="it holds a run already, which is never overwritten"):
        claim_output_folder(out, "--out", holds="a run")


def _claim(out: str, barrier: multiprocessing.synchronize.Barrier, results: object) -> None:
    barrier.wait()
    try:
        claim_output_folder(Path(out), "--out")
        results.put("claimed")  # type: ignore[attr-defined]
    except ConfigError:
        results.put("refused")  # type: ignore[attr-defined]


def test_of_two_processes_claiming_one_folder_at_once_exactly_one_wins(tmp_path: Path) -> None:
    ctx = multiprocessing.get_context("fork")
    for k in range(5):  # several rounds: the race goes either way
        out = tmp_path / f"out-{k}"
        barrier, results = ctx.Barrier(2), ctx.Queue()
        procs = [ctx.Process(target=_claim, args=(str(out), barrier, results)) for _ in range(2)]
        for p in procs:
            p.start()
        for p in procs:
            p.join(60)
        assert sorted(results.get(timeout=10) for _ in procs) == ["claimed", "refused"]


@pytest.mark.slow
def test_report_without_out_writes_beside_the_live_summary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from hil.experiments import api
    from hil.experiments.experiment import DEFAULT_EXPERIMENT

    short = DEFAULT_EXPERIMENT.replace("end_m = -5.0", "end_m = -2.9")
    folder = tmp_path / "run"
    api.run(short, folder=folder, figures=False, virtual_time=True)
    live = (folder / "summary.json").read_bytes()
    capsys.readouterr()
    assert main(["report", str(folder / "run.h5"), "--no-map", "--json"]) == 0
    out = capsys.readouterr().out
    rebuilt = json.loads(out.splitlines()[0])
    # The live summary (wall time, backlog, the telemetry truth error) is kept as it was.
    assert (folder / "summary.json").read_bytes() == live
    assert json.loads((folder / "rebuilt" / "summary.json").read_text()) == rebuilt
    assert rebuilt["estimates"] == json.loads(live)["estimates"]
    assert (folder / "rebuilt" / "estimates.csv").exists()


def test_simulate_without_out_writes_a_new_timestamped_folder_in_the_runs_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The rule tank-run follows: a command whose every run is new defaults --out to a new
    folder in $HIL_RUNS_DIR; two in the same second get -2."""
    import datetime as dt

    from hil.cli import simulate

    monkeypatch.setenv("HIL_RUNS_DIR", str(tmp_path / "runs"))
    now = dt.datetime(2026, 11, 28, 21, 5, 9)
    first = simulate.new_simulation_folder("my tank.toml", now)
    assert first == tmp_path / "runs" / "simulate-my_tank-20261128-210509"
    assert simulate.new_simulation_folder("my tank.toml", now) == first.with_name(first.name + "-2")
    assert main(["simulate", "att", "--duration", "0.1", "--quiet"]) == 0
    made = json.loads(capsys.readouterr().out)["out"]
    assert Path(made).parent == tmp_path / "runs" and Path(made).name.startswith("simulate-att-")
    assert (Path(made) / "received.wav").is_file()


def test_simulate_progress_in_a_log_is_lines_without_carriage_returns(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """stderr not a terminal (a log file, a pipe): one line per 10 % step, no ``\\r``."""
    assert main(["simulate", "att", "--duration", "0.2", "--out", str(tmp_path / "s")]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = err.splitlines()
    steps = [int(line.removeprefix("simulate:").removesuffix("%")) for line in lines]
    assert lines == [f"simulate: {p:3d} %" for p in steps]  # whole lines, no redraw
    assert steps[-1] == 100 and steps == sorted(set(steps)) and all(p % 10 == 0 for p in steps)
