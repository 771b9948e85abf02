"""GCAS two-stage search (``search="two-stage"``): coarse block correlators, exact stage 2."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.estimation.coarse_search import CoarseSearch
from hil.estimation.gcas import GcasReceiver
from hil.estimation.gcas.search_full import FullSearch
from hil.estimation.gcas.search_two_stage import TwoStageSearch
from hil.estimation.unit_correlators import UnitCorrelatorBank
from hil.signals.schedule import HopSchedule

from .conftest import (
    FS,
    LONE_TARGET_R0_M,
    att_schedule,
    echo_samples,
    lone_target_two_stage,
    make_gcas,
    run_blocks,
    true_range,
)


def _receiver(schedule: HopSchedule, search: str, **extra: object) -> GcasReceiver:
    return make_gcas(schedule, search=search, **extra)


_run = run_blocks


def _coarse_reference(
    x: np.ndarray, fs: float, nu: np.ndarray, q: np.ndarray, block: int, m_hops: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stage 1 written out in NumPy: windows of Q_d·B samples at block ends, the group power
    and the comb as a direct sum over M hops of Q_d blocks; returns s, d̂ and the noise floor
    per block."""
    u = UnitCorrelatorBank(fs, nu, q * block).process(x)[block - 1 :: block]  # (nb, D, K)
    g = np.sum(np.abs(u) ** 2, axis=2)  # (nb, D)
    nb, d = g.shape
    acc = np.zeros_like(g)
    for j in range(d):
        for m in range(m_hops):
            lag = m * q[j]
            acc[lag:, j] += g[: nb - lag, j]
    noise = np.median(np.abs(u) ** 2, axis=(1, 2)) / np.log(2.0)
    return acc.max(axis=1), acc.argmax(axis=1), noise


def test_coarse_search_equals_the_written_out_sums() -> None:
    rng = np.random.default_rng(3)
    nu = rng.uniform(-3000.0, 3000.0, (5, 4))
    q = np.array([10, 11, 10, 11, 9])
    x = rng.normal(size=5000) + 1j * rng.normal(size=5000)
    s, d_hat, noise, b0, _ = CoarseSearch(8333.3, nu, q, block=8, m_hops=3, noise_every=4).process(
        x
    )
    ref_s, ref_d, ref_noise = _coarse_reference(x, 8333.3, nu, q, 8, 3)
    assert b0 == 0 and s.shape == (625,)
    np.testing.assert_allclose(s, ref_s, rtol=1e-4)
    assert d_hat.shape == (625,)
    assert np.mean(d_hat == ref_d) > 0.99  # near-ties may differ
    on = np.arange(625) % 4 == 0
    np.testing.assert_allclose(noise[on], ref_noise[on], rtol=1e-4)
    assert np.all(np.isnan(noise[~on]))


@settings(max_examples=10, deadline=None)
@given(st.lists(st.integers(1, 9000), min_size=1, max_size=6), st.integers(0, 7))
def test_coarse_search_chunks_equal_whole(cuts: list[int], start: int) -> None:
    rng = np.random.default_rng(4)
    nu = rng.uniform(-3000.0, 3000.0, (3, 2))
    x = rng.normal(size=9000) + 1j * rng.normal(size=9000)

    def fresh() -> CoarseSearch:
        cs = CoarseSearch(8000.0, nu, [10, 11, 12], block=4, m_hops=5, noise_every=3)
        cs.reset(start)  # a first block that starts before the stream
        return cs

    whole = fresh().process(x)
    cs = fresh()
    edges = sorted({0, x.shape[0], *cuts})
    parts = [cs.process(x[a:b]) for a, b in itertools.pairwise(edges)]
    assert parts[0][3] == whole[3] == start // 4
    for i in (0, 1, 2, 4):
        assert np.array_equal(np.concatenate([p[i] for p in parts]), whole[i], equal_nan=i == 2)


def test_coarse_search_rounds_each_comb_lag() -> None:
    rng = np.random.default_rng(8)
    nu = rng.uniform(-3000.0, 3000.0, (2, 3))
    q = np.array([10, 11])
    cs = CoarseSearch(8000.0, nu, q, block=8, m_hops=5, hop_blocks=[10.5, 10.8])
    assert cs.comb_lags.tolist() == [[0, 10, 21, 32, 42], [0, 11, 22, 32, 43]]
    x = rng.normal(size=4000) + 1j * rng.normal(size=4000)
    s, d_hat, _, _, _ = cs.process(x)
    u = UnitCorrelatorBank(8000.0, nu, q * 8).process(x)[7::8]
    g = np.sum(np.abs(u) ** 2, axis=2)  # (nb, D)
    acc = np.zeros_like(g)
    for d in range(2):
        for lag in cs.comb_lags[d]:
            acc[lag:, d] += g[: g.shape[0] - lag, d]
    np.testing.assert_allclose(s, acc.max(axis=1), rtol=1e-4)  # the reference is complex64
    assert np.mean(d_hat == acc.argmax(axis=1)) > 0.99  # near-ties may differ


