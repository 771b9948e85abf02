"""Trajectories: positions and velocities against hand-computed values, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from sim_devices.acoustics.trajectory import (
    ConstantVelocity,
    Fixed,
    Live,
    Mirrored,
    Piecewise,
    Trajectory,
)


def test_fixed_is_at_rest_everywhere() -> None:
    point = Fixed((1.0, -2.0, 3.5))
    t = np.array([-5.0, 0.0, 1e4])
    assert point.position(t).tolist() == [[1.0, -2.0, 3.5]] * 3
    assert point.velocity(t).tolist() == [[0.0, 0.0, 0.0]] * 3
    assert point.max_speed_mps == 0.0
    assert isinstance(point, Trajectory)


def test_constant_velocity_positions_and_shapes() -> None:
    tow = ConstantVelocity((10.0, 1.0, -2.0), (-2.0, 0.5, 0.0), t_ref_s=1.0)
    assert tow.position(np.array([1.0, 3.0])).tolist() == [[10.0, 1.0, -2.0], [6.0, 2.0, -2.0]]
    assert tow.position(3.0).shape == (3,)
    assert tow.position(np.zeros((2, 4))).shape == (2, 4, 3)
    assert tow.velocity(np.array([7.0])).tolist() == [[-2.0, 0.5, 0.0]]
    assert tow.max_speed_mps == pytest.approx(np.hypot(2.0, 0.5), rel=1e-15)


def test_piecewise_waypoints_dwell_and_hold() -> None:
    # Leg 0: (0,0,0) -> (4,0,0) at 2 m/s takes 2 s, after a 1 s dwell at the start (t0 = 10).
    # Dwell 0.5 s at (4,0,0); leg 1 -> (4,3,0) at 1 m/s takes 3 s; then hold.
    path = Piecewise(
        [(0, 0, 0), (4, 0, 0), (4, 3, 0)], [2.0, 1.0], t_start_s=10.0, dwell_s=[1.0, 0.5, 0.0]
    )
    t = np.array([0.0, 10.5, 11.0, 12.0, 13.0, 13.25, 14.5, 16.5, 100.0])
    expected = [
        [0, 0, 0],  # before start
        [0, 0, 0],  # dwelling
        [0, 0, 0],  # leg 0 starts
        [2, 0, 0],
        [4, 0, 0],  # arrived, dwelling
        [4, 0, 0],
        [4, 1, 0],
        [4, 3, 0],  # arrived at the end
        [4, 3, 0],  # holding
    ]
    np.testing.assert_allclose(path.position(t), expected, atol=1e-12)
    v = path.velocity(np.array([9.0, 10.2, 11.5, 13.2, 14.0, 20.0]))
    assert v.tolist() == [[0, 0, 0], [0, 0, 0], [2, 0, 0], [0, 0, 0], [0, 1, 0], [0, 0, 0]]
    assert path.end_time_s == pytest.approx(16.5)
    assert path.max_speed_mps == 2.0


def test_piecewise_without_hold_keeps_last_velocity() -> None:
    path = Piecewise([(0, 0, 0), (0, 0, -3)], [1.5], hold_at_end=False)
    np.testing.assert_allclose(path.position(np.array([4.0])), [[0, 0, -6.0]], atol=1e-12)
    assert path.velocity(np.array([4.0])).tolist() == [[0, 0, -1.5]]


@settings(max_examples=60, deadline=None)
@given(t=st.floats(-1.0, 30.0))
def test_piecewise_position_is_continuous_and_velocity_is_its_slope(t: float) -> None:
    path = Piecewise(
        [(0, 0, 0), (3, 4, 0), (3, 4, 2), (-1, 0, 0)], [1.0, 0.5, 2.0], dwell_s=[0.0, 1.0, 0, 0]
    )
    h = 1e-7
    # Corners: leg 0 (5 m at 1 m/s) ends at 5 s, 1 s dwell, leg 1 (2 m at 0.5 m/s) to 10 s,
    # leg 2 (6 m at 2 m/s) to 13 s. The slope test needs t + h inside one segment.
    assume(min(abs(t - c) for c in (0.0, 5.0, 6.0, 10.0, 13.0)) > 2 * h)
    assert path.end_time_s == pytest.approx(13.0)
    p = path.position(np.array([t - h, t, t + h]))
    # Continuous: a step of h moves at most max_speed * h.
    assert np.all(np.linalg.norm(np.diff(p, axis=0), axis=1) <= 2.0 * h * (1 + 1e-6) + 1e-12)
    # Right derivative equals the (right-continuous) velocity.
    np.testing.assert_allclose((p[2] - p[1]) / h, path.velocity(np.array([t]))[0], atol=1e-6)


def test_live_uses_velocity_callable_or_central_difference() -> None:
    omega = 0.8

    def circle(t: np.ndarray) -> np.ndarray:
        return np.stack([np.cos(omega * t), np.sin(omega * t), np.zeros_like(t)], axis=-1)

    def circle_velocity(t: np.ndarray) -> np.ndarray:
        return omega * np.stack([-np.sin(omega * t), np.cos(omega * t), 0 * t], axis=-1)

    t = np.linspace(-3.0, 3.0, 13)
    numeric = Live(circle)
    exact = Live(circle, circle_velocity, max_speed_mps=omega)
    np.testing.assert_allclose(numeric.velocity(t), circle_velocity(t), atol=1e-9)
    assert np.array_equal(exact.velocity(t), circle_velocity(t))
    assert np.array_equal(numeric.position(t), circle(t))
    assert numeric.max_speed_mps is None
    assert exact.max_speed_mps == omega


def test_bad_positions_are_refused_with_field_and_range() -> None:
    with pytest.raises(
        ConfigError, match=r"position_m = \(0\.0, nan, 0\.0\) is not allowed: must be finite"
    ):
        Fixed((0.0, float("nan"), 0.0))
    with pytest.raises(ConfigError, match=r"velocity_mps = .* must be finite coordinates"):
        ConstantVelocity((0, 0, 0), (float("inf"), 0, 0))
    with pytest.raises(ConfigError, match=r"position_m = \(1, 2\) .* must be a 3-vector"):
        Fixed((1, 2))
    with pytest.raises(
        ConfigError, match=r"waypoints_m = nan .* must be finite coordinates in metres"
    ):
        Piecewise([(0, 0, 0), (np.nan, 0, 0)], [1.0])
    with pytest.raises(
        ConfigError, match=r"waypoints_m = \(1, 3\) .* an \(m, 3\) array with m >= 2"
    ):
        Piecewise([(0, 0, 0)], [])
    with pytest.raises(ConfigError, match=r"t_s = inf is not allowed: must be finite times"):
        Fixed((0, 0, 0)).position(np.array([0.0, np.inf]))


def test_bad_piecewise_settings_are_refused() -> None:
    pts = [(0, 0, 0), (1, 0, 0)]
    with pytest.raises(ConfigError, match=r"speeds_mps = 0\.0 is not allowed: must be > 0 m/s"):
        Piecewise(pts, [0.0])
    with pytest.raises(
        ConfigError, match=r"speeds_mps = \(2,\) .* one speed per leg: shape \(1,\)"
    ):
        Piecewise(pts, [1.0, 2.0])
    with pytest.raises(ConfigError, match=r"dwell_s = -1\.0 is not allowed: must be >= 0 s"):
        Piecewise(pts, [1.0], dwell_s=[0.0, -1.0])


def test_bad_live_callables_are_refused() -> None:
    with pytest.raises(ConfigError, match=r"position_fn = 3 is not allowed: must be a callable"):
        Live(3)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"max_speed_mps = -1\.0 .* >= 0 m/s"):
        Live(lambda t: np.zeros((*t.shape, 3)), max_speed_mps=-1.0)
    flat = Live(lambda t: np.zeros(t.shape))
    with pytest.raises(
        ConfigError, match=r"Live\.position_fn\(t\) shape = \(2,\) .* t\.shape \+ \(3,\)"
    ):
        flat.position(np.zeros(2))
    broken = Live(lambda t: np.full((*t.shape, 3), np.nan))
    with pytest.raises(ConfigError, match=r"Live\.position_fn\(t\) = nan .* must be finite values"):
        broken.position(np.zeros(2))


def test_mirrored_image_reflects_position_and_velocity() -> None:
    # Bottom at z = -10 m (normal given unnormalised): a point at z = -4 has its image at -16.
    inner = ConstantVelocity((1.0, 2.0, -4.0), (0.5, 0.0, -1.0))
    image = Mirrored(inner, (0.0, 0.0, -10.0), (0.0, 0.0, 3.0))
    t = np.array([0.0, 2.0])
    np.testing.assert_allclose(image.position(t), [[1, 2, -16], [2, 2, -14]], atol=1e-12)
    np.testing.assert_allclose(image.velocity(t), [[0.5, 0, 1.0]] * 2, atol=1e-15)
    assert image.max_speed_mps == inner.max_speed_mps
    # Mirroring twice gives the original back.
    twice = Mirrored(image, (0.0, 0.0, -10.0), (0.0, 0.0, 1.0))
    np.testing.assert_allclose(twice.position(t), inner.position(t), atol=1e-12)
    with pytest.raises(
        ConfigError, match=r"plane_normal = \(0\.0, 0\.0, 0\.0\) .* a non-zero vector"
    ):
        Mirrored(inner, (0, 0, 0), (0, 0, 0))
