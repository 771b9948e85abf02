"""Reference chirp and matched-filter latency measurement."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.devices.audio import (
    AudioSettings,
    DigitalLoopbackWorld,
    LatencyMeasurementError,
    SimulatedDuplex,
    lfm_chirp,
    matched_filter_delay,
    measure_loopback_latency,
    play_record_calibrated,
    reference_chirp,
)
from hil.devices.audio.contract import FloatArray
from hil.devices.audio.latency import mainlobe_halfwidth
from hil.errors import ConfigError


def test_chirp_sweeps_linearly_from_start_to_stop_frequency() -> None:
    fs, f0, f1, dur = 48000.0, 2000.0, 12000.0, 0.05
    x = lfm_chirp(fs, f0, f1, dur, amplitude=1.0, taper_fraction=0.0)
    assert x.shape == (2400,) and x.dtype == np.float32
    assert x[0] == 0.0
    # Instantaneous frequency from the analytic phase: f(t) = f0 + (f1 - f0) t / T.
    from scipy.signal import hilbert

    phase = np.unwrap(np.angle(hilbert(x.astype(np.float64))))
    inst = np.diff(phase) * fs / (2 * np.pi)
    t = (np.arange(inst.size) + 0.5) / fs
    core = slice(300, -300)  # the FFT Hilbert transform rings near the edges
    assert inst[core] == pytest.approx(f0 + (f1 - f0) * t[core] / dur, abs=60.0)


def test_reference_chirp_is_hann_tapered_with_low_sidelobes() -> None:
    ref = reference_chirp(192000)
    assert ref.shape == (3840,)
    assert float(np.max(np.abs(ref))) == pytest.approx(0.5, abs=1e-3)
    assert ref[0] == 0.0 and ref[-1] == pytest.approx(0.0, abs=1e-6)
    m = matched_filter_delay(np.concatenate([np.zeros(100), ref, np.zeros(100)]), ref, 192000)
    assert m.samples == 100
    assert m.peak_to_sidelobe_db > 40.0
    assert mainlobe_halfwidth(ref) == 9


@settings(max_examples=40, deadline=None)
@given(
    delay=st.integers(0, 3000),
    gain=st.floats(0.05, 1.0) | st.floats(-1.0, -0.05),
    seed=st.integers(0, 2**32 - 1),
)
def test_delay_found_to_the_sample_in_noise(delay: int, gain: float, seed: int) -> None:
    fs = 48000.0
    ref = reference_chirp(fs)
    rng = np.random.default_rng(seed)
    rx = 0.01 * rng.standard_normal(delay + ref.size + 500)
    rx[delay : delay + ref.size] += gain * ref
    m = matched_filter_delay(rx, ref, fs)
    assert m.samples == delay
    assert m.seconds == delay / fs
    assert m.gain == pytest.approx(gain, abs=0.02)
    assert m.peak_to_sidelobe_db > 15.0


def test_open_loop_is_refused_with_a_reason() -> None:
    def silence(output: FloatArray, index: int, inp: FloatArray) -> None:
        inp.fill(0.0)

    sim = SimulatedDuplex(AudioSettings(samplerate=48000, blocksize=64), silence)
    with pytest.raises(LatencyMeasurementError) as err:
        measure_loopback_latency(sim)
    assert str(err.value).startswith(
        "input channel 0: the reference chirp was not found cleanly (peak-to-sidelobe"
    )
    assert "check the loopback wiring and levels" in str(err.value)


def test_latency_beyond_the_search_window_is_refused() -> None:
    sim = SimulatedDuplex(AudioSettings(samplerate=48000, blocksize=64), DigitalLoopbackWorld(5000))
    with pytest.raises(LatencyMeasurementError, match=r"raise max_latency_frames \(1000\)"):
        measure_loopback_latency(sim, max_latency_frames=1000)


def test_calibrated_recording_is_aligned_per_run() -> None:
    rng = np.random.default_rng(11)
    signal = (0.2 * rng.standard_normal((3000, 2))).astype(np.float32)
    sim = SimulatedDuplex(
        AudioSettings(samplerate=48000, channels_in=2, channels_out=2, blocksize=128),
        DigitalLoopbackWorld(333, gain=-0.5),
        io_delay_samples=256,
    )
    run = play_record_calibrated(sim, signal, max_latency_frames=2000)
    assert [m.samples for m in run.calibration.latencies] == [589, 589]
    assert [m.gain for m in run.calibration.latencies] == pytest.approx([-0.5, -0.5], abs=1e-6)
    assert np.array_equal(run.recording, -0.5 * signal)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((48000, 0.0, 1000.0, 0.01), "f_start_hz = 0.0 is not allowed: must be in (0, 24000] Hz"),
        ((48000, 100.0, 1000.0, 0.0001), "duration_s = 0.0001 is not allowed: must be >= "),
    ],
)
def test_bad_chirp_parameters(args: tuple[float, float, float, float], message: str) -> None:
    with pytest.raises(ConfigError) as err:
        lfm_chirp(*args)
    assert str(err.value).startswith(message)


def test_bad_measurement_parameters() -> None:
    sim = SimulatedDuplex(AudioSettings(samplerate=48000, channels_in=2, blocksize=64))
    with pytest.raises(ConfigError, match=r"^input_channels = \(2,\) is not allowed: must be a"):
        measure_loopback_latency(sim, input_channels=[2])
    with pytest.raises(ConfigError, match=r"^lead_in_frames = -1 is not allowed"):
        measure_loopback_latency(sim, lead_in_frames=-1)
    with pytest.raises(ConfigError, match=r"^received = \(10,\) is not allowed: must be 1-D"):
        matched_filter_delay(np.zeros(10), np.ones(20), 48000)