def test_coarse_search_rounds_the_lags_of_a_shortlist_chosen_by_the_uniform_comb() -> None:
    rng = np.random.default_rng(9)
    n_hyp = 20
    nu = rng.uniform(-3000.0, 3000.0, (n_hyp, 2))
    q = np.full(n_hyp, 10)
    hop = 9.6 + 0.05 * np.arange(n_hyp)
    cs = CoarseSearch(8000.0, nu, q, block=8, m_hops=6, hop_blocks=hop)
    assert cs.shortlist == 8
    x = rng.normal(size=6000) + 1j * rng.normal(size=6000)
    s, d_hat, _, _, acc_out = cs.process(x)
    g = np.sum(np.abs(UnitCorrelatorBank(8000.0, nu, q * 8).process(x)[7::8]) ** 2, axis=2)
    nb = g.shape[0]
    uniform = np.zeros_like(g)
    rounded = np.zeros_like(g)
    for d in range(n_hyp):
        for m in range(6):
            uniform[m * 10 :, d] += g[: nb - m * 10, d]
            lag = cs.comb_lags[d, m]
            rounded[lag:, d] += g[: nb - lag, d]
    short = np.argsort(-uniform, axis=1, kind="stable")[:, :8]
    picked = np.take_along_axis(rounded, short, axis=1)
    np.testing.assert_allclose(s, picked.max(axis=1), rtol=1e-4)  # the reference is complex64
    ref_d = np.take_along_axis(short, picked.argmax(axis=1)[:, None], axis=1)[:, 0]
    assert np.mean(d_hat == ref_d) > 0.99  # near-ties may differ
    # Every hypothesis's comb on the shortlist, −inf off it.
    listed = np.isfinite(acc_out)
    assert np.all(listed.sum(axis=1) == 8)
    np.testing.assert_allclose(acc_out[listed], rounded[listed], rtol=1e-4)
    assert np.array_equal(np.max(acc_out, axis=1), s)
    # The shortlist matters here: on some blocks the best rounded comb lies outside it.
    assert np.count_nonzero(rounded.max(axis=1) > picked.max(axis=1) * (1 + 1e-3)) >= 2


def test_coarse_search_counts_samples_before_the_start_as_zero() -> None:
    nu = np.array([[100.0]])
    x = np.exp(2j * np.pi * 100.0 * np.arange(6, 40) / 1000.0)  # samples 6..39
    cs = CoarseSearch(1000.0, nu, [3], block=4, m_hops=1)
    cs.reset(6)
    s, _, _, b0, _ = cs.process(x)
    # Block 1 holds samples 4..7 of which 6 and 7 arrived: |v|² = 2²; then 6², 10², 12².
    assert b0 == 1 and np.round(s[:4], 6).tolist() == [4.0, 36.0, 100.0, 144.0]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"block": 0}, r"block = 0 .*integer >= 1"),
        ({"m_hops": 0}, r"m_hops = 0 .*integer >= 1"),
        ({"noise_every": 0}, r"noise_every = 0 .*integer >= 1"),
        ({"cell_weights": np.ones((2, 1))}, r"cell_weights = 'shape \(2, 1\)' .*shape \(1, 1\)"),
        ({"hyp_weights": [-1.0]}, r"hyp_weights\[0\] = -1\.0 .*finite weights >= 0 of shape"),
        ({"hop_blocks": [0.5]}, r"hop_blocks = \[0\.5\] .*1 finite lengths >= 1 block"),
    ],
)
def test_coarse_search_rejects_bad_settings(kwargs: dict[str, object], message: str) -> None:
    settings_ = {"block": 4, "m_hops": 2, **kwargs}
    with pytest.raises(ConfigError, match=message):
        CoarseSearch(1000.0, [[100.0]], [3], **settings_)  # type: ignore[arg-type]


