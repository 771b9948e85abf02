"""The full matched-filter bank on exact moving-target echoes."""

from __future__ import annotations

import itertools
import math
import re
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.estimation.cost import fft_bank_mults_per_sample, fft_mults
from hil.estimation.crlb import sampled_e_over_n0, schedule_crlb
from hil.estimation.mfbank import MatchedFilterBank
from hil.estimation.registry import make_receiver
from hil.signals.presets import check_design, get_preset
from hil.signals.waveforms import WaveformSpec, build_schedule

FS = 100_000.0
SCH = check_design(get_preset("att").spec("random-cyclic"))
M = 5


@pytest.fixture(scope="module")
def bank() -> MatchedFilterBank:
    return MatchedFilterBank(
        SCH, FS, sound_speed_mps=1500.0, max_speed_mps=12.0, max_range_m=100.0, m_hops=M,
        n_doppler=25,
    )  # fmt: skip


def run(rx: MatchedFilterBank, x: np.ndarray) -> list[Any]:
    rx.reset()
    return rx.process(x) + rx.flush()


@pytest.mark.slow
@pytest.mark.parametrize("speed", [9.3, -6.1])
def test_closing_and_opening_targets_are_recovered(
    bank: MatchedFilterBank, speed: float, kit: Any
) -> None:
    scene = kit.Scene(40.0, speed)
    est = run(bank, kit.echo(SCH, FS, scene, 0.35, snr_db=0.0, seed=3))
    assert len(est) >= 22  # one per hop (≈ 29 hops with a full window), a few may merge
    assert np.all(np.abs(scene.range_errors(est)) < 0.01)
    assert np.all(np.abs(scene.speed_errors(est)) < 0.03)
    hops = [e.hop_index for e in est]
    assert hops == sorted(hops)
    assert all(e.codeword == e.hop_index % SCH.period_hops for e in est)
    for e in est:
        assert e.t_s == pytest.approx(scene.true_t_rx(e.t_tx_s), abs=2e-5)


@pytest.mark.slow
def test_errors_shrink_with_snr_and_reach_the_crlb(bank: MatchedFilterBank, kit: Any) -> None:
    scene = kit.Scene(30.0, 7.7)
    rmse = {}
    for snr in (-9.0, 0.0):
        est = run(bank, kit.echo(SCH, FS, scene, 0.35, snr_db=snr, seed=11))
        rmse[snr] = float(np.sqrt(np.mean(scene.range_errors(est) ** 2)))
    assert rmse[0.0] < 0.6 * rmse[-9.0]
    # CRLB of one codeword (the M-hop window) at the E/N0 it collects at 0 dB per sample.
    sigma = math.sqrt(1.0 / 2.0)
    en0 = sampled_e_over_n0(1.0, sigma, FS, M * SCH.hop_s)
    bound = schedule_crlb(SCH, FS, 0.0, M * SCH.hop_s, 10 * math.log10(en0), 1500.0)
    assert bound.valid
    assert rmse[0.0] < 3.0 * bound.sigma_range_m


@pytest.mark.slow
def test_chunks_equal_whole(kit: Any) -> None:
    sch = check_design(get_preset("att").spec("random-cyclic"))
    rx = MatchedFilterBank(
        sch, FS, sound_speed_mps=1500.0, max_speed_mps=3.0, max_range_m=30.0, m_hops=2,
        n_doppler=3,
    )  # fmt: skip
    x = kit.echo(sch, FS, kit.Scene(12.0, 2.0), 0.12, snr_db=10.0, seed=5)
    whole = run(rx, x)
    assert len(whole) >= 6

    @settings(max_examples=6, deadline=None)
    @given(st.lists(st.integers(1, 12_000), min_size=1, max_size=5))
    def check(cuts: list[int]) -> None:
        rx.reset()
        edges = np.cumsum([0, *cuts])
        out = []
        for a, b in itertools.pairwise(edges):
            out += rx.process(x[a:b])
        out += rx.process(x[edges[-1] :]) + rx.flush()
        assert out == whole
        assert rx.samples_seen == x.shape[0]

    check()


def test_registry_builds_it_and_samples_seen_counts_gaps() -> None:
    rx = make_receiver(
        "mfbank", SCH, FS, sound_speed_mps=1500.0, max_speed_mps=2.0, max_range_m=50.0,
        m_hops=2, n_doppler=1,
    )  # fmt: skip
    assert isinstance(rx, MatchedFilterBank)
    rx.process(np.zeros(100))
    rx.process(np.zeros(50), gap_before=25)
    assert rx.samples_seen == 175


