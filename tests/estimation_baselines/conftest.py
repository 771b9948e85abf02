"""Shared fixtures: exact constant-velocity echoes (Doppler as time scaling) in white noise."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import NDArray

from hil.estimation.base import Estimate
from hil.signals.schedule import HopSchedule
from sim_devices.acoustics.delay import TwoWayPath
from sim_devices.acoustics.echo import AnalyticEcho
from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed

C = 1500.0


@dataclass(frozen=True)
class Scene:
    """A target at ``range_m`` (m) at t = 0 moving at ``speed_mps`` (m/s, > 0 closing)."""

    range_m: float
    speed_mps: float
    c: float = C

    def true_range(self, t_tx_s: float) -> float:
        """Range (m) at the bounce of the sound emitted at ``t_tx_s``: c·delay/2."""
        return self.c * (self.range_m - self.speed_mps * t_tx_s) / (self.c + self.speed_mps)

    def true_t_rx(self, t_tx_s: float) -> float:
        """Receive time (s) of the sound emitted at ``t_tx_s``."""
        return t_tx_s + 2.0 * self.true_range(t_tx_s) / self.c

    def range_errors(self, estimates: list[Estimate]) -> NDArray[np.float64]:
        return np.array([e.range_m - self.true_range(e.t_tx_s) for e in estimates])

    def speed_errors(self, estimates: list[Estimate]) -> NDArray[np.float64]:
        return np.array([e.speed_mps - self.speed_mps for e in estimates])


EchoFactory = Callable[..., NDArray[np.float64]]


def echo_samples(
    schedule: HopSchedule,
    fs_hz: float,
    scene: Scene,
    duration_s: float,
    *,
    snr_db: float | None = None,
    seed: int = 0,
    amplitude: float = 1.0,
) -> NDArray[np.float64]:
    """Exact echo samples (shape ``(round(duration·fs),)``) plus white noise at per-sample SNR.

    ``snr_db`` is ``(A²/2)/σ²`` over the full band 0…fs/2; None means no noise.
    """
    target = ConstantVelocity((scene.range_m, 0.0, 0.0), (-scene.speed_mps, 0.0, 0.0))
    path = TwoWayPath.monostatic(Fixed((0.0, 0.0, 0.0)), target, scene.c)
    n = int(round(duration_s * fs_hz))
    x = AnalyticEcho(schedule, path, fs_hz, amplitude=amplitude).block(0, n)
    if snr_db is not None:
        sigma = np.sqrt(amplitude**2 / 2.0 / 10.0 ** (snr_db / 10.0))
        x = x + np.random.default_rng(seed).normal(0.0, sigma, n)
    return x


@dataclass(frozen=True)
class Kit:
    """What the tests import from here (conftest is not importable under importlib mode)."""

    Scene: type[Scene]
    echo: EchoFactory


@pytest.fixture(scope="session")
def kit() -> Kit:
    return Kit(Scene=Scene, echo=echo_samples)
