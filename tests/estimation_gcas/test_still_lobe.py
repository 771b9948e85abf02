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
    whole.push(x, 0)
    y = whole.canceller(0, 8)
    # x[n - 3] is 0 before the start: y = x + x[n - 3] (σ = −1).
    assert y.tolist() == [1.0, 2.0, 3.0, 5.0, 7.0, 9.0, 11.0, 13.0]
    chunked = StillStreams(3, -1, 16)
    # Chunks shorter than the still period and longer than it, y read after each.
    parts = []
    for a, b in ((0, 2), (2, 7), (7, 8)):
        chunked.push(x[a:b], a)
        parts.append(chunked.canceller(a, b))
    assert np.array_equal(np.concatenate(parts), y)
    # Over samples 3 .. 7: Σy² = 445, w = x − x[n − 3] = 3 each, Σw² = 45.
    assert whole.powers(3, 8) == chunked.powers(3, 8) == ((45.0 - 445.0) / 20.0, 445.0 / 10.0)
    assert whole.powers(2, 8) == (0.0, 0.0)  # sample 2 has nothing a still period before it
    whole.reset(100)
    assert whole.valid_from == 103 and whole.powers(100, 100) == (0.0, 0.0)


def test_y_is_read_within_what_is_kept_only() -> None:
    streams = StillStreams(3, 1, 5)
    for a in range(0, 10_000, 1000):  # samples 0 .. 9999, x[n] = n + 1
        streams.push(np.arange(a + 1.0, a + 1001.0), a)
    assert streams.canceller(9995, 10_000).tolist() == [3.0] * 5
    assert streams.powers(9995, 10_000) == (
        float(np.dot(np.arange(9996.0, 10_001.0), np.arange(9993.0, 9998.0))) / 5,
        4.5,
    )
    for first, stop in ((0, 10), (9995, 10_001)):
        with pytest.raises(IndexError, match=r"of y: kept are \d+\.\.9999 \(at least the last 5\)"):
            streams.canceller(first, stop)
        assert streams.powers(first, stop) == (0.0, 0.0)


def test_random_chunks_give_the_whole_s_streams_and_powers() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=5000)
    cuts = [0, *sorted(rng.choice(np.arange(1, 5000), 25, replace=False).tolist()), 5000]
    whole, chunked = StillStreams(170, 1, 6000), StillStreams(170, 1, 6000)
    whole.push(x, 0)
    y = whole.canceller(0, 5000)
    parts = []
    for a, b in itertools.pairwise(cuts):
        chunked.push(x[a:b], a)
        parts.append(chunked.canceller(a, b))
    assert np.array_equal(np.concatenate(parts), y)
    assert np.array_equal(y[170:], x[170:] - x[:-170])
    for first, stop in ((170, 5000), (1000, 1234), (4000, 5000)):
        s_pow, rest = whole.powers(first, stop)
        assert (s_pow, rest) == chunked.powers(first, stop)
        # S = (Σw² − Σy²)/(4n), N = Σy²/(2n) (w the still sum).
        w = x[first:stop] + x[first - 170 : stop - 170]
        e_y, n = float(np.sum(y[first:stop] ** 2)), stop - first
        assert s_pow == pytest.approx((float(np.sum(w**2)) - e_y) / (4 * n), rel=1e-9)
        assert rest == pytest.approx(e_y / (2 * n), rel=1e-12)


def test_still_water_is_taken_out_exactly_and_measured_as_still_power() -> None:
    rng = np.random.default_rng(7)
    period = rng.normal(size=5)
    x = np.concatenate([period, -period, period, -period])  # σ = −1 every 5 samples
    streams = StillStreams(5, -1, 32)
    streams.push(x, 0)
    assert np.all(streams.canceller(5, 20) == 0.0)
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


def test_the_evidence_is_the_same_however_the_input_was_pushed_and_read() -> None:
    # y is made only when the evidence is read (the samples pushed since the last read, or
    # the still refiner's whole history after a longer gap): pushed at once, in chunks read
    # after each, or read early and then after more than that history, it is the same.
    schedule = att_schedule()
    hop = 150
    x = echo_samples(schedule, 60.0, -6.0, 1.7, snr_db=0.0, seed=2)
    x = x + echo_samples(schedule, 58.6, 0.0, 1.7, amplitude=10**0.5)
    t_b, alpha = _boundary(schedule, hop, 60.0, -6.0)

    def made() -> CoherentRefiner:
        refiner = CoherentRefiner(schedule, FS, 10, C, 0.75, 30.0)
        refiner.reset(0)
        return refiner

    whole = made()
    whole.push(x, 0)
    expected = whole.still_free_evidence(t_b, alpha, hop)
    assert expected is not None and np.all(expected > 0)
    chunked = made()
    cuts = [0, *sorted(np.random.default_rng(4).choice(x.size, 12, replace=False)), x.size]
    for a, b in itertools.pairwise(cuts):
        chunked.push(x[a:b], a)
        chunked.still_free_evidence(t_b, alpha, hop)
    gap = made()
    gap.push(x[:20_000], 0)
    assert gap.still_free_evidence(0.15, alpha, 10) is None  # not covered yet
    gap.push(x[20_000:], 20_000)
    assert gap._still_fits is not None and x.size - 20_000 > gap._still_fits.history
    for refiner in (chunked, gap):
        assert np.array_equal(refiner.still_free_evidence(t_b, alpha, hop), expected)
