"""play_record on the simulated backend: lengths, channel fan-out, bad inputs."""

from __future__ import annotations

import numpy as np
import pytest

from hil.devices.audio import AudioSettings, SimulatedDuplex, play_record
from hil.errors import ConfigError


def _sim(channels_out: int = 1) -> SimulatedDuplex:
    return SimulatedDuplex(
        AudioSettings(samplerate=48000, channels_in=2, channels_out=channels_out, blocksize=64),
        io_delay_samples=64,
    )


def test_one_dimensional_output_goes_to_every_channel() -> None:
    ramp = np.linspace(-1.0, 1.0, 257, dtype=np.float32)
    run = play_record(_sim(channels_out=2), ramp, extra_frames=64)
    assert run.recording.shape == (321, 2) and run.recording.dtype == np.float32
    assert np.array_equal(run.recording[64:, 0], ramp)
    assert np.array_equal(run.recording[64:, 1], ramp)


def test_output_ends_with_silence_during_extra_frames() -> None:
    ones = np.full(100, 0.5, dtype=np.float32)
    run = play_record(_sim(), ones, extra_frames=300)
    assert np.array_equal(np.flatnonzero(run.recording[:, 0]), np.arange(64, 164))


@pytest.mark.parametrize(
    ("output", "message"),
    [
        (np.full(10, 1.5), "output peak = 1.5 is not allowed: must be finite samples within +-1.0"),
        (np.array([0.0, np.nan]), "output peak = nan is not allowed"),
        (
            np.zeros((10, 3)),
            "output shape = (10, 3) is not allowed: must be (frames,) or (frames, 1)",
        ),
        (np.zeros(0), "output shape = (0, 1) is not allowed"),
    ],
)
def test_bad_output_is_refused_before_opening(output: np.ndarray, message: str) -> None:
    sim = _sim()
    with pytest.raises(ConfigError) as err:
        play_record(sim, output)
    assert str(err.value).startswith(message)
    assert sim.frames_processed == 0


def test_negative_extra_frames_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"^extra_frames = -5 is not allowed: must be an integer"):
        play_record(_sim(), np.zeros(10), extra_frames=-5)
