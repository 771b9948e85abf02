"""Trial registry, per-trial seeds, result normalisation and runner options."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.evaluation.engine import run_sweep
from hil.evaluation.registry import (
    TRIALS,
    load_trial,
    register_trial,
    resolve_trial,
    unregister_trial,
)
from hil.evaluation.runners import DaskRunner, LocalPoolRunner, SerialRunner, make_runner
from hil.evaluation.seeds import check_entropy, trial_seed
from hil.evaluation.sweep_file import sweep_from_dict
from hil.evaluation.worker import TrialTask, execute_trial, normalise_result

HELPERS = Path(__file__).with_name("evaluation_trials_for_tests.py")


# -- seeds -------------------------------------------------------------------------------


@given(
    entropy=st.integers(0, 2**80),
    point=st.integers(0, 50),
    rep=st.integers(0, 50),
)
def test_trial_seed_is_the_spawn_tree_child(entropy: int, point: int, rep: int) -> None:
    tree = np.random.SeedSequence(entropy).spawn(point + 1)[point].spawn(rep + 1)[rep]
    assert trial_seed(entropy, point, rep).generate_state(4).tolist() == (
        tree.generate_state(4).tolist()
    )


def test_trial_seeds_differ_between_trials() -> None:
    states = {
        tuple(trial_seed(5, p, r).generate_state(2).tolist()) for p in range(20) for r in range(20)
    }
    assert len(states) == 400


@pytest.mark.parametrize("bad", [-1, 1.5, True, "7"])
def test_bad_root_entropy_is_refused(bad: Any) -> None:
    with pytest.raises(ConfigError) as err:
        check_entropy(bad)
    assert str(err.value) == (
        f"sweep.seed = {bad!r} is not allowed: must be an integer >= 0 (the root entropy); "
        "e.g. seed = 20240601"
    )


# -- registry ----------------------------------------------------------------------------


def square_trial(params: dict[str, Any], seed: np.random.SeedSequence) -> dict[str, Any]:
    return {"y": params["x"] ** 2, "u": float(np.random.default_rng(seed).uniform())}


def test_registered_test_trial_runs_by_name(tmp_path: Path) -> None:
    register_trial("test_square")(square_trial)
    try:
        assert TRIALS["test_square"] == f"{square_trial.__module__}:square_trial"
        spec = sweep_from_dict(
            {"sweep": {"name": "sq", "trial": "test_square", "seed": 4}, "grid": {"x": [2, 3]}}
        )
        outcome = run_sweep(spec, tmp_path, SerialRunner(), show_progress=False)
        assert [r["result"]["y"] for r in outcome.records] == [4, 9]
        with pytest.raises(ConfigError) as err:
            register_trial("test_square")(test_registered_test_trial_runs_by_name)
        assert str(err.value) == (
            "trial name = 'test_square' is not allowed: must be a name not yet registered; "
            f"'test_square' is already {TRIALS['test_square']}; choose another name"
        )
    finally:
        unregister_trial("test_square")
    assert "test_square" not in TRIALS


def test_register_trial_in_a_trial_file_records_the_file(tmp_path: Path) -> None:
    path = tmp_path / "file_trials.py"
    path.write_text(
        "from hil.evaluation.registry import register_trial\n\n"
        "@register_trial('test_file_trial')\n"
        "def cube(params, seed):\n"
        "    return {'y': params['x'] ** 3}\n"
    )
    try:
        load_trial(f"{path}:cube")
        assert TRIALS["test_file_trial"] == f"{path}:cube"
        rec = execute_trial(TRIALS["test_file_trial"], TrialTask(0, 0, 0, {"x": 2}, 1))
        assert rec["result"] == {"y": 8}
    finally:
        unregister_trial("test_file_trial")


def test_resolve_trial_forms(tmp_path: Path) -> None:
    assert resolve_trial("waveform_af_sidelobe") == (
        "hil.evaluation.trials_waveform:waveform_af_sidelobe"
    )
    assert resolve_trial("pkg.mod:fn") == "pkg.mod:fn"
    assert resolve_trial("t.py:fn", tmp_path) == f"{tmp_path.resolve() / 't.py'}:fn"
    assert resolve_trial("/abs/t.py:fn", tmp_path) == "/abs/t.py:fn"


@pytest.mark.parametrize(
    ("target", "message"),
    [
        (
            "/nowhere/trials.py:f",
            "sweep.trial = '/nowhere/trials.py:f' is not allowed: must be a trial in an existing "
            "Python file; /nowhere/trials.py not found",
        ),
        (
            "hil.evaluation.trials_waveform:DEFAULTS",
            "sweep.trial = 'hil.evaluation.trials_waveform:DEFAULTS' is not allowed: must be a "
            "callable trial(params, seed)",
        ),
    ],
)
def test_load_trial_refuses(target: str, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_trial(target)
    assert str(err.value) == message


# -- results -----------------------------------------------------------------------------


def test_normalise_result_makes_json_types() -> None:
    out = normalise_result(
        {
            "a": np.float32(0.5),
            "b": np.arange(3).reshape(3, 1),
            "c": (1, np.int16(2)),
            "d": None,
            "e": np.bool_(True),
            "f": np.float64(1.5),
        }
    )
    assert out == {"a": 0.5, "b": [[0], [1], [2]], "c": [1, 2], "d": None, "e": True, "f": 1.5}
    assert type(out["a"]) is float and type(out["e"]) is bool
    assert type(out["f"]) is float  # np.float64 subclasses float, but leaves as a plain float


@pytest.mark.parametrize(
    ("result", "message"),
    [
        (
            {"x": {1, 2}},
            "result 'x' is a set: values must be float, int, bool, str, None or lists of them",
        ),
        ({1: 2.0}, "result keys must be str, got 1"),
        (3.0, "a trial must return a dict of results, got float"),
    ],
)
def test_normalise_result_refuses(result: Any, message: str) -> None:
    with pytest.raises(TypeError) as err:
        normalise_result(result)
    assert str(err.value) == message


# -- runners -----------------------------------------------------------------------------


_CORES = os.cpu_count() or 1
_LOCAL_WORKERS = (
    f"an integer in 1..{4 * _CORES} (4 per core, {_CORES} cores); one per core is the default;"
    " for more, run on a Dask cluster (--scheduler)"
)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"workers": 2, "serial": True},
            "--workers/--serial/--dask-workers/--scheduler = 'several' is not allowed: must be "
            "one way to run: the local pool (--workers), --serial, or Dask",
        ),
        (
            {"dask_workers": 2, "scheduler": "tcp://h:1"},
            "--dask-workers = 2 is not allowed: must be not given together with --scheduler; "
            "pick one",
        ),
        ({"workers": 0}, f"--workers = 0 is not allowed: must be {_LOCAL_WORKERS}"),
        ({"dask_workers": 0}, f"--dask-workers = 0 is not allowed: must be {_LOCAL_WORKERS}"),
        ({"workers": 100_000}, f"--workers = 100000 is not allowed: must be {_LOCAL_WORKERS}"),
        (
            {"scheduler": "localhost:8786"},
            "--scheduler = 'localhost:8786' is not allowed: must be an address tcp://HOST:PORT "
            "(or tls://HOST:PORT)",
        ),
    ],
)
def test_bad_runner_options_are_refused(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError) as err:
        make_runner(**kwargs)
    assert str(err.value) == message


def test_default_runner_is_the_process_pool() -> None:
    runner = make_runner()
    assert isinstance(runner, LocalPoolRunner)
    assert runner.workers >= 1
    assert isinstance(make_runner(dask_workers=3), DaskRunner)
    assert isinstance(make_runner(serial=True), SerialRunner)


def test_missing_dask_extra_is_a_config_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)  # as if not installed
    with pytest.raises(ConfigError) as err, DaskRunner(n_workers=1):
        pass
    assert str(err.value) == (
        "runner = 'dask' is not allowed: must be available only with the dask extra "
        "installed; pip install 'cas-hil[dask]'"
    )


def test_unreachable_scheduler_is_a_config_error() -> None:
    with (
        pytest.raises(ConfigError) as err,
        DaskRunner(scheduler="tcp://127.0.0.1:1", connect_timeout_s=0.5),
    ):
        pass
    assert str(err.value).startswith(
        "--scheduler = 'tcp://127.0.0.1:1' is not allowed: must be the address of a running "
        "dask scheduler; cannot connect ("
    )
    assert str(err.value).endswith("workers with `dask worker ADDRESS --nthreads 1`")


def test_default_path_does_not_import_dask(tmp_path: Path) -> None:
    sweep = tmp_path / "s.toml"
    sweep.write_text(
        f'[sweep]\nname = "d"\ntrial = "{HELPERS}:draw_trial"\nseed = 1\ntrials_per_point = 2\n'
    )
    code = (
        "import sys\nfrom hil.cli.main import main\n"
        f"status = main(['sweep', {str(sweep)!r}, '--out', {str(tmp_path / 'o')!r}, "
        "'--workers', '1', '--quiet'])\n"
        "print(status, 'dask' in sys.modules, 'distributed' in sys.modules)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=False, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "0 False False"


@pytest.mark.parametrize(
    ("trial", "hint"),
    [
        ("../trials:f", "to load a file, write its name with .py: '../trials.py:f'"),
        ("./trials:f", "to load a file, write its name with .py: './trials.py:f'"),
        ("a/b:f", "to load a file, write its name with .py: 'a/b.py:f'"),
        ("..:f", "to load a file, write its name with .py, e.g. '../trials.py:function'"),
    ],
)
def test_a_path_like_module_is_refused_in_one_line_with_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], trial: str, hint: str
) -> None:
    from hil.cli.main import main

    (tmp_path / "trials.py").write_text("def f(params, seed):\n    return {'y': 1.0}\n")
    (tmp_path / "sub").mkdir()
    sweep = tmp_path / "sub" / "s.toml"
    sweep.write_text(f'[sweep]\nname = "a"\ntrial = "{trial}"\nseed = 1\n')
    out = tmp_path / "out"
    assert main(["sweep", str(sweep), "--out", str(out), "--serial", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"hil sweep: error: sweep.trial = '{trial}' is not allowed: must be "
        "'package.module:function' (dotted names) or 'file.py:function' (a path); "
        f"{hint}\n"
    )
    assert not out.exists()


def test_a_trial_file_up_a_folder_runs(tmp_path: Path) -> None:
    from hil.cli.main import main

    (tmp_path / "trials.py").write_text("def f(params, seed):\n    return {'y': 1.0}\n")
    (tmp_path / "sub").mkdir()
    sweep = tmp_path / "sub" / "s.toml"
    sweep.write_text('[sweep]\nname = "a"\ntrial = "../trials.py:f"\nseed = 1\n')
    assert main(["sweep", str(sweep), "--out", str(tmp_path / "out"), "--serial", "--quiet"]) == 0
    record = (tmp_path / "out" / "results.jsonl").read_text().splitlines()
    assert [json.loads(line)["result"] for line in record] == [{"y": 1.0}]
