"""A detection on the ridge of an echo measured lately is refused without a fit where, with
that echo taken out, it reads far below what an echo must collect
(:meth:`hil.estimation.refine.CoherentRefiner.left_beside_known`,
:data:`hil.estimation.gcas.readout.LEFT_MARGIN_DB`): the same estimates to rounding, far
fewer full searches; a weaker echo on the ridge of a stronger one is still reported."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hil.estimation import refine
from hil.estimation.base import Estimate
from hil.estimation.gcas import GcasReceiver, readout
from tests.estimation_gcas.conftest import (
    FS,
    C,
    att_schedule,
    count_calls,
    count_hits,
    echo_samples,
    run_blocks,
)

#: The rule as shipped (math.inf turns it off: no reading is below −inf).
MARGIN_DB = readout.LEFT_MARGIN_DB


def _run(
    x: np.ndarray, monkeypatch: pytest.MonkeyPatch, margin_db: float, m_hops: int = 10
) -> tuple[list[Estimate], int]:
    """The estimates of ``x`` (att, ±30 m/s span, 100 m) with the rule's margin at
    ``margin_db``, and the number of full searches run (fits searched from the detection's
    point)."""
    monkeypatch.setattr(readout, "LEFT_MARGIN_DB", margin_db)
    calls = count_calls(monkeypatch, refine.CoherentRefiner, "_search_from_fewer_hops")
    rx = GcasReceiver.from_options(
        att_schedule(), FS, sound_speed_mps=C, max_speed_mps=30.0, max_range_m=100.0,
        m_hops=m_hops,
    )  # fmt: skip
    return run_blocks(rx, x), calls[0]


@pytest.mark.parametrize(
    ("m_hops", "skipped"),
    [pytest.param(*case, marks=pytest.mark.slow) for case in ((10, 18), (5, 2), (29, 1))],
)
def test_ridge_detections_cost_no_search_and_change_no_estimate(
    m_hops: int, skipped: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # bench_gcas's target: 60 m closing at 12 m/s, 0 dB per-sample SNR; its ridge holds
    # detections half a hop off its boundaries, three Doppler cells of a hop off its speed.
    x = echo_samples(att_schedule(), 60.0, 12.0, 2.0, snr_db=0.0, seed=1)
    without, searches_without = _run(x, monkeypatch, math.inf, m_hops)
    with_rule, searches_with = _run(x, monkeypatch, MARGIN_DB, m_hops)
    assert len(with_rule) == len(without) == count_hits(without, 60.0, 12.0)
    for a, b in zip(with_rule, without, strict=True):
        assert a.hop_index == b.hop_index
        # Not bit for bit: the fits of the refused detections no longer fill the
        # refinement's tables, so a later fit may read a kept table made a few samples
        # off its own window (the same sums to rounding).
        assert a.range_m == pytest.approx(b.range_m, abs=1e-9)
        assert a.speed_mps == pytest.approx(b.speed_mps, abs=1e-9)
        assert a.snr_db == b.snr_db
    # Measured (M = 10, 192 estimates): 27 full searches without the rule, 5 with it; M = 5
    # (197 estimates): 8 and 5; M = 29 (172 estimates): 3 and 2.
    assert searches_without - searches_with >= skipped


@pytest.mark.slow
def test_a_weaker_echo_on_the_ridge_of_a_stronger_one_is_still_reported(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The weaker target (10 dB down) starts half a hop of two-way delay behind the stronger
    # one (3.75 m) and 7.5 m/s faster (three Doppler cells of a hop): its boundaries lie on
    # the stronger echo's ridge, where the rule reads what is left once the stronger echo
    # is taken out.
    sch = att_schedule()
    strong = echo_samples(sch, 60.0, 12.0, 1.5)
    weak = echo_samples(sch, 63.75, 19.5, 1.5, amplitude=0.316)
    noise = np.random.default_rng(5).normal(0.0, np.sqrt(0.5), strong.shape)
    x = strong + weak + noise
    without, searches_without = _run(x, monkeypatch, math.inf)
    with_rule, searches_with = _run(x, monkeypatch, MARGIN_DB)
    weak_without, weak_with = count_hits(without, 63.75, 19.5), count_hits(with_rule, 63.75, 19.5)
    # Measured: 142 of the weak echo's boundaries and 141 of the strong one's either way
    # (150 in 1.5 s, the first M - 1 without a fit), 145 full searches without the rule and
    # 81 with it.
    assert weak_with == weak_without >= 135
    assert count_hits(with_rule, 60.0, 12.0) == count_hits(without, 60.0, 12.0) >= 135
    assert len(with_rule) == len(without)
    assert searches_without - searches_with >= 40  # the rule decided detections here