@pytest.mark.parametrize(
    ("kwargs", "text"),
    [
        ({"n_doppler": 0}, "n_doppler = 0 is not allowed: must be an integer in 1 .. 4096"),
        ({"threshold": 1.5}, "threshold = 1.5 is not allowed"),
        ({"max_range_m": 500.0}, "max_range_m = 500.0 is not allowed: must be <= the unambiguous"),
        ({"bogus": 1}, "receiver.options.bogus = 1 is not allowed"),
        ({"max_speed_mps": 2000.0}, "max_speed_mps = 2000.0 is not allowed"),
        ({"fft_workers": 0}, "fft_workers = 0 is not allowed: must be an integer >= 1"),
    ],
)
def test_bad_options(kwargs: dict[str, Any], text: str) -> None:
    opts: dict[str, Any] = {
        "sound_speed_mps": 1500.0,
        "max_speed_mps": 5.0,
        "max_range_m": 50.0,
        "m_hops": 2,
    }
    opts.update(kwargs)
    with pytest.raises(ConfigError, match=re.escape(text)):
        MatchedFilterBank.from_options(SCH, FS, **opts)


def test_bad_blocks() -> None:
    sch = build_schedule(WaveformSpec(family="random-cyclic", hop_s=0.01, code_length=17))
    rx = MatchedFilterBank(
        sch, FS, sound_speed_mps=1500.0, max_speed_mps=1.0, max_range_m=20.0, m_hops=1,
        n_doppler=1,
    )  # fmt: skip
    with pytest.raises(ConfigError, match="block = 'NaN/inf at sample 2' is not allowed"):
        rx.process(np.array([0.0, 1.0, np.nan]))
    with pytest.raises(ConfigError, match=r"block = 'shape \(2, 2\)' is not allowed"):
        rx.process(np.zeros((2, 2)))
    with pytest.raises(ConfigError, match="gap_before = -1 is not allowed"):
        rx.process(np.zeros(3), gap_before=-1)


# Refined estimates of the full-rate bank (FFT bins of the real input, complex128) on a clean
# echo at 40 m closing at 9.3 m/s, M = 5, 25 Doppler hypotheses over ±12 m/s: hop index,
# range (m), speed (m/s). The baseband bank refines from its own grid to the same optimum.
FULL_RATE_GOLDEN = [
    (-1, 39.7534395, 9.300019),
    (5, 39.1988558, 9.299808),
    (11, 38.6442686, 9.299832),
    (17, 38.0898025, 9.299913),
    (23, 37.5353004, 9.30008),
]


@pytest.mark.slow
def test_refined_estimates_match_the_full_rate_bank(bank: MatchedFilterBank, kit: Any) -> None:
    est = run(bank, kit.echo(SCH, FS, kit.Scene(40.0, 9.3), 0.3))
    assert [e.hop_index for e in est] == list(range(-1, 24))
    by_hop = {e.hop_index: e for e in est}
    for hop, range_m, speed_mps in FULL_RATE_GOLDEN:
        assert by_hop[hop].range_m == pytest.approx(range_m, abs=2e-5)
        assert by_hop[hop].speed_mps == pytest.approx(speed_mps, abs=2e-4)
        assert by_hop[hop].score == pytest.approx(1.0, abs=5e-4)


def direct_rho(x: np.ndarray, j: int, m_hops: int, alpha: float, start: int) -> float:
    """Exact normalised correlation of the real input with codeword ``j``'s analytic replica
    at Doppler ``alpha``, replica starting at input sample ``start`` (0 outside the input)."""
    hops = SCH.hops(j - m_hops + 1, m_hops)
    t_end = float(hops.start_s[-1] + hops.duration_s[-1])
    length = int(round((t_end - float(hops.start_s[0])) * FS / alpha))
    if start < 0 or start + length > x.shape[0]:
        return 0.0
    h = SCH.evaluate_analytic(t_end + alpha * (np.arange(length) - length) / FS)
    seg = x[start : start + length]
    return (
        math.sqrt(2.0)
        * abs(np.dot(seg, np.conj(h)))
        / math.sqrt(float(np.vdot(h, h).real) * float(np.dot(seg, seg)))
    )


