"""Swept-sine response of an injected resonant transducer and its equaliser."""

from __future__ import annotations

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.experiments.calibration.apply import equalise
from hil.experiments.calibration.device import CalibrationError
from hil.experiments.calibration.response import ResponseResult, calibrate_response
from hil.experiments.calibration.simworld import FirWorld, SimTruth, sim_transducer

BAND = (4000.0, 16000.0)
#: Stated tolerances: response magnitude within 0.1 dB and phase within 1 degree of the truth
#: in band; equalised residual ripple below 1 dB peak-to-peak.
MAG_TOL_DB, PHASE_TOL_DEG, RIPPLE_DB = 0.1, 1.0, 1.0


def dtft(h: np.ndarray, f: np.ndarray, fs: float) -> np.ndarray:
    return np.exp(-2j * np.pi * np.outer(f, np.arange(h.size)) / fs) @ h


@pytest.fixture(scope="module")
def measured() -> tuple[SimTruth, ResponseResult]:
    truth = SimTruth(noise_rms=3e-4)
    device, _ = sim_transducer(truth)
    return truth, calibrate_response(device, band_hz=BAND)


def test_response_matches_the_injected_fir_in_band(
    measured: tuple[SimTruth, ResponseResult],
) -> None:
    truth, r = measured
    f = np.geomspace(*BAND, 300)
    # The measured phase is relative to the window start; the truth starts at the latency.
    shift = np.exp(-2j * np.pi * f * (truth.latency_samples - r.delay_samples) / truth.samplerate)
    h_true = dtft(truth.transducer_fir(), f, truth.samplerate) * shift
    ratio = r.response(f) / h_true
    assert np.max(np.abs(20 * np.log10(np.abs(ratio)))) < MAG_TOL_DB
    assert np.max(np.abs(np.degrees(np.angle(ratio)))) < PHASE_TOL_DEG
    # The stored magnitude/phase grid is the same response.
    inband = (r.freqs_hz >= BAND[0]) & (r.freqs_hz <= BAND[1])
    grid = r.response(r.freqs_hz[inband])
    np.testing.assert_allclose(r.magnitude_db[inband], 20 * np.log10(np.abs(grid)), atol=1e-9)


def test_equaliser_flattens_the_true_transducer(measured: tuple[SimTruth, ResponseResult]) -> None:
    truth, r = measured
    f = np.geomspace(*BAND, 500)
    h_true = dtft(truth.transducer_fir(), f, truth.samplerate)
    flat_db = 20 * np.log10(np.abs(h_true * dtft(r.equaliser, f, truth.samplerate)))
    raw_db = 20 * np.log10(np.abs(h_true))
    assert raw_db.max() - raw_db.min() > 10.0  # a strongly coloured transducer...
    assert flat_db.max() - flat_db.min() < RIPPLE_DB  # ...flattened
    assert abs(np.mean(flat_db)) < 0.2
    assert r.ripple_db < RIPPLE_DB and r.raw_ripple_db > 10.0


def test_equalise_time_domain_keeps_alignment(measured: tuple[SimTruth, ResponseResult]) -> None:
    truth, r = measured
    fs = truth.samplerate
    t = np.arange(4800) / fs
    tone = np.sin(2 * np.pi * 12000.0 * t)
    through = np.convolve(equalise(tone, r), r.impulse_response)[: t.size]
    # Equalised then passed through the measured response: the tone comes back at unit gain.
    mid = slice(2000, 4000)
    amp = np.sqrt(2 * np.mean(through[mid] ** 2))
    assert 20 * np.log10(amp) == pytest.approx(0.0, abs=0.5)


def test_json_round_trip(measured: tuple[SimTruth, ResponseResult]) -> None:
    _, r = measured
    back = ResponseResult.from_json(r.to_json())
    np.testing.assert_array_equal(back.equaliser, r.equaliser)
    assert back.band_hz == r.band_hz and back.delay_samples == r.delay_samples


def test_open_loop_is_refused() -> None:
    from hil.devices.audio import AudioSettings, SimulatedDuplex
    from hil.experiments.calibration.device import from_duplex

    sim = SimulatedDuplex(AudioSettings(48000), FirWorld([0.0], noise_rms=1e-3, seed=1))
    with pytest.raises(CalibrationError, match=r"no clear impulse response on input 0 .*open"):
        calibrate_response(from_duplex(sim), duration_s=0.3)


def test_band_outside_the_sweep_is_refused() -> None:
    device, _ = sim_transducer(SimTruth())
    with pytest.raises(ConfigError, match=r"^band_hz = \(100.0, 16000.0\) is not allowed"):
        calibrate_response(device, band_hz=(100.0, 16000.0), sweep_hz=(200.0, 20000.0))
