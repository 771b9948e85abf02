"""Fields of the same water share their cubes process-wide, within a bounded count of
scatterers (sim_devices.acoustics.reverberation)."""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
import pytest

from sim_devices.acoustics import reverberation
from sim_devices.acoustics.reverberation import ScattererField


@pytest.fixture
def empty_shared_cache(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(reverberation, "_SHARED", OrderedDict())
    monkeypatch.setattr(reverberation, "_shared_points", 0)


@pytest.mark.usefixtures("empty_shared_cache")
def test_a_second_field_of_the_same_water_reads_the_drawn_cubes() -> None:
    a = ScattererField(density_per_m3=20.0, cube_m=0.5, seed=11).cube((1, -2, 0))
    b = ScattererField(density_per_m3=20.0, cube_m=0.5, seed=11).cube((1, -2, 0))
    assert all(p is q for p, q in zip(a, b, strict=True))
    assert not a[0].flags.writeable  # shared: nobody may change them
    # The same values as drawn afresh from the cube's own seed sequence.
    fresh = reverberation._draw_cube(20.0, 0.5, 11, (1, -2, 0))
    for p, q in zip(a, fresh, strict=True):
        np.testing.assert_array_equal(p, q)
    assert a[0].shape == (5,)  # this seed's draw of Poisson(20 · 0.125)
    other = ScattererField(density_per_m3=20.0, cube_m=0.5, seed=12).cube((1, -2, 0))
    assert not np.array_equal(other[0], a[0])


@pytest.mark.usefixtures("empty_shared_cache")
def test_the_shared_cubes_stay_within_their_scatterer_budget(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(reverberation, "_SHARED_POINTS", 500)
    field = ScattererField(density_per_m3=100.0, cube_m=1.0, seed=3)  # ~100 a cube
    counts = [field.cube((k, 0, 0))[0].shape[0] for k in range(20)]
    assert sum(counts) > 1500
    kept = reverberation._shared_points
    assert kept == sum(p[0].shape[0] for p in reverberation._SHARED.values()) <= 500
    # The most recent cubes are the ones kept.
    assert list(reverberation._SHARED)[-1] == (100.0, 1.0, 3, (19, 0, 0))
