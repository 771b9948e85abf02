"""The benchmark's same-run check (``benchmarks/run_identity.py``) on a real virtual run's
folder: a copy is the same run; a changed sample, estimate row, background value or summary
figure is a difference; the wall-clock flush table, start time and summary keys are not."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from tests.experiments.conftest import CliRun

# The check is a benchmark tool (benchmarks/), imported as the benchmark imports it.
BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))

from run_identity import check_or_save, differences  # noqa: E402


@pytest.fixture
def copies(cli_virtual_run: CliRun, tmp_path: Path) -> tuple[Path, Path]:
    """The run's folder copied twice: (the run, its reference)."""
    run, reference = tmp_path / "run", tmp_path / "reference"
    shutil.copytree(cli_virtual_run.folder, run)
    shutil.copytree(cli_virtual_run.folder, reference)
    return run, reference


def _edit_dataset(folder: Path, name: str) -> None:
    with h5py.File(folder / "run.h5", "r+") as f:
        data = f[name][()]
        data.flat[0] = data.flat[0] + 1
        f[name][...] = data


def test_a_copy_is_the_same_run(copies: tuple[Path, Path]) -> None:
    assert differences(*copies) == []


def test_a_changed_sample_is_a_difference(copies: tuple[Path, Path]) -> None:
    run, reference = copies
    _edit_dataset(run, "samples")
    assert differences(run, reference) == ["run.h5 samples: differs"]


def test_the_wall_clock_flush_table_is_not_a_difference(copies: tuple[Path, Path]) -> None:
    run, reference = copies
    _edit_dataset(run, "flushes/clock_s")
    summary = json.loads((run / "summary.json").read_text())
    summary["wall_s"] += 1.0
    (run / "summary.json").write_text(json.dumps(summary))
    assert differences(run, reference) == []


def test_outputs_beside_the_recording_are_compared(copies: tuple[Path, Path]) -> None:
    run, reference = copies
    background = np.load(run / "background.npy")
    background[0] = np.nextafter(background[0], np.inf)
    np.save(run / "background.npy", background)
    summary = json.loads((run / "summary.json").read_text())
    summary["estimates"] += 1
    (run / "summary.json").write_text(json.dumps(summary))
    with (run / "estimates.csv").open("a") as f:
        f.write("0\n")
    assert differences(run, reference) == [
        "background.npy: differs",
        "summary.json: estimates differ",
        "estimates.csv: differs",
    ]


def test_the_first_check_saves_the_run_and_the_next_compares(
    copies: tuple[Path, Path], tmp_path: Path
) -> None:
    run, _ = copies
    saved = tmp_path / "saved"
    assert check_or_save(run, saved) is None
    assert sorted(p.name for p in saved.iterdir()) == sorted(
        ["run.h5", "background.npy", "summary.json", "estimates.csv"]
    )
    assert check_or_save(run, saved) == []
    (run / "estimates.csv").unlink()
    assert check_or_save(run, saved) == ["estimates.csv: missing"]
