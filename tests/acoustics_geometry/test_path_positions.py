"""An echo path's solution carries where it found the transmitter, the target and the
receiver: the trajectories' own positions at the solved instants, bit for bit
(sim_devices.acoustics.delay.PathSolution.positions_m)."""

from __future__ import annotations

import numpy as np

from sim_devices.acoustics.delay import OneWayPath, PathSolution, TwoWayPath, solve_paths
from sim_devices.acoustics.tank import Tank, echo_paths
from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed


def assert_positions_are_the_trajectories(path: TwoWayPath, sol: PathSolution) -> None:
    assert sol.positions_m is not None and sol.t_bounce_s is not None
    tx_at, target_at, rx_at = sol.positions_m
    for got, trajectory, t in (
        (tx_at, path.tx, sol.t_emit_s),
        (target_at, path.target, sol.t_bounce_s),
        (rx_at, path.rx, sol.t_rx_s),
    ):
        assert got.shape == (t.shape[0], 3)
        assert got.tobytes() == trajectory.position(t).tobytes()


def test_one_path_and_a_bank_of_image_paths_carry_their_positions() -> None:
    sonar = Fixed((1.0, 0.8, -0.5))
    target = ConstantVelocity((3.0, 1.1, -0.6), (-1.5, 0.2, 0.0))
    t = np.linspace(0.0, 0.05, 41)
    direct = TwoWayPath.monostatic(sonar, target, 1480.0)
    assert_positions_are_the_trajectories(direct, direct.solve(t))
    tank = Tank(6.0, 2.0, 1.5, wall_reflection=0.8, bottom_reflection=0.7)
    paths = [TwoWayPath(p.tx, p.target, p.rx, 1480.0) for p in echo_paths(sonar, target, tank, 1)]
    assert len(paths) == 13
    for path, sol in zip(paths, solve_paths(paths, t), strict=True):
        assert_positions_are_the_trajectories(path, sol)


def test_a_one_way_path_carries_none() -> None:
    leg = OneWayPath(Fixed((0.0, 0.0, 0.05)), Fixed((0.0, 0.0, 0.0)), 1480.0)
    assert leg.solve(np.array([0.0, 0.1])).positions_m is None
