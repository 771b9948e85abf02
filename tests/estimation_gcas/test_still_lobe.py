"""The lobe decision beside still water (hil.estimation.still_lobe and
CoherentRefiner.still_free_evidence): the canceller's streams, chunks against the whole, and
the two-term model's evidence, which still water leaves exactly as it is."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import hil.estimation.refine as refine_module
from hil.estimation.refine import STILL_LOBES, CoherentRefiner
from hil.estimation.still_lobe import StillStreams, still_free_powers

from .conftest import FS, C, att_schedule, echo_samples


def test_the_streams_are_the_canceller_and_the_still_sum_and_chunks_equal_the_whole() -> None:
    x = np.arange(1.0, 9.0)  # 1 .. 8
    whole = StillStreams(3, -1, 16)
    y = whole.push(x, 0)
    # x[n - 3] is 0 before the start: y = x + x[n - 3] (σ = −1).
    assert y.tolist() == [1.0, 2.0, 3.0, 5.0, 7.0, 9.0, 11.0, 13.0]
    chunked = StillStreams(3, -1, 16)
    # Chunks shorter than the still period and longer than it.
    parts = [chunked.push(x[a:b], a) for a, b in ((0, 2), (2, 7), (7, 8))]
    assert np.array_equal(np.concatenate(parts), y)
    # Over samples 3 .. 7: Σy² = 445, w = x − x[n − 3] = 3 each, Σw² = 45.
    assert whole.powers(3, 8) == chunked.powers(3, 8) == ((45.0 - 445.0) / 20.0, 445.0 / 10.0)
    assert whole.powers(2, 8) == (0.0, 0.0)  # sample 2 has nothing a still period before it
    whole.reset(100)
    assert whole.valid_from == 103 and whole.powers(100, 100) == (0.0, 0.0)


def test_random_chunks_give_the_whole_s_streams_and_powers() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=5000)
    cuts = [0, *sorted(rng.choice(np.arange(1, 5000), 25, replace=False).tolist()), 5000]
    whole, chunked = StillStreams(170, 1, 6000), StillStreams(170, 1, 6000)
    y = whole.push(x, 0)
    parts = [chunked.push(x[a:b], a) for a, b in itertools.pairwise(cuts)]
    assert np.array_equal(np.concatenate(parts), y)
    assert np.array_equal(y[170:], x[170:] - x[:-170])
    for first, stop in ((170, 5000), (1000, 1234), (4000, 5000)):
        assert whole.powers(first, stop) == chunked.powers(first, stop)


def test_still_water_is_taken_out_exactly_and_measured_as_still_power() -> None:
    rng = np.random.default_rng(7)
    period = rng.normal(size=5)
    x = np.concatenate([period, -period, period, -period])  # σ = −1 every 5 samples
    streams = StillStreams(5, -1, 32)
    y = streams.push(x, 0)
    assert np.all(y[5:] == 0.0)
    s_pow, rest = streams.powers(5, 20)
    assert s_pow == pytest.approx(float(np.mean(x[5:] ** 2)), rel=1e-12) and rest == 0.0


def test_the_two_term_model_is_the_difference_of_its_terms() -> None:
    assert still_free_powers(np.array([1 + 1j, 2.0]), np.array([1j, -1.0])).tolist() == [1.0, 9.0]


def _boundary(schedule, hop: int, range_m: float, speed_mps: float) -> tuple[float, float]:
    """Receive time (s) and time scale of the boundary ending ``hop`` of a target at
    ``range_m`` (t = 0) closing at ``speed_mps``: ``c (t − T) = 2 R((T + t)/2)``."""
    t_tx = float(schedule.hops(hop + 1, 1).start_s[0])
    t_rx = ((C - speed_mps) * t_tx + 2.0 * range_m) / (C + speed_mps)
    return t_rx, (C + speed_mps) / (C - speed_mps)


def test_the_evidence_peaks_on_the_echo_s_lobe_and_still_water_leaves_it_unchanged() -> None:
    schedule = att_schedule()
    hop = 60  # both windows of M hops a still period after the still echo's first sample
    echo = echo_samples(schedule, 60.0, -6.0, 0.8)
    # Still water 10 dB above the echo, two grating lobes nearer (0.68 m a lobe).
    still = echo_samples(schedule, 58.6, 0.0, 0.8, amplitude=10**0.5)
    t_b, alpha = _boundary(schedule, hop, 60.0, -6.0)
    evidence, fits = [], []
    for x in (echo, echo + still):
        refiner = CoherentRefiner(schedule, FS, 10, C, 0.75, 30.0)
        refiner.reset(0)
        refiner.push(x, 0)
        fits.append(refiner.refine(t_b, alpha, hop))
        # Both read at the echo-alone fit's point.
        assert fits[0] is not None
        evidence.append(refiner.still_free_evidence(fits[0].t_s, fits[0].alpha, hop))
    assert fits[0] is not None and abs(fits[0].t_s - t_b) < 2e-5  # its lobe: 0.9 ms
    alone, beside = evidence
    assert alone is not None and beside is not None
    # The neighbouring lobes keep ρ² of the echo's lobe (ρ = 1 − 1/(α Δf D) = 0.91 on att),
    # the next ones about (1 − 2(1 − ρ))².
    np.testing.assert_allclose(
        alone / alone[STILL_LOBES], [0.6745, 0.8278, 1.0, 0.8279, 0.6746], atol=2e-4
    )
    # The still water goes with the canceller: the evidence is the echo's alone.
    np.testing.assert_allclose(beside, alone, rtol=1e-9)


@pytest.mark.parametrize("still_m", [58.6, 60.34])
def test_a_fit_pulled_a_lobe_off_by_still_water_is_returned_to_its_echo_s_lobe(
    still_m: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    # An echo at −10 dB per-sample SNR (seeded noise) and one still scatterer 10 dB above it,
    # 1.4 m nearer or 0.34 m farther: the fit on the input alone lands a grating lobe off
    # (measured −907 and −876 µs, a lobe 0.91 ms); judged on the input without its still
    # water it is fitted on the echo's lobe (7 and 36 µs off: the still water's pull within
    # the lobe).
    schedule = att_schedule()
    hop = 60
    echo = echo_samples(schedule, 60.0, -6.0, 0.8)
    still = echo_samples(schedule, still_m, 0.0, 0.8, amplitude=10**0.5)
    noise = np.random.default_rng(1).normal(0.0, 10**0.5 / np.sqrt(2.0), echo.shape)
    t_b, alpha = _boundary(schedule, hop, 60.0, -6.0)
    errors, lobe = {}, 0.0
    for judged in (False, True):
        if not judged:
            monkeypatch.setattr(refine_module, "STILL_OVER_REST", np.inf)
        else:
            monkeypatch.undo()
        refiner = CoherentRefiner(schedule, FS, 10, C, 0.75, 30.0)
        refiner.reset(0)
        refiner.push(echo + still + noise, 0)
        fit = refiner.refine(t_b, alpha, hop)
        assert fit is not None and fit.found
        errors[judged], lobe = fit.t_s - t_b, 1.0 / (alpha * refiner.spacing_hz)
    assert abs(errors[False]) > 0.9 * lobe
    assert abs(errors[True]) < 0.05 * lobe
