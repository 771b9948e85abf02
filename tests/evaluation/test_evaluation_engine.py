"""The sweep engine on every runner: same numbers everywhere, failures recorded, resume,
refusals, BLAS pinning in workers. One process pool and one local Dask cluster (2 workers
each) serve the whole module."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.evaluation.engine import SweepOutcome, run_sweep
from hil.evaluation.runners import DaskRunner, LocalPoolRunner, Runner, SerialRunner
from hil.evaluation.seeds import seed_from_record
from hil.evaluation.spec import SweepSpec
from hil.evaluation.store import SweepStore
from hil.evaluation.sweep_file import sweep_from_dict
from hil.evaluation.trials_waveform import waveform_af_sidelobe

HELPERS = Path(__file__).with_name("evaluation_trials_for_tests.py")


def helper(function: str) -> str:
    return f"{HELPERS}:{function}"


def af_sweep(seed: int = 20240601) -> SweepSpec:
    """8 real trials (periodic AF of random cyclic codes), a few ms each."""
    return sweep_from_dict(
        {
            "sweep": {
                "name": "af",
                "trial": "waveform_af_sidelobe",
                "trials_per_point": 2,
                "seed": seed,
            },
            "grid": {"code_length": [17, 19], "n_tones": [4, 5]},
            "fixed": {"doppler_bins": 1, "candidates": 2},
        }
    )


def results_by_id(outcome: SweepOutcome) -> dict[int, Any]:
    return {r["trial_id"]: r["result"] for r in outcome.records}


@pytest.fixture(scope="module")
def pool() -> Iterator[LocalPoolRunner]:
    with LocalPoolRunner(workers=2) as runner:
        yield runner


@pytest.fixture(scope="module")
def dask_runner() -> Iterator[DaskRunner]:
    with DaskRunner(n_workers=2) as runner:
        yield runner


def test_same_seed_gives_identical_numbers_twice(tmp_path: Path) -> None:
    first = run_sweep(af_sweep(), tmp_path / "a", SerialRunner(), show_progress=False)
    again = run_sweep(af_sweep(), tmp_path / "b", SerialRunner(), show_progress=False)
    other = run_sweep(af_sweep(seed=7), tmp_path / "c", SerialRunner(), show_progress=False)
    assert first.n_ok == 8 and first.complete
    assert results_by_id(first) == results_by_id(again)
    assert (tmp_path / "a" / "summary.csv").read_text() == (
        tmp_path / "b" / "summary.csv"
    ).read_text()
    assert [r["result"]["code_seed"] for r in first.records] != [
        r["result"]["code_seed"] for r in other.records
    ]


def test_pool_serial_and_dask_give_the_same_numbers(
    tmp_path: Path, pool: LocalPoolRunner, dask_runner: DaskRunner
) -> None:
    serial = run_sweep(af_sweep(), tmp_path / "serial", SerialRunner(), show_progress=False)
    pooled = run_sweep(af_sweep(), tmp_path / "pool", pool, show_progress=False)
    dasked = run_sweep(af_sweep(), tmp_path / "dask", dask_runner, show_progress=False)
    assert results_by_id(serial) == results_by_id(pooled) == results_by_id(dasked)
    assert serial.rows == pooled.rows == dasked.rows
    # The work really was spread over two worker processes, neither of them this one.
    for outcome in (pooled, dasked):
        workers = {r["worker"] for r in outcome.records}
        assert len(workers) == 2
        assert not any(w.endswith(f":{os.getpid()}") for w in workers)


def test_record_replays_from_its_seed(tmp_path: Path) -> None:
    outcome = run_sweep(af_sweep(), tmp_path, SerialRunner(), show_progress=False)
    rec = outcome.records[5]
    replay = waveform_af_sidelobe(rec["params"], seed_from_record(rec["seed"]))
    assert replay == rec["result"]
    assert rec["seed"] == {"entropy": 20240601, "spawn_key": [2, 1]}
    assert rec["params"] == {"doppler_bins": 1, "candidates": 2, "code_length": 19, "n_tones": 4}


@pytest.mark.parametrize("runner_name", ["serial", "pool", "dask"])
def test_failing_trial_is_recorded_and_sweep_finishes(
    tmp_path: Path, runner_name: str, request: pytest.FixtureRequest
) -> None:
    runner: Runner = (
        SerialRunner()
        if runner_name == "serial"
        else request.getfixturevalue("pool" if runner_name == "pool" else "dask_runner")
    )
    spec = sweep_from_dict(
        {
            "sweep": {
                "name": "f",
                "trial": helper("raising_trial"),
                "trials_per_point": 2,
                "seed": 3,
            },
            "grid": {"x": [1, 2, 3]},
        }
    )
    outcome = run_sweep(spec, tmp_path, runner, show_progress=False)
    assert outcome.complete and outcome.n_ok == 4 and outcome.n_failed == 2
    failed = [r for r in outcome.records if r["status"] == "error"]
    assert [r["trial_id"] for r in failed] == [2, 3]
    for rec in failed:
        assert rec["params"] == {"x": 2}
        assert rec["seed"] == {"entropy": 3, "spawn_key": [1, rec["rep"]]}
        assert rec["error"]["type"] == "ValueError"
        assert rec["error"]["message"] == "x = 2 is cursed"
        assert "raise ValueError" in rec["error"]["traceback"]
        assert "Traceback (most recent call last)" in rec["error"]["traceback"]
    assert [(row["x"], row["n_ok"], row["n_failed"]) for row in outcome.rows] == [
        (1, 2, 0),
        (2, 0, 2),
        (3, 2, 0),
    ]
    assert outcome.rows[1]["x_count"] == 0 and outcome.rows[1]["x_mean"] is None
    # The failures are on disk as well, one line each.
    lines = (tmp_path / "results.jsonl").read_text().splitlines()
    assert sum(json.loads(line)["status"] == "error" for line in lines) == 2


def test_trial_returning_a_non_dict_is_a_recorded_failure(tmp_path: Path) -> None:
    spec = sweep_from_dict({"sweep": {"name": "b", "trial": helper("bad_return_trial"), "seed": 0}})
    outcome = run_sweep(spec, tmp_path, SerialRunner(), show_progress=False)
    (rec,) = outcome.records
    assert rec["error"]["type"] == "TypeError"
    assert rec["error"]["message"] == "a trial must return a dict of results, got list"


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["pool", "dask"])
def test_workers_start_with_blas_pinned_to_one_thread(
    tmp_path: Path, kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The parent asks for 4 BLAS threads; its workers must still start with 1.
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.setenv(name, "4")
    spec = sweep_from_dict(
        {"sweep": {"name": "e", "trial": helper("env_trial"), "trials_per_point": 6, "seed": 0}}
    )
    runner = LocalPoolRunner(workers=2) if kind == "pool" else DaskRunner(n_workers=2)
    with runner:
        outcome = run_sweep(spec, tmp_path, runner, show_progress=False)
        assert runner.notes == []
        if isinstance(runner, DaskRunner):  # no statistical profiler in the local workers
            profiling = runner.client.run(
                lambda: __import__("dask").config.get("distributed.worker.profile.enabled")
            )
            assert set(profiling.values()) == {False}
    started = {
        (r["result"]["omp"], r["result"]["openblas"], r["result"]["mkl"]) for r in outcome.records
    }
    assert started == {("1", "1", "1")}
    # Dask's default MALLOC_TRIM_THRESHOLD_ (fixed mmap threshold, numpy trials 1.5x CPU) is not
    # given to the local workers, as the pool's never have it.
    assert {r["result"]["malloc_trim"] for r in outcome.records} == {"None"}
    assert len({r["result"]["pid"] for r in outcome.records}) == 2
    assert os.environ["OMP_NUM_THREADS"] == "4"  # the parent's own setting is back


def test_dask_runner_connects_to_a_scheduler_address(
    tmp_path: Path, dask_runner: DaskRunner
) -> None:
    address = dask_runner.client.scheduler.address
    with DaskRunner(scheduler=address) as remote:
        assert remote.workers == 2
        outcome = run_sweep(af_sweep(), tmp_path / "remote", remote, show_progress=False)
        assert remote.notes == []
    local = run_sweep(af_sweep(), tmp_path / "serial", SerialRunner(), show_progress=False)
    assert results_by_id(outcome) == results_by_id(local)


def test_resume_runs_only_the_missing_trials(tmp_path: Path) -> None:
    marker = tmp_path / "markers.txt"
    doc = {
        "sweep": {"name": "m", "trial": helper("marker_trial"), "trials_per_point": 3, "seed": 9},
        "grid": {"k": [0, 1]},
        "fixed": {"marker": str(marker)},
    }
    spec = sweep_from_dict(doc)
    out = tmp_path / "out"
    full = run_sweep(spec, out, SerialRunner(), show_progress=False)
    # Keep the first two records and half of the third line, as a kill while writing would.
    lines = (out / "results.jsonl").read_text().splitlines(keepends=True)
    (out / "results.jsonl").write_text("".join(lines[:2]) + lines[2][:25])
    marker.write_text("")
    resumed = run_sweep(spec, out, SerialRunner(), resume=True, show_progress=False)
    assert (resumed.ran, resumed.skipped) == (4, 2)
    assert sorted(marker.read_text().split()) == ["0,2", "1,0", "1,1", "1,2"]
    assert results_by_id(resumed) == results_by_id(full)
    assert len((out / "results.jsonl").read_text().splitlines()) == 6
    manifest = json.loads((out / "manifest.json").read_text())
    assert len(manifest["runs"]) == 2
    # Resuming a finished sweep runs nothing.
    again = run_sweep(spec, out, SerialRunner(), resume=True, show_progress=False)
    assert (again.ran, again.skipped) == (0, 6)
    assert len(marker.read_text().split()) == 4


def test_existing_sweep_folder_is_refused_without_resume(tmp_path: Path) -> None:
    run_sweep(af_sweep(), tmp_path, SerialRunner(), show_progress=False)
    with pytest.raises(ConfigError) as err:
        run_sweep(af_sweep(), tmp_path, SerialRunner(), show_progress=False)
    assert str(err.value) == (
        f"--out = '{tmp_path}' is not allowed: must be a folder without a sweep in it; "
        "pass --resume to continue that sweep, or choose another --out folder"
    )


@pytest.mark.parametrize(
    ("change", "difference"),
    [
        (
            lambda d: d["sweep"].update(seed=5),
            "seed differs: folder has 20240601, sweep file has 5",
        ),
        (
            lambda d: d["grid"].update(code_length=[17, 23]),
            "grid.code_length differs: folder has [17, 19], sweep file has [17, 23]",
        ),
        (
            lambda d: d.update(grid={"n_tones": [4, 5], "code_length": [17, 19]}),
            "grid order differs: folder has ['code_length', 'n_tones'], "
            "sweep file has ['n_tones', 'code_length']",
        ),
    ],
)
def test_resume_refuses_a_different_sweep(tmp_path: Path, change: Any, difference: str) -> None:
    doc = {
        "sweep": {
            "name": "af",
            "trial": "waveform_af_sidelobe",
            "trials_per_point": 1,
            "seed": 20240601,
        },
        "grid": {"code_length": [17, 19], "n_tones": [4, 5]},
        "fixed": {"doppler_bins": 1},
    }
    run_sweep(sweep_from_dict(doc), tmp_path, SerialRunner(), show_progress=False)
    change(doc)
    before = (tmp_path / "results.jsonl").read_bytes()
    with pytest.raises(ConfigError) as err:
        run_sweep(sweep_from_dict(doc), tmp_path, SerialRunner(), resume=True, show_progress=False)
    assert str(err.value) == (
        f"--resume = '{tmp_path}' is not allowed: must be a folder holding this same sweep "
        f"({difference}); resume with the sweep file that started it, or pass a new --out folder"
    )
    assert (tmp_path / "results.jsonl").read_bytes() == before


def test_damaged_results_line_is_refused(tmp_path: Path) -> None:
    run_sweep(af_sweep(), tmp_path, SerialRunner(), show_progress=False)
    path = tmp_path / "results.jsonl"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text(lines[0] + "{not json\n" + "".join(lines[1:]))
    with pytest.raises(ConfigError) as err:
        SweepStore(tmp_path).read_records()
    assert str(err.value).startswith(f"{path}:2 = '{{not json\\n' is not allowed: must be one JSON")
    assert "move it away to start over" in str(err.value)


def test_summary_statistics_match_numpy(tmp_path: Path) -> None:
    spec = sweep_from_dict(
        {
            "sweep": {
                "name": "s",
                "trial": helper("draw_trial"),
                "trials_per_point": 25,
                "seed": 1,
            },
            "grid": {"sigma": [0.5, 2.0]},
        }
    )
    outcome = run_sweep(spec, tmp_path, SerialRunner(), show_progress=False)
    for row in outcome.rows:
        err = np.array([r["result"]["err"] for r in outcome.records if r["point"] == row["point"]])
        assert row["err_count"] == 25 and row["n_ok"] == 25
        assert row["err_mean"] == pytest.approx(err.mean(), rel=1e-12)
        assert row["err_rmse"] == pytest.approx(math.sqrt(np.mean(err**2)), rel=1e-12)
        assert row["err_std"] == pytest.approx(err.std(ddof=1), rel=1e-12)
    assert "label_mean" not in outcome.rows[0]  # text fields are not summarised
    # RMSE grows with sigma; the CSV holds the same numbers.
    assert outcome.rows[1]["err_rmse"] > 2 * outcome.rows[0]["err_rmse"]
    header, first, _ = (tmp_path / "summary.csv").read_text().splitlines()
    assert header == (
        "point,sigma,n_trials,n_done,n_ok,n_failed,err_mean,err_rmse,err_std,err_count"
    )
    assert float(first.split(",")[7]) == outcome.rows[0]["err_rmse"]


def test_infinite_grid_value_round_trips_through_resume(tmp_path: Path) -> None:
    # SRR = inf ("no reverberation") is a natural grid value: JSON writes it as Infinity.
    doc = {
        "sweep": {"name": "inf", "trial": helper("draw_trial"), "trials_per_point": 2, "seed": 6},
        "grid": {"srr_db": [math.inf, 0.0]},
    }
    first = run_sweep(sweep_from_dict(doc), tmp_path, SerialRunner(), show_progress=False)
    again = run_sweep(
        sweep_from_dict(doc), tmp_path, SerialRunner(), resume=True, show_progress=False
    )
    assert (again.ran, again.skipped) == (0, 4)
    assert [row["srr_db"] for row in again.rows] == [math.inf, 0.0]
    assert results_by_id(again) == results_by_id(first)
    assert (tmp_path / "summary.csv").read_text().splitlines()[1].startswith("0,inf,2,2,2,0,")


def test_resume_refuses_results_of_another_grid(tmp_path: Path) -> None:
    run_sweep(af_sweep(), tmp_path, SerialRunner(), show_progress=False)
    manifest_before = (tmp_path / "manifest.json").read_text()
    with (tmp_path / "results.jsonl").open("a") as fh:
        fh.write(json.dumps({"trial_id": 99, "point": 49, "status": "ok", "result": {}}) + "\n")
    with pytest.raises(ConfigError) as err:
        run_sweep(af_sweep(), tmp_path, SerialRunner(), resume=True, show_progress=False)
    assert str(err.value) == (
        f"{tmp_path / 'results.jsonl'} = 99 is not allowed: must be trial ids in 0..7 (this "
        "sweep's grid); the results belong to another sweep: use a new --out folder"
    )
    assert (tmp_path / "manifest.json").read_text() == manifest_before  # no run added


@pytest.mark.slow
def test_resume_refuses_results_without_manifest(tmp_path: Path) -> None:
    run_sweep(af_sweep(), tmp_path, SerialRunner(), show_progress=False)
    (tmp_path / "manifest.json").unlink()
    with pytest.raises(ConfigError) as err:
        run_sweep(af_sweep(), tmp_path, SerialRunner(), resume=True, show_progress=False)
    assert str(err.value) == (
        f"--out = '{tmp_path}' is not allowed: must be a sweep folder with manifest.json; "
        "results without a manifest cannot be resumed; use a new --out folder"
    )
