"""A stationary target in the simulated tank (images, direct blast, noise) gives no
moving-target estimate, with the default band and with the tank run's settings."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from hil.data import scenario_path
from hil.estimation.gcas import GcasReceiver
from sim_devices.acoustics.scenario import Scenario, build_channel, parse_scenario

from .conftest import run_blocks


def _stationary_tank() -> tuple[np.ndarray, Scenario]:
    """1 s of the shipped tank-audio scenario with its target at rest 7.5 m away."""
    doc = tomllib.loads(scenario_path("tank-audio").read_text(encoding="utf-8"))
    doc["targets"][0]["velocity_mps"] = [0.0, 0.0, 0.0]
    sc = parse_scenario(doc)
    x = build_channel(sc).read(int(sc.duration_s * sc.fs_hz))
    return np.asarray(x, dtype=np.float64), sc


@pytest.mark.parametrize(
    "options",
    [{}, {"reverb_speed_mps": 0.0, "range_readout": "first-arrival"}],
    ids=["default band", "tank run (band off, first arrival)"],
)
def test_a_stationary_target_gives_no_moving_estimate(options: dict[str, object]) -> None:
    x, sc = _stationary_tank()
    rx = GcasReceiver.from_options(
        sc.schedule, sc.fs_hz, sound_speed_mps=sc.sound_speed_mps,
        max_speed_mps=3.0, max_range_m=12.0, m_hops=10, **options,
    )  # fmt: skip
    est = run_blocks(rx, x, 19_200)
    moving = [e for e in est if abs(e.speed_mps) > 0.3]
    assert moving == []
    if options:
        # Band off: the target (7.5 m) and the direct blast are reported at rest.
        assert len(est) > 50 and all(abs(e.speed_mps) < 0.3 for e in est)
    else:
        assert est == [] and rx.in_band_count > 50
