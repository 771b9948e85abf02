"""The two test tiers of the root conftest: plain ``pytest`` leaves out the tests marked
``slow``, ``--all`` runs everything, a ``-m`` expression or a test named by its node id
overrides the default selection. Run in a scratch project with the repository's conftest."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

ROOT_CONFTEST = Path(__file__).resolve().parents[1] / "conftest.py"

TESTS = """
import pytest

def test_fast():
    pass

@pytest.mark.slow
def test_slow():
    pass

@pytest.mark.slow
@pytest.mark.parametrize("k", [1, 2])
def test_slow_cases(k):
    pass
"""


@pytest.fixture
def project(pytester: pytest.Pytester) -> pytest.Pytester:
    pytester.makeconftest(ROOT_CONFTEST.read_text())
    pytester.makepyprojecttoml(
        """
[tool.pytest.ini_options]
addopts = "--strict-markers"
markers = ["slow: long-running test"]
"""
    )
    pytester.makepyfile(test_tiers_sample=TESTS)
    return pytester


QUIET = ("-p", "no:hypothesispytest")  # its summary hook costs ~0.5 s a run, unused here


def _passed(run: pytest.HookRecorder) -> list[str]:
    """Names of the tests that passed in an inline run, sorted."""
    passed, skipped, failed = run.listoutcomes()
    assert not skipped and not failed
    return sorted(report.nodeid.split("::", 1)[1] for report in passed)


def test_plain_pytest_is_the_fast_tier(project: pytest.Pytester) -> None:
    run = project.inline_run(*QUIET)
    assert _passed(run) == ["test_fast"]
    deselected = [item.name for call in run.getcalls("pytest_deselected") for item in call.items]
    assert sorted(deselected) == ["test_slow", "test_slow_cases[1]", "test_slow_cases[2]"]


def test_all_runs_the_slow_tests_too(project: pytest.Pytester) -> None:
    run = project.inline_run(*QUIET, "--all")
    assert _passed(run) == ["test_fast", "test_slow", "test_slow_cases[1]", "test_slow_cases[2]"]


def test_a_marker_expression_replaces_the_default_selection(project: pytest.Pytester) -> None:
    assert _passed(project.inline_run(*QUIET, "-m", "slow")) == [
        "test_slow",
        "test_slow_cases[1]",
        "test_slow_cases[2]",
    ]
    assert _passed(project.inline_run(*QUIET, "-m", "not slow")) == ["test_fast"]


def test_a_slow_test_named_by_its_node_id_runs(project: pytest.Pytester) -> None:
    assert _passed(project.inline_run(*QUIET, "test_tiers_sample.py::test_slow")) == ["test_slow"]
    named = project.inline_run(*QUIET, "test_tiers_sample.py::test_slow_cases")
    assert _passed(named) == ["test_slow_cases[1]", "test_slow_cases[2]"]


def test_a_run_naming_its_tests_by_node_id_starts_no_workers(project: pytest.Pytester) -> None:
    """``-n auto`` (the suite's addopts) runs tests named by node id in process."""
    result = project.runpytest_subprocess(*QUIET, "-n", "auto", "test_tiers_sample.py::test_slow")
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["collected 1 item"])
    result.stdout.no_fnmatch_line("created: *workers")


