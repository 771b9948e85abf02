"""Symmetric alpha-stable sampler (Chambers-Mallows-Stuck) against known distributions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from hil.errors import ConfigError
from sim_devices.acoustics.alpha_stable import symmetric_alpha_stable


def test_alpha_two_is_gaussian_with_variance_two_scale_squared() -> None:
    x = symmetric_alpha_stable(2.0, 20_000, np.random.default_rng(123), scale=3.0)
    assert stats.kstest(x / (3.0 * np.sqrt(2.0)), "norm").pvalue > 0.01
    assert np.var(x) == pytest.approx(18.0, rel=0.05)


def test_alpha_one_is_cauchy() -> None:
    x = symmetric_alpha_stable(1.0, 20_000, np.random.default_rng(7), scale=2.0)
    assert stats.kstest(x, stats.cauchy(scale=2.0).cdf).pvalue > 0.01


def test_alpha_one_and_a_half_matches_scipy_levy_stable_cdf() -> None:
    x = symmetric_alpha_stable(1.5, 100_000, np.random.default_rng(99))
    points = np.array([-3.0, -1.0, 0.0, 1.0, 3.0])
    empirical = (x[:, None] <= points).mean(axis=0)
    reference = stats.levy_stable.cdf(points, 1.5, 0.0)
    assert np.max(np.abs(empirical - reference)) < 0.006


def test_same_seed_same_draw() -> None:
    a = symmetric_alpha_stable(1.3, 1000, np.random.default_rng(5))
    b = symmetric_alpha_stable(1.3, 1000, np.random.default_rng(5))
    assert np.array_equal(a, b)


def test_alpha_zero_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"alpha = 0\.0 is not allowed: must be 0 < alpha <= 2"):
        symmetric_alpha_stable(0.0, 10, np.random.default_rng(0))


def test_non_positive_scale_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"scale = 0\.0 is not allowed: must be > 0"):
        symmetric_alpha_stable(1.5, 10, np.random.default_rng(0), scale=0.0)
