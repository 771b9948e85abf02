"""The versioned store, the current pointer, the age check and applying calibrations."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil import __version__
from hil.errors import ConfigError
from hil.experiments.calibration.apply import (
    CalibrationSet,
    StagePositionCorrection,
    align_recording,
)
from hil.experiments.calibration.latency import LatencyResult
from hil.experiments.calibration.sound_speed import calibrate_sound_speed_temperature
from hil.experiments.calibration.store import CalibrationStore

T0 = dt.datetime(2025, 3, 1, 10, 15, 0, tzinfo=dt.UTC)
LAT = LatencyResult((549, 549), 48000.0, 549, 549.0, 0.0, 0, 45.0, 0.35)


def test_round_trip_ids_and_record_contents(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path)
    rec = store.save("latency", LAT, {"device": "sim://audio"}, now=T0)
    assert rec.id.startswith("latency-20250301T101500000000Z-") and len(rec.id.split("-")[-1]) == 8
    data = json.loads(rec.path.read_text())
    assert data["software_version"] == __version__ and data["settings"] == {"device": "sim://audio"}
    assert store.load("latency", rec.id).result == LAT
    current = store.current("latency")
    assert current is not None and current.result == LAT


def test_versions_and_current_pointer(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path)
    first = store.save("sound-speed", calibrate_sound_speed_temperature(18.0), {}, now=T0)
    later = T0 + dt.timedelta(hours=1)
    second = store.save("sound-speed", calibrate_sound_speed_temperature(22.0), {}, now=later)
    assert store.history("sound-speed") == [first.id, second.id]
    assert store.current("sound-speed").id == second.id  # type: ignore[union-attr]
    store.set_current("sound-speed", first.id)
    assert store.current("sound-speed").result.temperature_c == 18.0  # type: ignore[union-attr]
    kept = store.save(
        "sound-speed", calibrate_sound_speed_temperature(25.0), {}, make_current=False
    )
    assert store.current("sound-speed").id == first.id and len(store.history("sound-speed")) == 3  # type: ignore[union-attr]
    assert kept.id != first.id
    with pytest.raises(ConfigError, match=r"^calibration id = 'nope' is not allowed"):
        store.set_current("sound-speed", "nope")


def test_age_check_messages(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path)
    with pytest.raises(
        ConfigError,
        match=rf"^calibration 'latency' = 'missing' is not allowed: must be present in the "
        rf"store .*; run: hil calibrate latency --store {tmp_path}$",
    ):
        store.require("latency", 86400.0)
    rec = store.save("latency", LAT, {}, now=T0)
    assert store.require("latency", 86400.0, now=T0 + dt.timedelta(hours=5)).id == rec.id
    with pytest.raises(
        ConfigError,
        match=rf"^calibration 'latency' = '3.0 days old \(id {rec.id}\)' is not allowed: must be "
        rf"at most 24.0 h old; it is stale; run: hil calibrate latency --store {tmp_path}$",
    ):
        store.require("latency", 86400.0, now=T0 + dt.timedelta(days=3))


def test_unknown_kind(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"^kind = 'gain' is not allowed: must be one of latency"):
        CalibrationStore(tmp_path).save("gain", LAT, {})


def test_calibration_set_collects_and_requires(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path)
    assert CalibrationSet.current(tmp_path).records == {}
    store.save("latency", LAT, {}, now=T0)
    store.save("sound-speed", calibrate_sound_speed_temperature(20.0), {}, now=T0)
    cal = CalibrationSet.current(tmp_path)
    assert (cal.sample_offset, round(cal.sound_speed_mps or 0, 2)) == (549, 1482.38)
    assert cal.stage is None and cal.stage_correction is None and cal.response is None
    now = T0 + dt.timedelta(minutes=10)
    assert CalibrationSet.require(tmp_path, ["latency", "sound-speed"], 3600.0, now).latency == LAT
    with pytest.raises(ConfigError, match=r"^calibration 'stage' = 'missing'"):
        CalibrationSet.require(tmp_path, ["latency", "stage"], 3600.0, now)


def test_align_recording() -> None:
    rec = np.zeros((600, 1))
    rec[549 + 7] = 1.0
    assert int(np.argmax(align_recording(rec, LAT))) == 7


@given(
    scale=st.floats(0.99, 1.01),
    backlash=st.floats(0.0, 1e-3),
    target=st.floats(-0.5, 0.0),
    direction=st.sampled_from([1, -1]),
)
def test_stage_correction_round_trip(
    scale: float, backlash: float, target: float, direction: int
) -> None:
    corr = StagePositionCorrection(scale, backlash, -0.2)
    command = corr.command_for(target, direction)
    assert corr.true_position(command, direction) == pytest.approx(target, abs=1e-12)
