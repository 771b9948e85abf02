"""The towed target's compiled position loop against its NumPy form, bit for bit
(hil.experiments.towed_kernels)."""

from __future__ import annotations

import numpy as np
import pytest

from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from hil.experiments.sim_tank import _hermite, _TowedTarget
from hil.experiments.towed_kernels import towed_positions


def _numpy_form(t, grid, x, v, h, origin, axis):  # type: ignore[no-untyped-def]
    return np.asarray(origin) + np.multiply.outer(_hermite(t, grid, x, v, h), np.asarray(axis))


@pytest.mark.parametrize("seed", range(6))
def test_towed_positions_equal_the_numpy_form_bit_for_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    h = 1e-3
    first = float(np.floor(rng.uniform(0.0, 5000.0)))
    grid = np.arange(first - 2.0, first + int(rng.integers(3, 3000))) * h
    x, v = rng.normal(size=grid.size), rng.normal(size=grid.size)
    # Times inside the grid, its ends and its knots among them.
    t = np.concatenate([rng.uniform(grid[0], grid[-1], 400), grid[[0, 1, -2, -1]]])
    t = np.sort(t)
    origin, axis = np.array([11.0, 2.0, -1.2]), rng.normal(size=3)
    out = np.empty((t.size, 3))
    towed_positions(t, grid, h, x, v, origin, axis, out)
    ref = _numpy_form(t, grid, x, v, h, origin, axis)
    assert out.view(np.uint64).tolist() == ref.view(np.uint64).tolist()


def test_towed_target_follows_a_constant_acceleration_exactly() -> None:
    # x = 0.3 + 0.5 t + 0.25 t² (m): the cubic Hermite is exact; the target moves along the
    # stage axis from the stage origin; a (2, 2) array of times gives shape (2, 2, 3).
    exp = parse_experiment(DEFAULT_EXPERIMENT)

    def motion(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return 0.3 + 0.5 * t + 0.25 * t * t, 0.5 + 0.5 * t

    target = _TowedTarget(exp, motion)

    class _World:
        origin_index = 0

    target.world = _World()
    t = np.array([[0.0101, 0.5], [1.2345, 2.0]])
    got = target(t)
    assert got.shape == (2, 2, 3)
    stage = 0.3 + 0.5 * t + 0.25 * t * t
    want = np.asarray(exp.stage_origin_m) + np.multiply.outer(stage, np.asarray(exp.stage_axis))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert got.view(np.uint64).tolist() == _numpy_form(
        t.reshape(-1), target._grid, target._x, target._v, target.GRID_S,
        exp.stage_origin_m, exp.stage_axis,
    ).reshape(2, 2, 3).view(np.uint64).tolist()  # fmt: skip
