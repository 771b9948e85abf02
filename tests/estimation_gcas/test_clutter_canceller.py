"""The one-code-period clutter canceller in front of GCAS (receiver ``gcas-mti``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.estimation.clutter import ClutterCancelledGcas, PeriodCanceller
from hil.estimation.registry import make_receiver
from hil.signals.presets import check_design, get_preset


def test_a_periodic_input_cancels_after_the_first_period() -> None:
    rng = np.random.default_rng(4)
    period = rng.standard_normal(50)
    y = PeriodCanceller(50).process(np.tile(period, 4))
    assert not np.any(y)  # the first period is blanked, the rest cancels exactly


def test_a_change_passes_as_itself_and_a_flipped_copy_one_period_later() -> None:
    x = np.zeros(300)
    x[120] = 1.0
    y = PeriodCanceller(100).process(x)
    assert y[120] == 1.0 and y[220] == -1.0 and np.count_nonzero(y) == 2


def test_a_gap_blanks_the_next_period() -> None:
    c = PeriodCanceller(10)
    c.process(np.ones(30))
    y = c.process(np.arange(1.0, 16.0), gap_before=3)
    assert y[:10].tolist() == [0.0] * 10 and y[10:].tolist() == [10.0] * 5


@settings(max_examples=30, deadline=None)
@given(cuts=st.lists(st.integers(1, 90), min_size=1, max_size=8))
def test_any_chunking_gives_the_same_output(cuts: list[int]) -> None:
    x = np.random.default_rng(1).standard_normal(400)
    whole = PeriodCanceller(37).process(x)
    c = PeriodCanceller(37)
    parts, k = [], 0
    for n in [*cuts, x.size]:
        parts.append(c.process(x[k : k + n]))
        k += n
        if k >= x.size:
            break
    assert np.array_equal(np.concatenate(parts)[: x.size], whole)


def test_bad_periods_are_refused() -> None:
    with pytest.raises(ConfigError, match=r"period_samples = 0 .*>= 1 sample"):
        PeriodCanceller(0)
    with pytest.raises(ConfigError, match=r"period_samples = 2\.5 .*an integer"):
        PeriodCanceller(2.5)  # type: ignore[arg-type]


def test_the_registry_builds_gcas_behind_the_canceller_with_gcas_options() -> None:
    spec = get_preset("tank-audio").spec("random-cyclic")
    schedule = check_design(spec)
    rx = make_receiver(
        "gcas-mti", schedule, spec.fs_hz, sound_speed_mps=1482.0, max_speed_mps=3.0,
        max_range_m=12.0, m_hops=10, range_readout="first-arrival",
    )  # fmt: skip
    assert isinstance(rx, ClutterCancelledGcas)
    assert rx.canceller.period == round(schedule.period_s * spec.fs_hz)
    assert rx.process(np.zeros(1000)) == [] and rx.samples_seen == 1000
    with pytest.raises(ConfigError, match=r"coherent = 'yes' .*gcas-mti"):
        make_receiver(
            "gcas-mti", schedule, spec.fs_hz, sound_speed_mps=1482.0, max_speed_mps=3.0,
            max_range_m=12.0, m_hops=10, coherent="yes",
        )  # fmt: skip
