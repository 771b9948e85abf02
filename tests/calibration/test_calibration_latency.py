"""Loopback latency against the injected I/O and cable delays, and its refusals."""

from __future__ import annotations

import numpy as np
import pytest

from hil.devices.audio import AudioSettings, SimulatedDuplex
from hil.errors import ConfigError
from hil.experiments.calibration.device import CalibrationError, PlayRecordDevice, from_duplex
from hil.experiments.calibration.latency import LatencyResult, calibrate_latency
from hil.experiments.calibration.simworld import FirWorld


def bench(
    io_delay: int, cable: int, gain: float, noise: float, block: int = 128
) -> PlayRecordDevice:
    world = FirWorld([gain], delay_samples=cable, noise_rms=noise, seed=5)
    sim = SimulatedDuplex(AudioSettings(48000, blocksize=block), world, io_delay_samples=io_delay)
    return from_duplex(sim)


@pytest.mark.parametrize(
    ("io_delay", "cable", "gain"), [(128, 0, 1.0), (256, 37, 0.35), (384, 1001, -0.05)]
)
def test_latency_is_sample_exact_on_every_repeat(io_delay: int, cable: int, gain: float) -> None:
    r = calibrate_latency(bench(io_delay, cable, gain, noise=1e-3), repeats=4)
    assert r.samples == (io_delay + cable,) * 4
    assert (r.latency_samples, r.spread_samples, r.std_samples) == (io_delay + cable, 0, 0.0)
    assert r.mean_samples == io_delay + cable
    assert r.loop_gain == pytest.approx(gain, rel=0.01)
    assert r.latency_s == pytest.approx((io_delay + cable) / 48000)


def test_spread_and_median_of_varying_runs() -> None:
    lags = iter([100, 103, 100, 101, 100])

    def shifting(output: np.ndarray) -> np.ndarray:
        return np.roll(output, next(lags), axis=0)

    r = calibrate_latency(PlayRecordDevice(shifting, 48000.0), repeats=5)
    assert r.samples == (100, 103, 100, 101, 100)
    assert (r.latency_samples, r.spread_samples) == (100, 3)
    assert r.mean_samples == pytest.approx(100.8)
    assert LatencyResult.from_json(r.to_json()) == r


def test_open_loop_is_refused_with_advice() -> None:
    with pytest.raises(
        CalibrationError, match=r"run 1: .* on input 0 .*no signal.*loop looks open"
    ):
        calibrate_latency(bench(128, 0, 0.0, noise=0.0))
    with pytest.raises(CalibrationError, match=r"peak-to-sidelobe .* dB, need >= 20 dB"):
        calibrate_latency(bench(128, 0, 0.0, noise=0.01))


def test_latency_beyond_the_search_window_is_refused() -> None:
    with pytest.raises(CalibrationError, match="raise --max-latency if the latency exceeds 100"):
        calibrate_latency(bench(256, 0, 1.0, noise=1e-3), max_latency_frames=100)


def test_bad_options() -> None:
    dev = bench(128, 0, 1.0, 0.0)
    with pytest.raises(ConfigError, match=r"^repeats = 0 is not allowed: must be an integer >= 1"):
        calibrate_latency(dev, repeats=0)
    with pytest.raises(
        ConfigError, match=r"^input_channel = 2 is not allowed: must be an integer in \[0, 1\)"
    ):
        calibrate_latency(dev, input_channel=2)
