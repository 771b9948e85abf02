"""The still period and its sign on the shipped presets, and every still-water stage built on
it: the one-period canceller (``gcas-mti``, the first-arrival readout's), the empty-tank
background's capture and subtraction. On ``att`` and ``tank-board`` the hops' phase advances by
π over a code period: a still return comes back with the opposite sign, and ``x[n] − x[n −
P]`` doubled it."""

from __future__ import annotations

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.estimation.background import BackgroundSubtractor
from hil.estimation.clutter import PeriodCanceller
from hil.estimation.first_arrival import FirstArrivalReadout
from hil.estimation.still_period import still_period
from hil.estimation.still_water import StillWaterBackground
from hil.experiments.calibration.background import average_periods
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule import HopSchedule

# Each preset's code period (samples) and the sign its still water repeats with.
PRESETS = [("att", -1), ("tank-board", -1), ("tank-audio", 1)]


def _still_water(preset: str, periods: int) -> tuple[np.ndarray, int, float]:
    """Three still returns (delays 1.3, 7.9 and 20.2 ms, levels 1, 0.5, 0.2) of ``preset``'s
    random-cyclic transmit over ``periods`` code periods; the code period (samples) and fs."""
    spec = get_preset(preset).spec("random-cyclic")
    schedule = check_design(spec)
    fs = float(spec.fs_hz)
    p = schedule.period_samples(fs)
    assert p is not None
    t = np.arange(periods * p) / fs
    x = sum(
        a * schedule.evaluate_analytic(t - d).real
        for a, d in ((1.0, 1.3e-3), (0.5, 7.9e-3), (0.2, 20.2e-3))
    )
    return np.asarray(x), p, fs


@pytest.mark.parametrize(("preset", "sign"), PRESETS)
def test_each_preset_s_still_water_repeats_with_its_sign(preset: str, sign: int) -> None:
    x, p, _ = _still_water(preset, 3)
    spec = get_preset(preset).spec("random-cyclic")
    assert still_period(check_design(spec), p) == (p, sign)
    late = x[p : 2 * p]
    assert np.max(np.abs(x[2 * p :] - sign * late)) < 1e-9 * np.max(np.abs(late))


@pytest.mark.parametrize(("preset", "sign"), PRESETS)
def test_the_period_canceller_removes_the_still_water(preset: str, sign: int) -> None:
    x, p, _ = _still_water(preset, 3)
    y = PeriodCanceller(p, sign).process(x)
    assert np.max(np.abs(y[p:])) < 1e-9 * np.max(np.abs(x))
    # With the sign left out, the still water of a π-advancing transmit is doubled.
    if sign < 0:
        doubled = PeriodCanceller(p).process(x)[p:]
        assert np.allclose(doubled, 2.0 * x[p:], atol=1e-9)


@pytest.mark.parametrize(("preset", "sign"), PRESETS)
def test_a_background_captured_and_subtracted_removes_the_still_water(
    preset: str, sign: int
) -> None:
    x, p, _ = _still_water(preset, 5)
    # Captured from receiver sample 123 on (a converter latency), used from sample 0.
    b = average_periods(x[123:], p, first_index=123, sign=sign)
    y = BackgroundSubtractor(b, sign).process(x, first_index=0)
    assert np.max(np.abs(y)) < 1e-9 * np.max(np.abs(x))
    if sign < 0:  # averaged without the sign, the periods cancel: nothing is taken out
        assert np.max(np.abs(average_periods(x[: 4 * p], p))) < 1e-9


@pytest.mark.parametrize(("preset", "sign"), PRESETS)
def test_the_first_arrival_readout_cancels_with_the_sign(preset: str, sign: int) -> None:
    spec = get_preset(preset).spec("random-cyclic")
    readout = FirstArrivalReadout(check_design(spec), float(spec.fs_hz), 10, 1500.0)
    assert readout.sign == sign and readout.period == check_design(spec).period_samples(
        float(spec.fs_hz)
    )


@pytest.mark.parametrize(
    ("make", "field", "says"),
    [
        (lambda: PeriodCanceller(0), "period_samples", ">= 1 sample"),
        (lambda: PeriodCanceller(10.5), "period_samples", "an integer number of samples"),
        (lambda: PeriodCanceller(10, sign=0), "sign", "+1 or -1"),
        (lambda: BackgroundSubtractor(np.zeros(4), sign=2), "sign", "+1 or -1"),
        (lambda: StillWaterBackground(10, sign=-2), "sign", "+1 or -1"),
        (lambda: StillWaterBackground(True), "period_samples", "an integer number of samples"),
    ],
)
def test_every_still_water_stage_refuses_a_bad_period_or_sign_naming_it(
    make: object, field: str, says: str
) -> None:
    with pytest.raises(ConfigError) as err:
        make()  # type: ignore[operator]
    assert err.value.field == field and says in str(err.value)


def test_a_transmit_whose_still_water_never_repeats_is_refused_saying_what_to_use() -> None:
    # 1.2373 cycles a hop: over one to 16 code periods the phase advance is never 0 or π.
    schedule = HopSchedule.from_segments("d", [1000.0, 1237.3], [0, 1], 0.001)
    with pytest.raises(ConfigError) as err:
        still_period(schedule, 20)
    assert err.value.field == "waveform"
    assert "0 or π" in str(err.value) and "use gcas (its reverberation band)" in str(err.value)