@pytest.mark.slow
@pytest.mark.parametrize("snr_db", [None, 0.0])
def test_grid_scores_match_direct_correlation(snr_db: float | None, kit: Any) -> None:
    # Unrefined: each estimate is a grid point (lag on the R-sample grid, α on the Doppler
    # grid) and its score the bank's baseband ρ. The exact full-rate correlation there agrees
    # within 0.005 (band-limiting and window-edge sampling), and no grid point within ±3 lags
    # and any Doppler scores higher than it by more than that.
    m_hops = 3
    rx = MatchedFilterBank(
        SCH, FS, sound_speed_mps=1500.0, max_speed_mps=6.0, max_range_m=60.0, m_hops=m_hops,
        n_doppler=7, refine=False,
    )  # fmt: skip
    r = rx.baseband.decimation
    x = kit.echo(SCH, FS, kit.Scene(30.0, 4.1), 0.3, snr_db=snr_db, seed=2)
    est = run(rx, x)
    assert len(est) >= 25
    for e in est:
        assert e.alpha in rx.alphas
        length = int(round(SCH.hop_s * m_hops * FS / e.alpha))
        start = int(round(e.t_s * FS)) - length
        assert start % r == 0
        exact = direct_rho(x, e.codeword, m_hops, e.alpha, start)
        assert e.score == pytest.approx(exact, abs=5e-3)
        around = max(
            direct_rho(x, e.codeword, m_hops, float(a), start + k * r)
            for a in rx.alphas
            for k in range(-3, 4)
        )
        assert around <= exact + 5e-3


def test_chunks_equal_whole_across_a_gap(kit: Any) -> None:
    # A gap restarts the baseband at an index off the R-sample grid; the lag grid stays fixed
    # by absolute sample index, so any cutting of the two segments gives the same estimates.
    rx = MatchedFilterBank(
        SCH, FS, sound_speed_mps=1500.0, max_speed_mps=3.0, max_range_m=30.0, m_hops=2,
        n_doppler=3, refine=False,
    )  # fmt: skip
    x = kit.echo(SCH, FS, kit.Scene(12.0, 2.0), 0.24, snr_db=10.0, seed=7)
    split, gap = 11_003, 997
    assert gap % rx.baseband.decimation != 0
    rx.reset()
    whole = rx.process(x[:split]) + rx.process(x[split + gap :], gap_before=gap) + rx.flush()
    assert len(whole) >= 12
    assert any(e.t_s > (split + gap) / FS for e in whole)

    @settings(max_examples=6, deadline=None)
    @given(st.lists(st.integers(1, 9_000), min_size=1, max_size=6))
    def check(cuts: list[int]) -> None:
        rx.reset()
        cut_at = [c for c in np.cumsum([0, *cuts]).tolist() if c < x.shape[0]]
        kept = [c for c in cut_at if not split < c < split + gap]
        edges = sorted({*kept, split, split + gap, x.shape[0]})
        out = []
        for a, b in itertools.pairwise(edges):
            if a == split:
                continue  # the gap: these samples are not delivered
            out += rx.process(x[a:b], gap_before=gap if a == split + gap else 0)
        out += rx.flush()
        assert out == whole
        assert rx.samples_seen == x.shape[0]

    check()


def test_multiplies_per_sample_are_the_baseband_count() -> None:
    # att, M = 10, D = 64 over ±30 m/s (bench_gcas): R = 11, a 169-tap front end, 4096-sample
    # frames advancing 3151 lags. About 13x fewer than the same bank at the input rate.
    rx = MatchedFilterBank(
        SCH, FS, sound_speed_mps=1500.0, max_speed_mps=30.0, max_range_m=100.0, m_hops=10,
        n_doppler=64, refine=False,
    )  # fmt: skip
    assert rx.baseband.decimation == 11 and rx.baseband.n_taps == 169
    per_frame = fft_mults(4096) + 17 * 64 * (4096 + fft_mults(4096) + 3151)
    assert rx.mults_per_sample == pytest.approx(169 / 11 + per_frame / (3151 * 11), rel=1e-12)
    assert rx.mults_per_sample == pytest.approx(1015.0, abs=0.1)
    assert fft_bank_mults_per_sample(17, 64, 10, 1000) / rx.mults_per_sample > 13.0


def test_a_sample_rate_below_the_stretched_band_is_refused() -> None:
    # att tops out at 31.65 kHz, 32.51 kHz closing at 20 m/s, plus a 400 Hz margin.
    with pytest.raises(
        ConfigError,
        match=re.escape("fs_hz = 60000.0 is not allowed: must be > 2 × 32905.4 Hz"),
    ):
        MatchedFilterBank(
            SCH, 60_000.0, sound_speed_mps=1500.0, max_speed_mps=20.0, max_range_m=50.0,
            m_hops=2, n_doppler=3,
        )  # fmt: skip
