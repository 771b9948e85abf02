"""Simulated calibrations live apart from real ones and a real run never applies one;
``--samplerate`` sets the simulated bench's rate; ``HIL_CALIBRATION_DIR`` is the default store."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.cli.main import main
from hil.errors import ConfigError
from hil.experiments.calibration.store import CalibrationStore
from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from hil.experiments.run_calibrations import load_run_calibrations


def _experiment(store: Path, board: str, stage: str) -> str:
    text = DEFAULT_EXPERIMENT.replace('store = "calibration"', f'store = "{store}"')
    text = text.replace("required = []", 'required = ["latency"]')
    return text.replace('"sim://board"', f'"{board}"').replace('"sim://stage"', f'"{stage}"')


def test_real_run_refuses_a_simulated_calibration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["calibrate", "latency", "--store", str(tmp_path), "--repeats", "2"]) == 0
    simulated = CalibrationStore(tmp_path / "simulated").current("latency")
    assert simulated is not None and simulated.settings["simulated"] is True
    # A store of an older version held simulated results as current: a real run refuses them.
    record = CalibrationStore(tmp_path).save("latency", simulated.result, simulated.settings)
    real = parse_experiment(_experiment(tmp_path, "/dev/ttyACM0", "/dev/ttyUSB0"))
    with pytest.raises(ConfigError) as err:
        load_run_calibrations(real, 48000.0)
    assert str(err.value) == (
        f"calibration 'latency' = 'simulated (id {record.id})' is not allowed: must be measured "
        "on the real devices: a real run never applies a simulated one; run: hil calibrate "
        f"latency --device DEVICE --store {tmp_path}"
    )
    # A simulated run may use it.
    sim = parse_experiment(_experiment(tmp_path, "sim://board", "sim://stage"))
    assert load_run_calibrations(sim, 48000.0).latency_samples == 549


def test_samplerate_is_honoured_in_simulation(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["calibrate", "latency", "--store", str(tmp_path), "--repeats", "2"]
    assert main([*argv, "--samplerate", "96000"]) == 0
    out = capsys.readouterr().out
    assert "[truth] simulated loopback at 96000 Hz" in out
    record = CalibrationStore(tmp_path / "simulated").current("latency")
    assert record is not None and record.result.samplerate == 96000.0
    assert main([*argv, "--samplerate", "100"]) == 2
    assert capsys.readouterr().err.strip() == (
        "hil calibrate: error: --samplerate = 100.0 is not allowed: must be 8000 ... 384000 Hz"
    )


def test_calibration_dir_from_the_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("HIL_CALIBRATION_DIR", str(tmp_path / "lab-cal"))
    monkeypatch.setenv("HIL_RUNS_DIR", str(tmp_path / "lab-runs"))
    assert main(["calibrate", "sound-speed", "--temperature", "18.3"]) == 0
    assert CalibrationStore(tmp_path / "lab-cal").current("sound-speed") is not None
    exp = parse_experiment(DEFAULT_EXPERIMENT)
    assert exp.calibration_store == tmp_path / "lab-cal"
    assert exp.output_dir == tmp_path / "lab-runs"
    written = DEFAULT_EXPERIMENT.replace('output_dir = "runs"', 'output_dir = "mine"')
    assert parse_experiment(written).output_dir == Path("mine")


def test_the_former_simulated_audio_spelling_runs_the_simulated_bench(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["calibrate", "latency", "--store", str(tmp_path), "--repeats", "2"]
    assert main([*argv, "--device", "audio://sim"]) == 0
    captured = capsys.readouterr()
    assert "hil: WARNING: audio://sim is deprecated: write sim://audio" in captured.err
    assert "simulated: kept apart in" in captured.out
    record = CalibrationStore(tmp_path / "simulated").current("latency")
    assert record is not None and record.settings["simulated"] is True
