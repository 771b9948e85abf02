"""``hil calibrate`` in simulation: output, store, exit codes."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.cli.main import main
from hil.experiments.calibration.apply import CalibrationSet


def test_latency_in_simulation_prints_truth_result_and_store(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["calibrate", "latency", "--store", str(tmp_path), "--repeats", "3"]) == 0
    out = capsys.readouterr().out
    assert "[truth] simulated loopback" in out and "expect latency 549 samples" in out
    assert "latency: 549 samples" in out and "runs: 3: [549, 549, 549]" in out
    assert f"stored: {tmp_path}/simulated/latency/latency-" in out
    assert f"simulated: kept apart in {tmp_path}/simulated; a real run never applies it" in out
    assert CalibrationSet.current(tmp_path / "simulated").sample_offset == 549
    assert CalibrationSet.current(tmp_path).latency is None


def test_sound_speed_from_temperature_then_stage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store = ["--store", str(tmp_path)]
    assert main(["calibrate", "sound-speed", "--temperature", "18.3", *store]) == 0
    assert "by temperature" in capsys.readouterr().out
    args = ["calibrate", "stage", "--positions=-0.3:-0.1:4", "--pings", "2", *store]
    assert main(args) == 0
    out = capsys.readouterr().out
    # The simulated bench reads its own store: its thermometer, not the real calibration.
    assert "sound speed used: 1477.038 m/s (simulated thermometer 18.3 °C)" in out
    assert "stage scale:" in out and "backlash:" in out
    # The simulated GRBL powers up locked ($22=1): the stage is homed before it moves.
    assert "[truth] simulated stage powered up locked ($22=1): homing ($H, up to" in out
    assert CalibrationSet.current(tmp_path).sound_speed is not None  # by thermometer: real
    cal = CalibrationSet.current(tmp_path / "simulated")
    assert cal.stage is not None and cal.stage.scale == pytest.approx(1.0015, abs=5e-4)


def test_config_errors_exit_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store = ["--store", str(tmp_path)]
    assert main(["calibrate", "sound-speed", "--temperature", "-3", *store]) == 2
    err = capsys.readouterr().err
    assert err == (
        "hil calibrate: error: --temperature (temperature_c) = -3.0 is not allowed: must be "
        "0 to 95 °C (Marczak 1997); Marczak (1997) covers liquid water at 1 atm; for sea "
        "water use unesco_sound_speed\n"
    )
    assert main(["calibrate", "stage", "--positions=-0.2", *store]) == 2
    assert "--positions (positions_m) = [-0.2] is not allowed" in capsys.readouterr().err
    assert main(["calibrate", "level", "--source-level", "180", *store]) == 2
    assert "--source-level/--distance" in capsys.readouterr().err
    assert not (tmp_path / "level").exists()


def test_unknown_kind_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["calibrate", "gain"])
    assert info.value.code == 2
    assert "invalid choice: 'gain'" in capsys.readouterr().err
