"""The still-water background in front of GCAS (receiver ``gcas-still``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.estimation.registry import make_receiver
from hil.estimation.still_copies import CopyVeto
from hil.estimation.still_water import (
    DEFAULT_STILL_PERIODS,
    WARMUP_PERIODS,
    StillWaterBackground,
    StillWaterGcas,
    still_period,
)

from .conftest import FS, C, att_schedule, echo_samples

Q = 17_000  # att's code period at 100 kHz, samples


def test_att_still_water_flips_sign_every_code_period() -> None:
    # Every att hop holds a whole number of cycles and a half: the phase advance per period
    # is π, so the still period is the code period with sign −1.
    schedule = att_schedule()
    assert schedule.period_samples(FS) == Q
    assert still_period(schedule, Q) == (Q, -1)


@pytest.mark.parametrize("sign", [1, -1])
def test_a_still_input_passes_until_the_warmup_then_is_removed_exactly(sign: int) -> None:
    period = np.random.default_rng(4).standard_normal(50)
    x = np.concatenate([period * sign**m for m in range(12)])
    y = StillWaterBackground(50, 8, sign=sign).process(x)
    assert np.array_equal(y[: WARMUP_PERIODS * 50], x[: WARMUP_PERIODS * 50])
    assert np.max(np.abs(y[WARMUP_PERIODS * 50 :])) < 1e-14


def test_a_still_echo_on_att_is_removed_to_numerical_precision() -> None:
    x = echo_samples(att_schedule(), 40.0, 0.0, 1.5)  # a target at rest: still water
    q, sign = still_period(att_schedule(), Q)
    y = StillWaterBackground(q, 8, sign=sign).process(x)
    tail = slice(WARMUP_PERIODS * Q, None)
    # Measured: −207 dB re the echo's power.
    assert np.sum(y[tail] ** 2) < 1e-18 * np.sum(x[tail] ** 2)


def test_white_noise_grows_by_one_over_k_in_power() -> None:
    x = np.random.default_rng(3).standard_normal(40 * 1000)
    for k in (4, 8):
        y = StillWaterBackground(1000, k).process(x)
        ratio = np.var(y[k * 1000 :]) / np.var(x[k * 1000 :])
        assert ratio == pytest.approx(1.0 + 1.0 / k, rel=0.02)  # measured 1.2495, 1.1249


@pytest.mark.parametrize(("speed", "leak_hi"), [(6.0, 0.05), (10.0, 0.06), (25.0, 0.15)])
def test_a_moving_echo_passes_whole_and_leaves_about_one_kth_of_its_power(
    speed: float, leak_hi: float
) -> None:
    # The mean of K = 8 periods holds the echo of its last 8 periods, each 1/8 of it at a phase
    # turned 2·v·Q·f/c cycles further (41 at 6 m/s): measured 0.035, 0.042 and 0.130 of its
    # power at 6, 10 and 25 m/s (1/K = 0.125 on average over speeds); its projection on the
    # echo 1.05, 1.07 and 1.00.
    x = echo_samples(att_schedule(), 40.0, speed, 1.9)
    y = StillWaterBackground(Q, 8, sign=-1).process(x)
    seg = slice(8 * Q, 11 * Q)
    e, out = x[seg], y[seg]
    kept = np.dot(out, e) / np.dot(e, e)
    leak = np.sum((out - e) ** 2) / np.sum(e**2)
    assert 0.95 <= kept <= 1.12
    assert 0.01 <= leak <= leak_hi


def _chunked(x: np.ndarray, cuts: list[int], gaps: list[int], stage: StillWaterBackground) -> list:
    out, k, index = [], 0, 0
    for i, n in enumerate([*cuts, x.size]):
        gap = gaps[i % len(gaps)] if gaps else 0
        part = x[k : k + n]
        out.append(stage.process(part, first_index=index + gap, gap_before=gap))
        index += gap + part.size
        k += n
        if k >= x.size:
            break
    return out


@settings(max_examples=40, deadline=None)
@given(
    cuts=st.lists(st.integers(1, 120), min_size=1, max_size=10),
    k=st.integers(1, 5),
    sign=st.sampled_from([1, -1]),
)
def test_any_chunking_gives_the_same_output_bit_for_bit(cuts: list[int], k: int, sign: int) -> None:
    x = np.random.default_rng(1).standard_normal(500)
    whole = StillWaterBackground(37, k, sign=sign).process(x)
    parts = _chunked(x, cuts, [], StillWaterBackground(37, k, sign=sign))
    assert np.array_equal(np.concatenate(parts)[: x.size], whole)


def test_a_gap_keeps_the_background_and_the_phase_continues() -> None:
    period = np.random.default_rng(5).standard_normal(40)
    stage = StillWaterBackground(40, 4, sign=-1)
    stage.process(np.concatenate([period * (-1) ** m for m in range(6)]))
    # 93 samples go missing: the next block starts at index 333, phase 13 of period 8.
    after = np.concatenate([period * (-1) ** m for m in range(8, 11)])[13:]
    y = stage.process(after, first_index=333, gap_before=93)
    assert np.max(np.abs(y)) < 1e-14
    assert stage.periods_held.tolist() == [4] * 40


def test_bad_still_periods_are_refused_naming_the_option() -> None:
    for bad in (0, 65, 2.5, True, "8"):
        with pytest.raises(ConfigError) as err:
            make_receiver("gcas-still", att_schedule(), FS, sound_speed_mps=C,
                          max_speed_mps=30.0, max_range_m=100.0, m_hops=10,
                          still_periods=bad)  # fmt: skip
        assert err.value.field == "still_periods"
        assert "a whole number of code periods in 1 .. 64" in str(err.value)


def test_the_registry_builds_gcas_still_with_refinement_and_gcas_band() -> None:
    common = {"sound_speed_mps": C, "max_speed_mps": 30.0, "max_range_m": 100.0, "m_hops": 10}
    rx = make_receiver("gcas-still", att_schedule(), FS, **common)
    gcas = make_receiver("gcas", att_schedule(), FS, **common)
    assert isinstance(rx, StillWaterGcas)
    assert rx.still_water.still_periods == DEFAULT_STILL_PERIODS
    assert (rx.still_water.period, rx.still_water.sign) == (Q, -1)
    assert rx.inner.refine is True
    assert rx.inner.reverb_speed_mps == gcas.reverb_speed_mps  # type: ignore[attr-defined]
    other = make_receiver("gcas-still", att_schedule(), FS, **common, still_periods=3)
    assert other.still_water.still_periods == 3 and other.still_water.warmup == 3  # type: ignore[attr-defined]


def _estimate(hop: int, range_m: float, speed: float, snr_db: float) -> Estimate:
    t = 0.01 * (hop + 1)
    return Estimate(t, range_m, speed, hop, 1.0, snr_db, 1.0, t - 0.05, hop % 17, "gcas-still")


def test_a_copy_of_an_earlier_estimate_is_dropped_and_a_target_as_strong_is_not() -> None:
    veto = CopyVeto(17, 0.17, 8, 4, 10)
    # A target closing at 10 m/s from 50 m, 20 dB, every hop for 1.1 s.
    target = [_estimate(h, 50.0 - 0.1 * h, 10.0, 20.0) for h in range(110)]
    assert veto.filter(target) == target
    # At hop 110 (held 6 periods: copies 15.6 dB down) its echo of hop 110 − 2·17 = 76, at
    # that boundary's range: a weak one is the copy, one as strong as the target is not.
    then = 50.0 - 0.1 * 76
    weak = _estimate(110, then + 0.3, 10.0, 6.0)
    strong = _estimate(110, then, 10.0, 19.0)
    # Copies lie 1.7 m apart over the target's last 6 periods (40.7 .. 49.2 m): a weak echo
    # nearer than 39.7 m, or more than 1 m/s off the target's speed, is no copy.
    nearer = _estimate(110, 38.0, 10.0, 6.0)
    slower = _estimate(110, then, 8.5, 6.0)
    assert veto.filter([weak, strong, nearer, slower]) == [strong, nearer, slower]
    assert veto.dropped == 1
    # Copies of boundaries before the first estimate: matched to the first estimates moved
    # back at their speed (hop 120 copies hop 1 at 7 periods: the estimates start at hop 0).
    veto2 = CopyVeto(17, 0.17, 8, 4, 10)
    veto2.filter(target[5:])
    assert veto2.filter([_estimate(120, 50.0 - 0.1, 10.0, 3.0)]) == []
    # A target is never its own copy, however slow, nor a weaker one where it is now.
    veto4 = CopyVeto(17, 0.17, 8, 4, 10)
    slow = [_estimate(h, 50.0 - 0.02 * h, 2.0, 20.0 - 0.1 * (h % 3)) for h in range(200)]
    assert veto4.filter(slow) == slow and veto4.dropped == 0
    # Before the warm-up nothing is subtracted: nothing is a copy.
    veto3 = CopyVeto(17, 0.17, 8, 4, 10)
    veto3.filter(target[:40])
    early = _estimate(57, 50.0 - 0.1 * 40, 10.0, 3.0)  # 0.58 s: 3 periods held
    assert veto3.filter([early]) == [early]
