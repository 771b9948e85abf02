"""Progress output (terminal and log forms, on an injected clock) and the ``hil sweep``
command end to end."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import pytest

from hil.cli.main import main
from hil.evaluation.progress import Progress
from hil.evaluation.sweep_file import shipped_sweeps

HELPERS = Path(__file__).with_name("evaluation_trials_for_tests.py")


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_terminal_progress_redraws_one_line() -> None:
    out, clock = io.StringIO(), Clock()
    p = Progress(4, label="s", stream=out, tty=True, width=4, clock=clock)
    clock.t += 1.0
    p.update(ok=True)
    clock.t += 1.0
    p.update(ok=False)
    p.close()
    assert out.getvalue() == (
        "\rs [#---]   1/4   25.0%  1.00 trials/s  ETA 0:00:03"
        "\rs [##--]   2/4   50.0%  1.00 trials/s  ETA 0:00:02  1 failed"
        "\n"
    )


def test_log_progress_prints_periodic_lines_and_a_last_one() -> None:
    out, clock = io.StringIO(), Clock()
    p = Progress(
        10, already_done=2, label="s", stream=out, tty=False, interval_s=5, width=10, clock=clock
    )
    for _ in range(6):
        clock.t += 2.0
        p.update(ok=True)
    p.close()
    # Lines at t = 6 s (3 done this run) and t = 12 s, then the closing line adds nothing new.
    assert out.getvalue().splitlines() == [
        "s [#####-----]    5/10   50.0%  0.50 trials/s  ETA 0:00:10",
        "s [########--]    8/10   80.0%  0.50 trials/s  ETA 0:00:04",
    ]


def test_log_progress_close_shows_the_final_count() -> None:
    out, clock = io.StringIO(), Clock()
    p = Progress(3, label="s", stream=out, tty=False, interval_s=60, width=3, clock=clock)
    clock.t += 3.0
    for _ in range(3):
        p.update(ok=True)
    p.close()
    assert out.getvalue() == "s [###]   3/3  100.0%  1.00 trials/s  ETA 0:00:00\n"


def _sweep_file(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "sweep.toml"
    path.write_text(body)
    return path


def test_cli_runs_a_sweep_and_prints_a_summary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sweep = _sweep_file(
        tmp_path,
        f"""
[sweep]
name = "cursed"
trial = "{HELPERS}:raising_trial"
trials_per_point = 2
seed = 8

[grid]
x = [1, 2]
""",
    )
    out = tmp_path / "out"
    assert main(["sweep", str(sweep), "--out", str(out), "--serial"]) == 1  # a trial failed
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert (
        lines[0]
        == "sweep cursed: trial " + f"{HELPERS}:raising_trial, 2 point(s) x 2 = 4 trials, seed 8"
    )
    assert lines[1].startswith("ran 4 (0 already done) in ")
    assert lines[1].split(" s on ")[1].startswith("serial (1 worker): ")
    assert lines[1].endswith(" trials/s; 2 ok, 2 failed")
    assert lines[2].split() == [
        "point",
        "x",
        "n_ok",
        "n_failed",
        "x_mean",
        "x_rmse",
        "u_mean",
        "u_rmse",
    ]
    assert lines[3].split()[:6] == ["0", "1", "2", "0", "1", "1"]
    assert lines[4].split() == ["1", "2", "0", "2", "-", "-", "-", "-"]
    assert lines[5] == (
        "first failure: trial 2 (point 1, rep 0): ValueError: x = 2 is cursed "
        f"(details in {out / 'results.jsonl'})"
    )
    assert (
        lines[6] == f"wrote {out / 'manifest.json'}, {out / 'results.jsonl'}, {out / 'summary.csv'}"
    )
    assert "cursed [" in captured.err  # the progress line

    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["format"] == "hil-sweep/1"
    assert manifest["definition"]["seed"] == 8
    assert manifest["definition"]["grid"] == {"x": [1, 2]}
    assert manifest["points"] == [{"x": 1}, {"x": 2}]
    assert manifest["n_trials"] == 4
    assert set(manifest["versions"]) == {"cas-hil", "python", "numpy", "scipy"}
    assert manifest["runs"][0]["runner"] == {"runner": "serial", "workers": 1}
    with (out / "summary.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["x"], r["n_ok"], r["n_failed"], r["x_mean"]) for r in rows] == [
        ("1", "2", "0", "1.0"),
        ("2", "0", "2", ""),
    ]


def test_cli_json_output_and_resume(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sweep = _sweep_file(
        tmp_path,
        f"""
[sweep]
name = "d"
trial = "{HELPERS}:draw_trial"
trials_per_point = 3
seed = 2

[fixed]
sigma = 0.5
""",
    )
    out = tmp_path / "out"
    assert main(["sweep", str(sweep), "--out", str(out), "--serial", "--quiet", "--json"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert [(r["point"], r["n_ok"], r["err_count"]) for r in first] == [(0, 3, 3)]
    assert main(["sweep", str(sweep), "--out", str(out), "--serial", "--quiet"]) == 2
    assert capsys.readouterr().err.startswith("hil sweep: error: --out = ")
    assert main(["sweep", str(sweep), "--out", str(out), "--resume", "--quiet", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == first


def test_cli_refuses_two_ways_to_run(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["sweep", "x.toml", "--out", "o", "--workers", "2", "--dask-workers", "2"])
    assert exit_info.value.code == 2
    assert "argument --dask-workers: not allowed with argument --workers" in capsys.readouterr().err


def test_cli_missing_sweep_file_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nope.toml"
    assert main(["sweep", str(missing), "--out", str(tmp_path / "o")]) == 2
    shipped = ", ".join(shipped_sweeps())
    assert capsys.readouterr().err == (
        f"hil sweep: error: SWEEP = '{missing}' is not allowed: must be a sweep file, or a "
        f"shipped sweep: one of {shipped}; {missing} is not a file\n"
    )
