"""The schedule check tells the recording's own schedule from one of another seed, at any
delay and speed in range, down to a low in-band SNR."""

from __future__ import annotations

import numpy as np
import pytest

from hil.signals.presets import check_design, get_preset
from hil.signals.schedule_match import match_schedule
from hil.signals.synthesis import BlockSynthesizer

FS = 100_000.0


def _schedule(seed: int):  # type: ignore[no-untyped-def]
    return check_design(get_preset("att").spec("random-cyclic", seed=seed))


def _received(seed: int, delay_s: float, speed_mps: float, snr_db: float) -> np.ndarray:
    """2 s of the att waveform, delayed and Doppler-scaled, in white noise (seeded)."""
    schedule = _schedule(seed)
    n = int(2.0 * FS)
    alpha = 1.0 + 2.0 * speed_mps / 1500.0
    t = np.arange(n) / FS
    synth = BlockSynthesizer(schedule, FS, amplitude=0.5)
    clean = synth.render(0, n + int(FS * 0.3), np.float64)
    x = np.interp(alpha * t - delay_s, np.arange(clean.size) / FS, clean, left=0.0)
    rng = np.random.default_rng(seed)
    noise = rng.normal(0.0, np.sqrt(np.mean(x**2) / 10 ** (snr_db / 10)), n)
    return np.asarray(x + noise)


@pytest.mark.parametrize(
    ("delay_s", "speed_mps", "snr_db"),
    [(0.0, 0.0, 10.0), (0.0537, -12.0, 0.0), (0.11, 20.0, -15.0)],
)
def test_own_schedule_matches_and_another_seed_does_not(
    delay_s: float, speed_mps: float, snr_db: float
) -> None:
    x = _received(1, delay_s, speed_mps, snr_db)
    own = match_schedule(x, FS, _schedule(1), sound_speed_mps=1500.0, max_speed_mps=25.0)
    assert own is not None and own.matched, own
    assert own.chance == 0.25 and own.n_hops == 195  # 2 s less the largest stretch
    for seed in (2, 3, 4):
        other = match_schedule(x, FS, _schedule(seed), sound_speed_mps=1500.0, max_speed_mps=25.0)
        assert other is not None and not other.matched, (seed, other)


def test_too_short_or_not_tone_hopping_gives_no_verdict() -> None:
    x = _received(1, 0.0, 0.0, 10.0)
    assert match_schedule(x[:3000], FS, _schedule(1), sound_speed_mps=1500.0,
                          max_speed_mps=25.0) is None  # fmt: skip
    fmcw = check_design(get_preset("att").spec("fmcw-saw"))
    assert match_schedule(x, FS, fmcw, sound_speed_mps=1500.0, max_speed_mps=25.0) is None
