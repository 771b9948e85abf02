"""The tank's own echoes' fast paths give the reference values bit for bit: the compiled
transmit phase (sim_devices.acoustics.hop_phase) against HopSchedule.instantaneous_phase, and
the convolver that keeps the response's spectrum
(sim_devices.acoustics.fixed_convolver) against scipy's oaconvolve."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import oaconvolve

from hil.signals.presets import get_preset
from hil.signals.schedule import HopSchedule
from hil.signals.waveforms import build_schedule
from sim_devices.acoustics.fixed_convolver import FixedResponseConvolver
from sim_devices.acoustics.hop_phase import sample_phases

FS = 192_000.0


def chirped() -> HopSchedule:
    """Chirped hops of uneven lengths, a start phase, a period phase and a late start."""
    return HopSchedule.from_segments(
        "demo",
        [50e3, 58e3, 66e3],
        [2, 0, 1, 0],
        [0.004, 0.0075, 0.01, 0.0023],
        chirp_hz_per_s=[4e5, -2e5, 0.0, 1e6],
        start_phase_rad=1.25,
        t0_s=0.0371,
    )


SCHEDULES = {
    "tank-audio": lambda: build_schedule(get_preset("tank-audio").spec("random-cyclic")).shifted(
        64 / FS
    ),
    "chirped": chirped,
}


@pytest.mark.parametrize("name", sorted(SCHEDULES))
@pytest.mark.parametrize("n0", [-3_000_000, -40_000, 0, 1_919, 5_000_000, 1_000_000_000])
def test_sample_phases_are_the_instantaneous_phase_bit_for_bit(name: str, n0: int) -> None:
    schedule = SCHEDULES[name]()
    count = 100_000  # half a second at 192 kHz: many hops, boundaries on samples too
    n = np.arange(n0, n0 + count, dtype=np.int64)
    reference = schedule.instantaneous_phase(n / FS)
    got = sample_phases(schedule, n0, count, FS)
    assert got.tobytes() == reference.tobytes()


def test_sample_phases_of_nothing_is_empty() -> None:
    assert sample_phases(chirped(), 10, 0, FS).shape == (0,)


@pytest.mark.parametrize(
    ("n", "m"),
    [
        (65_536, 32_850),  # a frame of the built-in tank's own echoes: one FFT product
        (32_850, 32_850),  # the priming convolution: equal lengths
        (1_000, 1_900),  # the response longer than the block
        (16_384, 3_000),  # short response: oaconvolve's overlap-add blocks
        (1, 40),
    ],
)
def test_the_convolver_equals_oaconvolve_bit_for_bit_call_after_call(n: int, m: int) -> None:
    rng = np.random.default_rng(n + m)
    h = rng.standard_normal(m)
    conv = FixedResponseConvolver(h)
    for _ in range(3):  # the held spectrum serves the later calls
        x = rng.standard_normal(n)
        assert conv(x).tobytes() == oaconvolve(x, h).tobytes()


def test_the_convolver_refuses_an_empty_response() -> None:
    with pytest.raises(Exception, match="h"):
        FixedResponseConvolver(np.zeros(0))
