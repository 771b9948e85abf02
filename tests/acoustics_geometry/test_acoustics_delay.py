"""Exact two-way and one-way delay: closed forms, residuals, chunking and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from sim_devices.acoustics.delay import (
    DelayNotConvergedError,
    OneWayPath,
    TwoWayPath,
    closed_form_monostatic,
    doppler_ratio,
)
from sim_devices.acoustics.trajectory import (
    ConstantVelocity,
    Fixed,
    Live,
    Mirrored,
    Piecewise,
    Trajectory,
)


@settings(max_examples=80, deadline=None)
@given(
    range_m=st.floats(1.0, 2000.0),
    speed_mps=st.floats(-60.0, 60.0),
    c=st.floats(1400.0, 1600.0),
    direction=st.sampled_from([(1.0, 0.0, 0.0), (0.0, -0.6, 0.8), (0.48, 0.6, -0.64)]),
)
def test_monostatic_constant_velocity_matches_closed_form(
    range_m: float, speed_mps: float, c: float, direction: tuple[float, float, float]
) -> None:
    # Sonar off the origin, target on a radial line closing (v > 0) or opening (v < 0).
    sonar_at = np.array([3.0, -1.0, -5.0])
    u = np.array(direction)
    target = ConstantVelocity(sonar_at + range_m * u, -speed_mps * u)
    sonar = Fixed(sonar_at)
    # Keep the target on its side of the sonar while the echoes are in flight.
    t_end = min(5.0, 0.5 * range_m / max(abs(speed_mps), 1e-9))
    t = np.linspace(0.0, t_end, 257)
    sol = TwoWayPath.monostatic(sonar, target, c).solve(t)
    alpha, tau0 = closed_form_monostatic(range_m, speed_mps, c)
    delay = t - alpha * (t - tau0)
    np.testing.assert_allclose(sol.delay_s, delay, rtol=1e-9)
    np.testing.assert_allclose(sol.t_emit_s, alpha * (t - tau0), rtol=1e-9, atol=1e-9 * tau0)
    np.testing.assert_allclose(sol.alpha, alpha, rtol=1e-9)
    # Speeds well below c converge in a few iterations.
    assert sol.iterations <= 12


@pytest.mark.parametrize("speed_mps", [-25.72, -10.0, -1.0, 0.5, 10.0, 25.72])
def test_alpha_is_the_slope_of_the_emission_time(speed_mps: float) -> None:
    sonar = Fixed((0.0, 0.0, 0.0))
    target = ConstantVelocity((80.0, 20.0, -5.0), (-speed_mps, 0.3, 0.0))
    path = TwoWayPath.monostatic(sonar, target, 1480.0)
    t = np.array([0.5, 1.0, 1.5])
    h = 1e-4
    ahead, behind = path.solve(t + h).t_emit_s, path.solve(t - h).t_emit_s
    np.testing.assert_allclose(path.solve(t).alpha, (ahead - behind) / (2 * h), rtol=1e-8)


def test_stationary_bistatic_gives_straight_line_delays_exactly() -> None:
    c = 1487.5
    tx, target, rx = (1.0, 2.0, -3.0), (40.0, -7.5, -10.0), (-2.5, 0.25, -3.0)
    path = TwoWayPath(Fixed(tx), Fixed(target), Fixed(rx), c)
    t = np.array([0.0, 0.37, 12.0, 1e3])
    sol = path.solve(t)

    def dist(a: tuple[float, ...], b: tuple[float, ...]) -> float:
        return math.sqrt((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2)

    r1, r2 = dist(target, tx), dist(rx, target)
    assert sol.delay_s.tolist() == [r2 / c + r1 / c] * 4
    assert sol.t_bounce_s is not None
    assert sol.t_bounce_s.tolist() == (t - r2 / c).tolist()
    assert sol.alpha.tolist() == [1.0] * 4
    assert sol.leg_lengths_m[0].tolist() == [r1] * 4
    assert sol.leg_lengths_m[1].tolist() == [r2] * 4
    assert sol.iterations == 1


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    c=st.floats(1400.0, 1600.0),
)
def test_moving_bistatic_solution_satisfies_the_path_equations(seed: int, c: float) -> None:
    rng = np.random.default_rng(seed)
    tx = ConstantVelocity(rng.uniform(-5, 5, 3), rng.uniform(-3, 3, 3))
    target = ConstantVelocity(rng.uniform(20, 200, 3), rng.uniform(-30, 30, 3))
    rx = ConstantVelocity(rng.uniform(-5, 5, 3), rng.uniform(-3, 3, 3))
    t = np.sort(rng.uniform(0.0, 0.5, 64))
    sol = TwoWayPath(tx, target, rx, c).solve(t)
    assert sol.t_bounce_s is not None
    t_b, t_e = sol.t_bounce_s, sol.t_emit_s
    leg2 = np.linalg.norm(rx.position(t) - target.position(t_b), axis=1) / c
    leg1 = np.linalg.norm(target.position(t_b) - tx.position(t_e), axis=1) / c
    np.testing.assert_allclose(t - t_b, leg2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(t_b - t_e, leg1, rtol=0, atol=1e-12)
    np.testing.assert_allclose(sol.delay_s, leg1 + leg2, rtol=0, atol=2e-12)


def test_one_way_path_of_approaching_source_matches_closed_form() -> None:
    # Source closing on a fixed receiver at v: t_e = (t − D0/c)/(1 − v/c), alpha = c/(c − v).
    c, d0, v = 1500.0, 300.0, 12.0
    path = OneWayPath(ConstantVelocity((d0, 0, 0), (-v, 0, 0)), Fixed((0, 0, 0)), c)
    t = np.linspace(0.2, 3.0, 50)
    sol = path.solve(t)
    np.testing.assert_allclose(sol.t_emit_s, (t - d0 / c) / (1 - v / c), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(sol.delay_s, t - (t - d0 / c) / (1 - v / c), rtol=1e-12)
    np.testing.assert_allclose(sol.alpha, c / (c - v), rtol=1e-12)
    assert sol.t_bounce_s is None
    assert len(sol.leg_lengths_m) == 1


def _accelerating_target() -> Live:
    # Swinging target: x = 30 + 2 sin(3 t), speed at most 6 m/s.
    return Live(
        lambda t: np.stack([30 + 2 * np.sin(3 * t), 0.5 * t, np.zeros_like(t)], axis=-1),
        lambda t: np.stack([6 * np.cos(3 * t), np.full_like(t, 0.5), np.zeros_like(t)], axis=-1),
        max_speed_mps=6.1,
    )


@pytest.mark.parametrize(
    "target",
    [
        Piecewise([(50, 0, 0), (20, 10, 0), (20, 10, -5)], [12.0, 3.0], t_start_s=0.01),
        _accelerating_target(),
        Mirrored(ConstantVelocity((40, 5, -3), (-9, 1, 0)), (0, 0, -12.0), (0, 0.2, 1)),
    ],
    ids=["piecewise", "live", "mirrored"],
)
def test_chunked_solves_equal_one_whole_solve_bit_for_bit(target: Trajectory) -> None:
    path = TwoWayPath(Fixed((0, 0, 0)), target, Fixed((0.5, 0, 0)), 1500.0)
    t = np.arange(20000) / 8000.0
    whole = path.solve(t)
    rng = np.random.default_rng(7)
    cuts = np.sort(rng.choice(np.arange(1, t.size), size=25, replace=False))
    parts = [path.solve(chunk) for chunk in np.split(t, cuts)]
    for name in ("t_emit_s", "delay_s", "alpha"):
        joined = np.concatenate([getattr(p, name) for p in parts])
        assert np.array_equal(joined, getattr(whole, name)), name


def test_doppler_ratio_values() -> None:
    assert doppler_ratio(0.0, 1500.0) == 1.0
    np.testing.assert_allclose(doppler_ratio([10.0, -10.0], 1500.0), [1510 / 1490, 1490 / 1510])


def test_speed_at_or_above_sound_speed_is_refused() -> None:
    sonar = Fixed((0, 0, 0))
    fast = ConstantVelocity((100, 0, 0), (-1500.0, 0, 0))
    with pytest.raises(
        ConfigError,
        match=r"target\.max_speed_mps = 1500\.0 is not allowed: must be < sound speed c = 1500 m/s",
    ):
        TwoWayPath.monostatic(sonar, fast, 1500.0)
    with pytest.raises(ConfigError, match=r"tx\.max_speed_mps = 1600\.0 .* < sound speed c = 1500"):
        OneWayPath(ConstantVelocity((0, 0, 0), (0, 1600.0, 0)), sonar, 1500.0)
    with pytest.raises(ConfigError, match=r"closing_speed_mps = 1500\.0 .* \|v\| < c = 1500 m/s"):
        doppler_ratio(1500.0, 1500.0)
    with pytest.raises(ConfigError, match=r"closing_speed_mps = -2000\.0 .* \|v\| < c = 1500 m/s"):
        closed_form_monostatic(10.0, -2000.0, 1500.0)


def test_supersonic_live_trajectory_reports_non_convergence() -> None:
    # A Live trajectory cannot declare its speed in advance: the solve itself must refuse.
    supersonic = Live(lambda t: np.stack([100 - 2000 * t, 0 * t, 0 * t], axis=-1))
    path = TwoWayPath.monostatic(Fixed((0, 0, 0)), supersonic, 1500.0)
    with pytest.raises(
        DelayNotConvergedError,
        match=r"target speed = '3 of 3 samples still changing by .* after 100 iterations' is not "
        r"allowed: must be well below the sound speed c = 1500 m/s",
    ):
        path.solve(np.array([0.01, 0.02, 0.03]))


def test_bad_sound_speed_is_refused() -> None:
    sonar = Fixed((0, 0, 0))
    for c in (0.0, -1500.0, float("nan")):
        with pytest.raises(ConfigError, match=r"sound_speed_mps = .* must be > 0 m/s and finite"):
            TwoWayPath.monostatic(sonar, sonar, c)
    with pytest.raises(ConfigError, match=r"sound_speed_mps = 0 is not allowed: must be > 0 m/s"):
        doppler_ratio(1.0, 0)


def test_bad_range_times_and_solver_settings_are_refused() -> None:
    with pytest.raises(
        ConfigError, match=r"range_m = -1\.0 is not allowed: must be >= 0 m and finite"
    ):
        closed_form_monostatic(-1.0, 5.0)
    sonar = Fixed((0, 0, 0))
    path = TwoWayPath.monostatic(sonar, Fixed((10, 0, 0)), 1500.0)
    with pytest.raises(ConfigError, match=r"t_rx_s = nan is not allowed: must be finite times"):
        path.solve(np.array([0.0, np.nan]))
    with pytest.raises(ConfigError, match=r"t_rx_s = 'shape \(2, 2\)' .* a 1-D array"):
        path.solve(np.zeros((2, 2)))
    with pytest.raises(ConfigError, match=r"tolerance_s = 0\.0 is not allowed: must be > 0 s"):
        TwoWayPath(sonar, sonar, sonar, 1500.0, tolerance_s=0.0)
    with pytest.raises(
        ConfigError, match=r"max_iterations = 0 is not allowed: must be an integer >= 1"
    ):
        OneWayPath(sonar, sonar, 1500.0, max_iterations=0)
    with pytest.raises(ConfigError, match=r"target = 'sonar' is not allowed: must be a Trajectory"):
        TwoWayPath(sonar, "sonar", sonar, 1500.0)  # type: ignore[arg-type]
