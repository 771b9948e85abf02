"""Gain and hydrophone sensitivity against injected truths (sim_devices' receiver model)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hil.devices.audio import AudioSettings, SimulatedDuplex
from hil.errors import ConfigError
from hil.experiments.calibration.apply import pressure_upa
from hil.experiments.calibration.device import CalibrationError, from_duplex
from hil.experiments.calibration.level import (
    LevelResult,
    ReferenceSource,
    calibrate_level,
)
from hil.experiments.calibration.simworld import (
    FirWorld,
    SimTruth,
    default_references,
    sim_hydrophones,
    sim_transducer,
)
from sim_devices.acoustics.channel import Receiver, source_amplitude

GAIN_TOL_DB = 0.1  # the requirement


@pytest.mark.parametrize("frequency", [1000.0, 9000.0, 15000.0])
def test_gain_through_the_transducer_within_0_1_db(frequency: float) -> None:
    truth = SimTruth(noise_rms=1e-3)
    device, _ = sim_transducer(truth)
    r = calibrate_level(device, frequency_hz=frequency, amplitude=0.3)
    h = truth.transducer_fir()
    true_gain = abs(np.exp(-2j * np.pi * frequency * np.arange(h.size) / truth.samplerate) @ h)
    assert r.gain_db == pytest.approx(20 * np.log10(true_gain), abs=GAIN_TOL_DB)
    assert r.gain_fs_per_fs == pytest.approx(r.received_fs / 0.3)


def test_sensitivity_from_a_reference_hydrophone_and_from_a_source() -> None:
    truth = SimTruth(noise_rms=1e-3)
    device, _ = sim_hydrophones(truth)
    by_hydrophone, by_source = default_references(truth)
    kw: dict[str, Any] = {
        "adc_full_scale_v": truth.adc_full_scale_v,
        "input_gain_db": truth.input_gain_db,
    }
    r1 = calibrate_level(device, reference=by_hydrophone, **kw)
    r2 = calibrate_level(device, reference=by_source, **kw)
    assert r1.sensitivity_db == pytest.approx(truth.sensitivity_db, abs=GAIN_TOL_DB)
    assert r2.sensitivity_db == pytest.approx(truth.sensitivity_db, abs=GAIN_TOL_DB)
    assert (r1.reference["method"], r2.reference["method"]) == ("hydrophone", "source")
    # Gain against the receiver model: p (µPa) -> V -> FS.
    p = source_amplitude(truth.source_level_db) / truth.distance_m
    rx = Receiver(truth.sensitivity_db, truth.input_gain_db, truth.adc_full_scale_v)
    expected = float(rx.to_counts(np.array([p]))[0])
    assert r1.gain_db == pytest.approx(20 * np.log10(expected), abs=GAIN_TOL_DB)
    # Applying it: counts back to the pressure that made them.
    assert float(pressure_upa(r1.received_fs, r1)) == pytest.approx(0.25 * p, rel=0.012)
    assert LevelResult.from_json(r2.to_json()) == r2


def test_absorption_raises_the_received_level_estimate() -> None:
    truth = SimTruth(noise_rms=0.0)
    device, _ = sim_hydrophones(truth)
    lossless = calibrate_level(device, reference=ReferenceSource(180.0, 1.0))
    lossy = calibrate_level(device, reference=ReferenceSource(180.0, 1.0, 1000.0))
    assert lossless.sensitivity_db is not None and lossy.sensitivity_db is not None
    assert lossy.sensitivity_db - lossless.sensitivity_db == pytest.approx(1.0, abs=1e-9)


def test_clipping_and_open_loop_are_refused() -> None:
    clip = SimulatedDuplex(AudioSettings(48000), FirWorld([4.0]))
    with pytest.raises(CalibrationError, match=r"input 0 clips .*lower the drive amplitude"):
        calibrate_level(from_duplex(clip))
    silent = SimulatedDuplex(AudioSettings(48000), FirWorld([0.0], noise_rms=1e-3))
    with pytest.raises(CalibrationError, match=r"did not come back on input 0 .*open"):
        calibrate_level(from_duplex(silent))


def test_bad_inputs() -> None:
    device, _ = sim_transducer(SimTruth())
    with pytest.raises(ConfigError, match=r"^frequency_hz = 30000.0 is not allowed: must be in"):
        calibrate_level(device, frequency_hz=30000.0)
    with pytest.raises(ConfigError, match=r"^duration_s = 0.1 is not allowed: .*lengthen the tone"):
        calibrate_level(device, duration_s=0.1)
    with pytest.raises(ConfigError, match=r"^distance_m = 0.0 is not allowed"):
        ReferenceSource(180.0, 0.0)
