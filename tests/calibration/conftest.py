"""Shared simulated benches of the calibration tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from hil.experiments.calibration.ranging import EchoRanger
from hil.experiments.calibration.simworld import EchoTank, MechanicalStage, SimTruth, sim_tank


@pytest.fixture(scope="module")
def tank_truth() -> SimTruth:
    """Injected truths of the tank tests: scale error and backlash, water at 18.3 °C."""
    return SimTruth(stage_scale=1.0012, backlash_m=180e-6, temperature_c=18.3, seed=7)


@pytest.fixture
def tank(tank_truth: SimTruth) -> Iterator[tuple[MechanicalStage, EchoTank, EchoRanger]]:
    """The GRBL driver on the simulated controller, the echo tank and a ranger."""
    with sim_tank(tank_truth) as (stage, echo_tank, _):
        ranger = EchoRanger(
            echo_tank.device(), (1e-3, 3e-3), latency_samples=tank_truth.tank_latency_samples
        )
        yield stage, echo_tank, ranger
