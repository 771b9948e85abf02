"""Every output a command writes is checked before any work by one helper
(:mod:`hil.outputs`): an unwritable one is refused in one line naming the option, exit status
2, never a traceback after the work was done."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from .conftest import one_line_error

SWEEP = Path(__file__).resolve().parents[2] / "hil" / "data" / "sweeps" / "cmp_fmcw.toml"


@pytest.fixture
def read_only(tmp_path: Path) -> Iterator[Path]:
    """A folder where no file can be created: a mode-555 folder, or for root (who ignores
    permission bits) sysfs, which refuses new files to root as well."""
    if os.geteuid() != 0:
        folder = tmp_path / "read-only"
        folder.mkdir()
        folder.chmod(0o555)
        yield folder
        folder.chmod(0o755)
        return
    sysfs = Path("/sys")
    try:
        os.close(os.open(sysfs / "hil-probe", os.O_CREAT | os.O_WRONLY))
    except PermissionError:
        yield sysfs
        return
    except OSError:
        pass
    pytest.skip("running as root without a read-only place (sysfs) to write into")


def _cannot_write(option: str, folder: Path) -> str:
    return (
        f"{option} = '{folder}' is not allowed: must be a folder this user can write;"
        f" cannot write there (Permission denied): choose a writable folder"
    )


def test_tank_run_out_in_a_read_only_folder(
    read_only: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = one_line_error(capsys, ["tank-run", "--out", str(read_only / "run")])
    assert line == "hil tank-run: error: " + _cannot_write("--out (its parent folder)", read_only)


def test_runs_dir_read_only(
    read_only: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("HIL_RUNS_DIR", str(read_only))
    line = one_line_error(capsys, ["tank-run"])
    assert line == "hil tank-run: error: " + _cannot_write("run.output_dir", read_only)


def test_report_out_read_only(
    read_only: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = one_line_error(capsys, ["report", str(tmp_path / "run.h5"), "--out", str(read_only)])
    assert line == "hil report: error: " + _cannot_write("--out", read_only)


def test_replay_csv_read_only(
    read_only: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["replay", str(tmp_path / "run.h5"), "--csv", str(read_only / "est.csv")]
    line = one_line_error(capsys, argv)
    assert line == "hil replay: error: " + _cannot_write("--csv (its folder)", read_only)


@pytest.mark.parametrize("option", ["--csv", "--map"])
def test_estimate_outputs_read_only(
    option: str,
    read_only: Path,
    schedule_and_wav: tuple[Path, Path],
    capsys: pytest.CaptureFixture[str],
) -> None:
    schedule, wav = schedule_and_wav
    argv = ["estimate", "--input", str(wav), "--schedule", str(schedule)]
    line = one_line_error(capsys, [*argv, option, str(read_only / "out.x")])
    assert line == "hil estimate: error: " + _cannot_write(f"{option} (its folder)", read_only)


@pytest.mark.parametrize("option", ["--out", "--schedule"])
def test_waveform_files_read_only(
    option: str, read_only: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = one_line_error(capsys, ["waveform", "--duration", "0.05", option, str(read_only / "x")])
    assert line == "hil waveform: error: " + _cannot_write(f"{option} (its folder)", read_only)


def test_waveform_plot_read_only_or_onto_a_file(
    read_only: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = one_line_error(capsys, ["waveform", "--duration", "0.05", "--plot", str(read_only)])
    assert line == "hil waveform: error: " + _cannot_write("--plot", read_only)
    a_file = tmp_path / "plots.png"
    a_file.write_text("")
    line = one_line_error(capsys, ["waveform", "--duration", "0.05", "--plot", str(a_file)])
    assert line == (
        f"hil waveform: error: --plot = '{a_file}' is not allowed: must be a folder;"
        " it is a file: choose a folder"
    )


def test_simulate_out_read_only(read_only: Path, capsys: pytest.CaptureFixture[str]) -> None:
    line = one_line_error(capsys, ["simulate", "att", "--out", str(read_only / "sim")])
    assert line == "hil simulate: error: " + _cannot_write("--out (its parent folder)", read_only)


def test_sweep_and_reproduce_out_read_only(
    read_only: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = one_line_error(capsys, ["sweep", str(SWEEP), "--out", str(read_only)])
    assert line == "hil sweep: error: " + _cannot_write("--out", read_only)
    line = one_line_error(capsys, ["reproduce", "--quick", "--out", str(read_only)])
    assert line == "hil reproduce: error: " + _cannot_write("--out", read_only)


def test_calibration_store_read_only(read_only: Path, capsys: pytest.CaptureFixture[str]) -> None:
    line = one_line_error(capsys, ["calibrate", "latency", "--store", str(read_only)])
    # A simulated calibration goes into the store's simulated/ folder, made first.
    assert line == (
        f"hil calibrate: error: --store (or HIL_CALIBRATION_DIR) = '{read_only / 'simulated'}'"
        " is not allowed: must be a folder this user can create; cannot create it"
        f" ({'Permission denied' if os.geteuid() else 'Operation not permitted'}):"
        " choose a writable place"
    )


def test_log_file_read_only(read_only: Path, capsys: pytest.CaptureFixture[str]) -> None:
    line = one_line_error(capsys, ["--log-file", str(read_only / "hil.log"), "devices", "--json"])
    assert line == "hil devices: error: " + _cannot_write("--log-file (its folder)", read_only)


def test_a_folder_given_for_a_file_and_a_file_for_a_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = one_line_error(capsys, ["waveform", "--duration", "0.05", "--out", str(tmp_path)])
    assert line == (
        f"hil waveform: error: --out = '{tmp_path}' is not allowed: must be a file;"
        " it is a folder: give a file name inside it"
    )
    line = one_line_error(capsys, ["tank-run", "--out", "/dev/null"])
    assert line == (
        "hil tank-run: error: --out = '/dev/null' is not allowed: must be a new or empty"
        " folder; it is a file, not a folder"
    )