@pytest.mark.slow
def test_a_run_over_the_suite_shares_its_tests_among_workers(
    project: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PYTEST_XDIST_AUTO_NUM_WORKERS", "2")
    result = project.runpytest_subprocess(*QUIET, "-n", "auto", "--all")
    result.stdout.fnmatch_lines(["*2 workers [[]4 items[]]*"])
    result.assert_outcomes(passed=4)
    fast = project.runpytest_subprocess(*QUIET, "-n", "auto")
    fast.stdout.fnmatch_lines(["*2 workers [[]1 item[]]*"])
    fast.assert_outcomes(passed=1)


def test_the_suite_runs_on_every_core() -> None:
    """pyproject's addopts hand the suite to one pytest-xdist worker per core."""
    pyproject = tomllib.loads((ROOT_CONFTEST.parent / "pyproject.toml").read_text())
    addopts = pyproject["tool"]["pytest"]["ini_options"]["addopts"].split()
    assert "auto" in addopts and addopts[addopts.index("auto") - 1] == "-n"


def test_the_header_says_how_to_run_everything(project: pytest.Pytester) -> None:
    fast = project.runpytest(*QUIET)
    fast.stdout.fnmatch_lines(["fast tier: tests marked slow are deselected (pytest --all *"])
    fast.stdout.fnmatch_lines(["*1 passed, 3 deselected*"])
    assert "fast tier" not in project.runpytest(*QUIET, "--all").stdout.str()


def test_every_run_ends_with_its_20_slowest_tests(project: pytest.Pytester) -> None:
    pyproject = tomllib.loads((ROOT_CONFTEST.parent / "pyproject.toml").read_text())
    addopts = pyproject["tool"]["pytest"]["ini_options"]["addopts"].split()
    durations = [opt for opt in addopts if opt.startswith("--durations")]
    assert durations == ["--durations=20"]
    result = project.runpytest_inprocess(*QUIET, "--all", *durations)
    result.stdout.fnmatch_lines(["*slowest 20 durations*"])


def test_ci_runs_the_readme_test_command_verbatim() -> None:
    """The README's test command is the last line of ``.ci/run``, durations included."""
    repo = ROOT_CONFTEST.parent
    readme = (repo / "README.md").read_text().splitlines()
    commands = [line for line in readme if "pytest --all" in line and "pip install" in line]
    assert len(commands) == 1, commands
    ci_lines = [line for line in (repo / ".ci/run").read_text().splitlines() if line.strip()]
    assert ci_lines[-1] == commands[0]
    assert commands[0].endswith("pytest --all --durations=20")


WARM_UP = """
import sys
import time
from pathlib import Path

# Each part's file appears only after a pause, so a test run before the warm-up ends misses it.
time.sleep(2.0)
(Path(__file__).parent / f"warmed-{sys.argv[1]}").write_text("done")
"""

#: The stand-in for the tests that count which parts a warm-up ran, not when: no pause.
WARM_UP_AT_ONCE = """
import sys
from pathlib import Path

(Path(__file__).parent / f"warmed-{sys.argv[1]}").write_text("done")
"""

WARMED_TEST = """
from pathlib import Path

def test_the_warm_up_ended_first():
    here = Path(__file__).parent
    assert (here / "tests" / "warmed-tank").exists()
    assert (here / "tests" / "warmed-receivers").exists()
"""


@pytest.mark.slow
def test_workers_wait_for_the_numba_warm_up_before_their_first_test(
    project: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The controller of an xdist run starts ``tests/numba_warm_up.py`` once per part; every
    worker runs its first test only after those processes ended (here a stand-in script that
    leaves one file per part)."""
    (project.path / "tests").mkdir()
    (project.path / "tests" / "numba_warm_up.py").write_text(WARM_UP)
    project.makepyfile(test_warmed=WARMED_TEST)
    monkeypatch.setenv("PYTEST_XDIST_AUTO_NUM_WORKERS", "2")
    result = project.runpytest_subprocess(
        *QUIET, "-n", "auto", "test_warmed.py", "test_tiers_sample.py"
    )
    result.assert_outcomes(passed=2)
    assert sorted(p.name for p in (project.path / "tests").iterdir()) == [
        "numba_warm_up.py",
        "warmed-receivers",
        "warmed-tank",
    ]


@pytest.mark.slow
def test_a_run_over_the_sources_the_last_warm_up_left_starts_none(
    project: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The controller keeps the digest of the kernels' sources and numba's cache that a
    completed warm-up left (the pytest cache): the next run over the same files starts no
    warm-up; a module added to a kernel package starts it again."""
    tests = project.path / "tests"
    tests.mkdir()
    (tests / "numba_warm_up.py").write_text(WARM_UP_AT_ONCE)
    monkeypatch.setenv("PYTEST_XDIST_AUTO_NUM_WORKERS", "2")

    def warmed_parts() -> list[str]:
        """Run the sample's fast test on 2 workers: the parts the warm-up ran (their files,
        removed after)."""
        result = project.runpytest_subprocess(*QUIET, "-n", "auto", "test_tiers_sample.py")
        result.assert_outcomes(passed=1)
        parts = sorted(tests.glob("warmed-*"))
        for path in parts:
            path.unlink()
        return [path.name for path in parts]

    assert warmed_parts() == ["warmed-receivers", "warmed-tank"]
    assert warmed_parts() == []
    (project.path / "hil").mkdir()
    (project.path / "hil" / "kernels.py").write_text("SCALE = 2\n")
    assert warmed_parts() == ["warmed-receivers", "warmed-tank"]


@pytest.mark.slow
def test_the_suite_keeps_its_rewritten_test_modules_where_bytecode_is_off(
    project: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Without the cached bytecode each worker rewrites every test module's assertions again
    # (the root conftest's pytest_configure).
    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    result = project.runpytest_subprocess("-p", "no:xdist", *QUIET)
    result.assert_outcomes(passed=1, deselected=3)
    cached = sorted(p.name for p in (project.path / "__pycache__").glob("test_tiers_sample.*.pyc"))
    assert len(cached) == 1 and "-pytest-" in cached[0], cached
