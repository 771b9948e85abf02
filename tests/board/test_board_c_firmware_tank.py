"""``hil tank-run`` with the C reference firmware in the Python board's place.

The simulated tank puts the firmware (``sim://board?impl=c``) behind the acoustic tank
through its HAL (``sim_devices.board.c_firmware.CFirmwareBoardOnPty``), on the tank's shared
clock. The run must complete and track the towed target as with the Python board. Needs
``cc`` and ``make`` (skip without them, failure under ``HIL_REQUIRE_SYSTEM_DEPS=1``).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from hil.cli.main import main
from hil.experiments.experiment import DEFAULT_EXPERIMENT
from sim_devices.board import c_firmware


@pytest.mark.slow
def test_tank_run_completes_with_the_c_firmware_as_the_board(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    require_system: Callable[[bool, str], None],
) -> None:
    missing = c_firmware.toolchain_missing()
    require_system(missing is None, f"C firmware not buildable: {missing}")
    text = DEFAULT_EXPERIMENT.replace('board = "sim://board"', 'board = "sim://board?impl=c"')
    text = text.replace("end_m = -5.0", "end_m = -3.5")
    assert "impl=c" in text
    exp_file = tmp_path / "c-board.toml"
    exp_file.write_text(text)
    folder = tmp_path / "run"
    assert main(["tank-run", str(exp_file), "--out", str(folder), "--no-live", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["error"] == "" and not summary["interrupted"]
    assert summary["adc_overruns"] == 0  # the firmware's link buffer never overflowed
    assert summary["adc_clipped_samples"] == 0  # counted by the firmware, as in Python
    assert summary["dropped_samples"] == 0
    assert summary["loopback_latency_samples"] == 64  # the simulated converters, as in Python
    assert summary["scored_estimates"] >= 50
    assert summary["speed_rmse_mps"] < 0.1 and summary["range_rmse_m"] < 0.6
    assert summary["detection_rate"] > 0.9
