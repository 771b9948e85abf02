"""A grid echo added to a block by the compiled loops (GridEcho.add_render) equals the NumPy
form (GridEcho.render) bit for bit: pure tones and chirps, hop amplitudes, an echo amplitude,
intervals solved per sample (sim_devices.acoustics.echo_kernels)."""

from __future__ import annotations

import numpy as np
import pytest

from hil.signals.schedule import HopSchedule
from sim_devices.acoustics.delay import TwoWayPath
from sim_devices.acoustics.grid_echo import GridEcho
from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed, Piecewise

FS = 192_000.0


def tones() -> HopSchedule:
    return HopSchedule.from_segments("tones", [28e3, 30e3, 32e3], [0, 2, 1, 2], 0.0021)


def chirps() -> HopSchedule:
    return HopSchedule.from_segments(
        "chirps", [28e3, 31e3], [0, 1, -1], [0.003, 0.002, 0.0007],
        chirp_hz_per_s=[4e5, -6e5, 0.0], amplitude=[1.0, 0.5, 0.0],
    )  # fmt: skip


def both_forms(echo: GridEcho, n0: int, count: int) -> tuple[np.ndarray, np.ndarray]:
    """``base + render`` and ``base + add_render`` of the same block, from the same base."""
    base = np.random.default_rng(5).standard_normal(count)
    grid = echo.sample_grid(n0, count)
    expected = base + echo.render(grid)
    got = base.copy()
    echo.add_render(echo.sample_grid(n0, count), got)
    return expected, got


@pytest.mark.parametrize("schedule", [tones(), chirps()], ids=["tones", "chirps"])
@pytest.mark.parametrize("amplitude", [1.0, 3.7e4])
@pytest.mark.parametrize(("n0", "count"), [(0, 16384), (5000, 3001), (81920, 16384)])
def test_the_compiled_block_equals_the_numpy_form_bit_for_bit(
    schedule: HopSchedule, amplitude: float, n0: int, count: int
) -> None:
    target = ConstantVelocity((3.0, 0.4, -0.2), (-2.0, 0.3, 0.0))
    path = TwoWayPath.monostatic(Fixed((0.0, 0.0, 0.0)), target, 1480.0)
    echo = GridEcho(schedule, path, FS, amplitude=amplitude)
    expected, got = both_forms(echo, n0, count)
    assert got.tobytes() == expected.tobytes()
    assert echo.exact_intervals == 0
    assert np.max(np.abs(got - np.random.default_rng(5).standard_normal(count))) > 0.1


def test_a_block_with_intervals_solved_per_sample_equals_the_numpy_form() -> None:
    # A corner of the path inside an interval: that interval is solved per sample.
    corner = Piecewise([(2.0, 0.0, 0.0), (2.5, 0.0, 0.0), (2.5, 0.6, 0.0)], speeds_mps=[1.5, 1.5])
    path = TwoWayPath.monostatic(Fixed((0.0, 0.0, 0.0)), corner, 1480.0)
    echo = GridEcho(tones(), path, FS)
    expected, got = both_forms(echo, 0, 16384 * 6)
    assert echo.exact_intervals > 0
    assert got.tobytes() == expected.tobytes()


def test_a_still_path_is_solved_once_and_gives_the_same_samples() -> None:
    """The direct blast between two still points (a fixed transducer and an offset of it):
    its first batch serves every batch, with the samples of solving each one."""
    from sim_devices.acoustics.delay import OneWayPath
    from sim_devices.acoustics.tank import BoxImage, Offset

    sonar = Fixed((0.5, 2.0, -1.2))
    image = BoxImage(sonar, (1.0, 1.0, -1.0), (0.0, 0.0, 0.0))  # in the surface
    for tx in (Offset(sonar, (0.0, 0.0, 0.05)), image):
        path = OneWayPath(tx, sonar, 1480.0)
        still = GridEcho(chirps(), path, FS, amplitude=2.5e3)
        every = GridEcho(chirps(), path, FS, amplitude=2.5e3)
        every.still = False
        assert still.still
        solves = {"n": 0}
        real_solve = path.solve

        def counted(t: np.ndarray, real=real_solve, tally=solves) -> object:
            tally["n"] += 1
            return real(t)

        path.solve = counted  # type: ignore[method-assign]
        got = still.block(7_000, 200_000)
        assert solves["n"] == 1
        expected = every.block(7_000, 200_000)
        assert solves["n"] > 10
        assert got.tobytes() == expected.tobytes()
        assert np.max(np.abs(got)) > 1.0
    moving = TwoWayPath.monostatic(sonar, ConstantVelocity((3.0, 2.0, -1.2), (-1.0, 0, 0)), 1480.0)
    assert not GridEcho(tones(), moving, FS).still