def test_exact_stage_two_correlators_equal_the_full_bank(rc_schedule: HopSchedule) -> None:
    x = echo_samples(rc_schedule, 50.0, 10.0, 0.7, snr_db=0.0, seed=13)
    # Raw correlators: no reverberation band (it weights the cells).
    full = _receiver(rc_schedule, "full", coherent=True, reverb_speed_mps=0.0)
    two = _receiver(rc_schedule, "two-stage", reverb_speed_mps=0.0)
    full.process(x)
    two.process(x)
    assert isinstance(full.strategy, FullSearch) and isinstance(two.strategy, TwoStageSearch)
    u_ring = full.strategy._u_ring
    stop = u_ring.next_index
    first = np.array([stop - 900, stop - 500, stop - 40])
    dd = np.array([3, 31, 60])
    got = two.strategy.exact.windows(first, dd, 30)  # (3, 30, K)
    ref = np.stack(
        [
            u_ring.array[u_ring.position(f + np.arange(30)), d]
            for f, d in zip(first, dd, strict=True)
        ]
    )
    assert np.max(np.abs(got - ref)) < 2e-4 * np.max(np.abs(ref))


@pytest.mark.parametrize("speed", [12.0, -8.0, 25.0])
def test_two_stage_estimates_match_the_full_search(rc_schedule: HopSchedule, speed: float) -> None:
    r0 = LONE_TARGET_R0_M
    # A lone target in noise, test_high_snr_tracks_range_speed_and_codeword's (its two-stage
    # run shared with that test): no band.
    x, two_stage = lone_target_two_stage(speed)
    full = _run(_receiver(rc_schedule, "full", reverb_speed_mps=0.0), x)
    two = list(two_stage)
    assert len(two) >= 50 and abs(len(two) - len(full)) <= 1
    dr = np.array([e.range_m - true_range(r0, speed, e.t_tx_s, e.t_s) for e in two])
    dv = np.array([e.speed_mps - speed for e in two])
    assert np.sqrt(np.mean(dr**2)) < 0.03 and np.sqrt(np.mean(dv**2)) < 0.15
    assert np.all(np.diff([e.hop_index for e in two]) == 1)
    # Same hops, same times to well within a sample (stage 2 evaluates the same sums).
    by_hop = {e.hop_index: e for e in full}
    common = [e for e in two if e.hop_index in by_hop]
    assert len(common) >= len(two) - 1
    assert max(abs(e.t_s - by_hop[e.hop_index].t_s) for e in common) < 0.2 / (FS / 12)


def test_two_stage_coherent_refines_like_the_full_search(rc_schedule: HopSchedule) -> None:
    r0, v = 45.0, 15.0
    x = echo_samples(rc_schedule, r0, v, 0.7, snr_db=0.0, seed=12)
    full = _run(_receiver(rc_schedule, "full", coherent=True), x)
    two = _run(_receiver(rc_schedule, "two-stage", coherent=True), x)
    assert len(two) >= 55
    dr = np.array([e.range_m - true_range(r0, v, e.t_tx_s, e.t_s) for e in two])
    dr_full = np.array([e.range_m - true_range(r0, v, e.t_tx_s, e.t_s) for e in full])
    assert np.sqrt(np.mean(dr**2)) < 1.2 * np.sqrt(np.mean(dr_full**2)) + 1e-4
    assert np.sqrt(np.mean(np.array([e.speed_mps - v for e in two]) ** 2)) < 0.05


@pytest.mark.slow
@settings(max_examples=5, deadline=None)
@given(st.lists(st.integers(1, 40_000), min_size=1, max_size=5))
def test_two_stage_chunks_equal_whole(cuts: list[int]) -> None:
    schedule = att_schedule()
    x = echo_samples(schedule, 30.0, -10.0, 0.4, snr_db=-10.0, seed=2)
    whole = _run(_receiver(schedule, "two-stage"), x, block=x.shape[0])
    rx = _receiver(schedule, "two-stage")
    edges = sorted({0, x.shape[0], *(c % x.shape[0] for c in cuts)})
    parts: list[Estimate] = []
    for a, b in itertools.pairwise(edges):
        parts += rx.process(x[a:b])
    parts += rx.flush()
    assert parts == whole and len(whole) > 10


@pytest.mark.slow
@settings(max_examples=8, deadline=None)
@given(st.lists(st.integers(1, 3_000), min_size=20, max_size=60), st.integers(0, 3))
def test_nothing_comes_out_before_the_next_decision_index(sizes: list[int], seed: int) -> None:
    # Mostly noise with a lax threshold, so false alarms come out at random places (seed 3:
    # a strong target at the default threshold); the detector's own decisions (refinement
    # off: it refuses the noise detections this test needs).
    schedule = att_schedule()
    x = echo_samples(schedule, 30.0, -10.0, 0.4, snr_db=0.0 if seed == 3 else -30.0, seed=seed)
    extra: dict[str, object] = {"refine": False} if seed == 3 else {"pfa": 0.5, "refine": False}
    rx = _receiver(schedule, "two-stage", **extra)
    i, out = 0, []
    for n in itertools.cycle(sizes):
        if i >= x.shape[0]:
            break
        bound = rx.next_decision_index
        assert bound >= rx.samples_seen
        new = rx.process(x[i : i + n])
        i += n
        if rx.samples_seen < bound:
            assert new == [], f"estimate before the decision index {bound} (fed {rx.samples_seen})"
        out += new
    whole = _run(_receiver(schedule, "two-stage", **extra), x, block=x.shape[0])
    assert out + rx.flush() == whole and len(whole) >= 3


