"""The chapter-6 trials on tiny settings: expected keys, sane values, scoring, bad input."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.evaluation.registry import TRIALS, load_trial
from hil.evaluation.trials_ch6 import (
    ch6_cost_trial,
    ch6_fmcw_trial,
    ch6_receiver_trial,
    noise_sigma,
    score_estimates,
    validate_fmcw_params,
    validate_receiver_params,
)

TINY: dict[str, Any] = {"duration_s": 0.45, "warmup_s": 0.15}
SCORE_KEYS = {
    "n_truth", "n_detected", "n_estimates", "n_false", "pd", "false_per_s", "range_rmse_m",
    "range_bias_m", "speed_rmse_mps", "speed_bias_mps", "range_sse_m2", "range_rmse_all_m",
    "crlb_range_m", "crlb_speed_mps", "e_over_n0_db", "snr_band_db", "start_range_m",
    "true_speed_mps",
}  # fmt: skip


def seed(point: int = 0, rep: int = 0) -> np.random.SeedSequence:
    return np.random.SeedSequence(7, spawn_key=(point, rep))


def test_registered_by_name() -> None:
    for name, fn in (("ch6_receiver", ch6_receiver_trial), ("ch6_fmcw", ch6_fmcw_trial),
                     ("ch6_cost", ch6_cost_trial)):  # fmt: skip
        assert load_trial(TRIALS[name]) is fn


def test_gcas_high_snr_is_accurate_and_complete() -> None:
    out = ch6_receiver_trial({**TINY, "snr_db": 10.0}, seed())
    assert set(out) >= SCORE_KEYS
    assert out["n_truth"] >= 25
    assert out["pd"] == 1.0 and out["n_false"] == 0
    assert out["range_rmse_m"] < 0.05
    assert out["speed_rmse_mps"] < 0.05
    assert 30.0 <= out["start_range_m"] <= 90.0 and 5.0 <= out["true_speed_mps"] <= 25.0
    # GCAS's refinement measures at the bound (one trial's RMSE scatters around it).
    assert 0 < out["range_rmse_m"] < 3 * out["crlb_range_m"]
    assert math.isclose(out["snr_band_db"], 10.0 + 10 * math.log10(50_000 / 4400))
    # E/N0 over M = 10 hops of 10 ms at 100 kHz: SNR + 10 log10(50 000 · 0.1).
    assert math.isclose(out["e_over_n0_db"], 10.0 + 10 * math.log10(5000.0))


def test_same_seed_same_result_and_noise_only_gives_nothing() -> None:
    a = ch6_receiver_trial({**TINY, "snr_db": 0.0}, seed(1, 2))
    b = ch6_receiver_trial({**TINY, "snr_db": 0.0}, seed(1, 2))
    a.pop("receiver_cpu_s"), b.pop("receiver_cpu_s")
    assert a == b
    lost = ch6_receiver_trial({**TINY, "snr_db": -45.0}, seed())
    assert lost["n_detected"] == 0 and math.isnan(lost["range_rmse_m"])


def test_crlb_positive_and_decreasing_with_snr() -> None:
    bounds = [
        ch6_receiver_trial({**TINY, "snr_db": s, "receiver": "stft"}, seed())["crlb_range_m"]
        for s in (-10.0, 0.0, 10.0)
    ]
    assert bounds[0] > bounds[1] > bounds[2] > 0
    # Stein's bound scales as 1/sqrt(E/N0): 10 dB is a factor sqrt(10).
    assert math.isclose(bounds[0] / bounds[1], math.sqrt(10.0), rel_tol=1e-9)


@pytest.mark.parametrize(
    ("params", "max_rmse"),
    [
        ({"receiver": "stft", "n_s": 10}, 0.2),
        ({"receiver": "jifs", "speed_mps": [2.0, 10.0], "max_speed_mps": 12.0}, 0.2),
        ({"receiver": "gcas", "family": "three-state"}, 0.1),
        ({"receiver": "gcas", "srr_db": 10.0, "speed_mps": [10.0, 25.0]}, 0.1),
    ],
)
def test_other_receivers_and_settings_run(params: dict[str, Any], max_rmse: float) -> None:
    out = ch6_receiver_trial({**TINY, "snr_db": 10.0, **params}, seed())
    assert out["pd"] >= 0.8
    assert out["range_rmse_m"] < max_rmse


def test_mfbank_runs_through_the_trial() -> None:
    # Unrefined and on a coarse grid to stay fast; the refined bank is the cmp_mfbank sweep.
    opts = {"mfbank": {"n_doppler": 4, "threshold": 0.1, "refine": False}}
    out = ch6_receiver_trial(
        {
            "receiver": "mfbank",
            "duration_s": 0.45,
            "warmup_s": 0.15,
            "snr_db": 0.0,
            "m_hops": 5,
            "receiver_options": opts,
            "speed_mps": [9.5, 10.5],
        },
        seed(),
    )
    assert out["pd"] >= 0.8 and out["n_false"] <= 2
    # Doppler-grid limited without refinement (cells of 7 m/s): well above the bound.
    assert out["crlb_range_m"] < out["range_rmse_m"] < 0.5


def test_map_kept_once_per_point_at_its_snr() -> None:
    params = {**TINY, "snr_db": -10.0, "map_snr_db": -10.0, "map_bin_s": 0.002}
    out = ch6_receiver_trial(params, seed(0, 0))
    n = len(out["map_t_s"])
    assert n == pytest.approx(0.45 / 0.002, abs=2)
    assert len(out["map_db"]) == n and len(out["map_db"][0]) == 17
    assert len(out["map_speed_mps"]) == n
    assert set(out["truth_codeword"]) <= set(range(17))
    # The map peaks at the true codeword of each boundary (after the warm-up), within a bin.
    db = np.asarray(out["map_db"])
    t = np.asarray(out["map_t_s"])
    hits = []
    for tr, cw in zip(out["truth_t_rx_s"], out["truth_codeword"], strict=True):
        i = int(np.argmin(np.abs(t - tr)))
        if tr > 0.15 and 0 < i < n - 1:
            hits.append(int(np.argmax(db[i - 1 : i + 2].max(axis=0))) == cw)
    assert len(hits) >= 20 and np.mean(hits) > 0.9
    assert "map_db" not in ch6_receiver_trial(params, seed(0, 1))
    assert "map_db" not in ch6_receiver_trial({**params, "snr_db": 0.0}, seed(0, 0))


def test_fmcw_sawtooth_bias_matches_prediction_and_triangle_removes_it() -> None:
    saw = ch6_fmcw_trial({"family": "fmcw-saw", "speed_mps": 10.0, "snr_db": 10.0}, seed())
    assert saw["n_estimates"] >= 3
    assert saw["predicted_saw_bias_m"] == pytest.approx(-0.2 * 10.0 * 30_000 / 4400)
    assert abs(saw["range_bias_m"] - saw["predicted_saw_bias_m"]) < 0.5
    tri = ch6_fmcw_trial(
        {"family": "fmcw-tri", "speed_mps": 10.0, "snr_db": 10.0, "duration_s": 1.7}, seed()
    )
    assert tri["n_estimates"] >= 2 and abs(tri["range_bias_m"]) < 0.2
    assert tri["crlb_range_m"] > 0


def test_cost_golden_numbers() -> None:
    out = ch6_cost_trial({"m_hops": 5, "measure_s": 0.05}, seed())
    assert out["gcas_mults"] == 512.0
    assert out["direct_bank_mults"] == 17 * 64 * 5 * 1000
    assert out["gcas_adds"] == 2 * 4 * 64 + 17 * 64 * 4
    assert out["fft_bank_mults"] < out["direct_bank_mults"]
    assert out["gcas_cpu_s_per_s"] > 0


def _est(t: float, hop: int, rng: float, v: float = 10.0) -> Estimate:
    return Estimate(t, rng, v, hop, 1.0, 10.0, 1.0, 0.0, hop % 17, "gcas")


def test_score_estimates_counts_and_errors() -> None:
    truth = [
        SimpleNamespace(hop_index=h, t_rx_s=0.01 * h, range_m=50.0, radial_speed_mps=10.0)
        for h in range(1, 6)
    ]
    path = SimpleNamespace(solve=lambda t: SimpleNamespace(delay_s=np.full(len(t), 0.1) / 1.5))
    est = [
        _est(0.010, 0, 50.1),  # boundary starting hop 1: detected, +0.1 m
        _est(0.011, 0, 50.0),  # duplicate: false alarm
        _est(0.020, 1, 49.7, 11.0),  # detected, −0.3 m, +1 m/s
        _est(0.030, 7, 50.0),  # wrong hop index: false alarm
        _est(0.047, 3, 50.0),  # right index, 0.7 hop late: false alarm
        _est(0.5, 4, 50.0),  # outside the window: ignored
    ]
    s = score_estimates(est, truth, path, hop_s=0.01, sound_speed_mps=1500.0, window=(0.0, 0.1))
    assert (s["n_truth"], s["n_detected"], s["n_estimates"], s["n_false"]) == (5, 2, 5, 3)
    assert s["pd"] == 0.4 and s["false_per_s"] == pytest.approx(30.0)
    assert s["range_rmse_m"] == pytest.approx(math.sqrt((0.01 + 0.09) / 2))
    assert s["range_bias_m"] == pytest.approx(-0.1)
    assert s["speed_rmse_mps"] == pytest.approx(math.sqrt(0.5))
    # All estimates against the true delay (range 50 m): 0.1, 0, −0.3, 0, 0.
    assert s["range_sse_all_m2"] == pytest.approx(0.1)


def test_noise_sigma_golden() -> None:
    assert noise_sigma(-20.0) == pytest.approx(math.sqrt(50.0))


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"receiver": "fmcw"}, "receiver = 'fmcw' is not allowed: must be one of gcas, jifs"),
        ({"snr": 0}, "snr = 0 is not allowed: must be a parameter of ch6_receiver"),
        ({"speed_mps": 5.0}, "speed_mps = 5.0 is not allowed: must be [low, high]"),
        ({"speed_mps": [9.0, 2.0]}, "must be [low, high] with low <= high"),
        ({"srr_db": "loud"}, "srr_db = 'loud' is not allowed: must be a finite number"),
        ({"family": "costas"}, "family = 'costas' is not allowed: must be one of random-cyclic"),
        ({"warmup_s": 0.79}, "warmup_s = 0.79 is not allowed: must be < duration_s"),
        ({"range_m": [10.0, 90.0]}, "range_m = [10.0, 90.0] is not allowed: must be ranges"),
        ({"m_hops": 2}, "m_hops = 2 is not allowed: must be an integer in 3..64"),
        (
            {"receiver": "stft", "receiver_options": {"stft": {"nope": 1}}},
            "receiver.options.nope = 1 is not allowed",
        ),
        ({"bandwidth_hz": 4500.0}, "hop_s = 0.01 is not allowed: must be a multiple of 1/Δf"),
    ],
)
def test_bad_receiver_params_name_the_field(params: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError) as info:
        validate_receiver_params(params)
    assert message in str(info.value)


def test_bad_fmcw_params() -> None:
    with pytest.raises(ConfigError, match=r"family = 'fmcw-sine' is not allowed"):
        validate_fmcw_params({"family": "fmcw-sine"})
    with pytest.raises(ConfigError, match=r"max_range_m = 200.0 is not allowed"):
        validate_fmcw_params({"max_range_m": 200.0})