@pytest.mark.slow
def test_feeding_up_to_the_next_decision_index_gives_every_estimate_in_few_calls(
    rc_schedule: HopSchedule,
) -> None:
    x = echo_samples(rc_schedule, 60.0, 12.0, 0.8, snr_db=0.0, seed=1)
    whole = _run(_receiver(rc_schedule, "two-stage"), x, block=x.shape[0])
    rx = _receiver(rc_schedule, "two-stage")
    out: list[Estimate] = []
    calls = 0
    emitted_at: list[int] = []
    while rx.samples_seen < x.shape[0]:
        stop = min(max(rx.next_decision_index, rx.samples_seen + 1), x.shape[0])
        new = rx.process(x[rx.samples_seen : stop])
        calls += 1
        emitted_at += [rx.samples_seen] * len(new)
        out += new
    assert out + rx.flush() == whole and len(whole) >= 50
    # Each estimate came out the moment its bound was reached (no later than a 1-sample
    # feed would give it), and the calls are a few per hop (one per candidate cell of stage
    # 1: the echo's boundary, its Doppler sidelobes and its ghosts one tone spacing away,
    # which stage 2 and the refinement refuse), not one per sample block.
    hops = x.shape[0] / (rc_schedule.hop_s * FS)
    assert calls <= 6 * hops + 20
    one = _receiver(rc_schedule, "two-stage")
    first_seen: list[int] = []
    for k in range(0, x.shape[0], 25):
        first_seen += [k + 25] * len(one.process(x[k : k + 25]))
    assert len(first_seen) == len(emitted_at)
    assert all(a <= b for a, b in zip(emitted_at, first_seen, strict=True))


def test_full_search_gives_no_decision_bound(rc_schedule: HopSchedule) -> None:
    rx = _receiver(rc_schedule, "full")
    rx.process(np.zeros(12_345))
    assert rx.next_decision_index == rx.samples_seen == 12_345


def test_two_stage_gap_restarts_cleanly(rc_schedule: HopSchedule) -> None:
    r0, v = 50.0, 10.0
    x = echo_samples(rc_schedule, r0, v, 1.0, snr_db=0.0, seed=5)
    rx = _receiver(rc_schedule, "two-stage")
    first = rx.process(x[:40_000])
    second = rx.process(x[60_000:], gap_before=20_000) + rx.flush()
    assert all(e.t_s < 0.4 for e in first)
    assert second and all(e.t_s > 0.6 for e in second)
    dr = np.array([e.range_m - true_range(r0, v, e.t_tx_s, e.t_s) for e in second])
    assert np.max(np.abs(dr)) < 0.1
    assert np.all(np.diff([e.hop_index for e in second]) == 1)


def test_unknown_search_is_refused(rc_schedule: HopSchedule) -> None:
    with pytest.raises(ConfigError, match=r"search = 'exhaustive' .*one of full, two-stage"):
        _receiver(rc_schedule, "exhaustive")


@pytest.mark.parametrize("step", [0, 30])
def test_coarse_step_out_of_range_is_refused(rc_schedule: HopSchedule, step: int) -> None:
    with pytest.raises(ConfigError, match=rf"coarse_step = {step} .*an integer in 1\.\.20"):
        _receiver(rc_schedule, "two-stage", coarse_step=step)


_SIGNATURES_SCRIPT = """
import json
import numpy as np
from hil.estimation import kernels
from tests.estimation_gcas.conftest import att_schedule, echo_samples
from tests.estimation_gcas.test_gcas_two_stage import _receiver

def counts():
    return {{k: len(f.signatures) for k, f in vars(kernels).items() if hasattr(f, "signatures")}}

schedule = att_schedule("random-cyclic")
rx = _receiver(schedule, "two-stage")
maps = []
if {with_map}:
    rx.on_map = lambda t_s, p, speed: maps.append(p.shape)
before = counts()
x = echo_samples(schedule, 60.0, 12.0, 0.4, snr_db=0.0, seed=2)
n = sum(len(rx.process(x[i : i + 1000])) for i in range(0, x.shape[0], 1000))
print(json.dumps({{"before": before, "after": counts(), "estimates": n, "maps": len(maps)}}))
"""


@pytest.mark.slow
@pytest.mark.parametrize("with_map", [False, True])
def test_two_stage_loads_no_compiled_kernel_once_built(with_map: bool) -> None:
    # Loading a kernel specialisation takes ~10 ms (compiling one, seconds): in a live run
    # that lands inside one block. A fresh interpreter shows what the first stream adds.
    # The time–codeword map (the tank run's report) reads exact windows even when
    # noncoherent, so the warm-up covers them too (a first call compiles for about 0.2 s).
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    done = subprocess.run(
        [sys.executable, "-c", _SIGNATURES_SCRIPT.format(with_map=with_map)],
        capture_output=True, text=True, cwd=root, timeout=300, check=True,
    )  # fmt: skip
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["estimates"] >= 20
    assert (result["maps"] > 0) == with_map
    assert result["after"] == result["before"]
    assert set(result["before"]) >= {"codeword_sums", "coarse_search", "fir_decimate"}


def _with_reference_fine_stage(rx: GcasReceiver) -> GcasReceiver:
    """``rx`` deciding its candidates with the NumPy formulation of stage 2."""
    assert isinstance(rx.strategy, TwoStageSearch)
    rx.strategy._fine_stage = rx.strategy._fine_stage_reference  # type: ignore[method-assign]
    return rx


def test_compiled_stage_two_equals_the_numpy_reference_for_two_echoes_of_one_speed() -> None:
    # Two echoes at 12 m/s exactly one hop of delay apart: every boundary of one arrives with
    # a boundary of the other, their codewords tie at the peak, and the runner-up test reads
    # the third codeword there (the refinement on: it tells the pair's fits apart).
    schedule = att_schedule()
    x = echo_samples(schedule, 40.0, 12.0, 0.8, snr_db=0.0, seed=11)
    x = x + echo_samples(schedule, 47.5, 12.0, 0.8)
    got = _run(_receiver(schedule, "two-stage"), x, 3_000)
    want = _run(_with_reference_fine_stage(_receiver(schedule, "two-stage")), x, 3_000)
    assert repr(got) == repr(want)  # every field, bit for bit
    off = [min(abs(e.range_m - true_range(r, 12.0, e.t_tx_s, e.t_s)) for r in (40.0, 47.5))
           for e in got]  # fmt: skip
    # Measured: 140 estimates, 70 of each target, every one within 0.005 m (reading the
    # runner-up alone: 15, 14 of one and 1 of the other).
    assert len(got) >= 120 and max(off) < 0.05


@pytest.mark.parametrize(
    ("family", "extra", "snr_db", "speed", "quiet_s", "at_least"),
    [
        ("random-cyclic", {}, -15.0, 12.0, 0.0, 20),
        ("random-cyclic", {}, -24.0, -7.0, 0.0, 3),  # weak: threshold and runner-up rejections
        # The trailing-window statistic CFAR needs target-free history to detect at all.
        # (3 m/s is at the default band's edge: no band.)
        ("random-cyclic", {"cfar_mode": "statistic", "reverb_speed_mps": 0.0}, -12.0, 3.0, 1.0, 5),
        ("three-state", {}, -12.0, 20.0, 0.0, 20),
        # Calls whose every candidate passes the threshold and fails the runner-up test.
        ("random-cyclic", {"runner_up_ratio": 1.5}, -15.0, 12.0, 0.0, 1),
    ],
)
def test_compiled_stage_two_equals_the_numpy_reference(
    family: str,
    extra: dict[str, object],
    snr_db: float,
    speed: float,
    quiet_s: float,
    at_least: int,
) -> None:
    schedule = att_schedule(family)
    x = echo_samples(schedule, 40.0, speed, quiet_s + 0.8, snr_db=snr_db, seed=11)
    x = x + echo_samples(schedule, 70.0, -speed / 2, quiet_s + 0.8, amplitude=0.5)
    quiet = int(quiet_s * FS)
    x[:quiet] = np.random.default_rng(3).normal(0.0, np.std(x[quiet:]), quiet)
    # The detector's stage 2 (refinement off: it measures after either formulation).
    extra = {**extra, "refine": False}
    got = _run(_receiver(schedule, "two-stage", **extra), x, 3_000)
    want = _run(_with_reference_fine_stage(_receiver(schedule, "two-stage", **extra)), x, 3_000)
    assert len(got) >= at_least
    assert repr(got) == repr(want)  # every field, bit for bit
