"""Fields of the same water share their cubes process-wide, within a bounded count of
scatterers (sim_devices.acoustics.reverberation)."""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
import pytest

from hil.signals.presets import check_design, get_preset
from sim_devices.acoustics import reverberation
from sim_devices.acoustics.beam import PistonBeam, TwoWayAmplitudeTable
from sim_devices.acoustics.reverberation import (
    ReverberationSettings,
    ScattererField,
    VolumeReverberation,
)

ATT = check_design(get_preset("att").spec("random-cyclic"))


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


def resting_reverberation(seed: int = 4, scale: float = 1.0) -> VolumeReverberation:
    """A sonar at rest in 0.5 scatterers per m³ (a fresh beam table each time)."""
    beam = PistonBeam(ka=6.0)
    settings = ReverberationSettings(0.5, -70.0, 15.0, 0.5, seed=seed, frame_samples=4096)
    return VolumeReverberation(
        ATT, 100_000.0, source_amplitude_upa=1e6, reference_hz=30e3,
        sonar_position_m=(0.0, 0.0, -20.0), sonar_velocity_mps=(0.0, 0.0, 0.0),
        beam=TwoWayAmplitudeTable(beam, beam), beam_axis=(1.0, 0.2, 0.0),
        sound_speed_mps=1500.0, settings=settings, scale=scale,
    )  # fmt: skip


def test_reverberations_of_one_set_up_at_rest_share_the_insonified_scatterers(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A second reverberation of the same water, sonar and beam takes the first one's
    insonified set (no look-up of the field) and gives the same samples; another seed or
    scale is another set-up."""
    monkeypatch.setattr(reverberation, "_AT_REST", OrderedDict())
    first = resting_reverberation()
    expected = first.generate(20_000)
    assert len(reverberation._AT_REST) == 1
    looked_up: list[int] = []
    real_near = ScattererField.near

    def counted(self: ScattererField, *args: object, **kwargs: object) -> object:
        looked_up.append(1)
        return real_near(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(ScattererField, "near", counted)
    second = resting_reverberation()
    got = np.concatenate([second.generate(n) for n in (7, 9_000, 10_993)])
    assert got.tobytes() == expected.tobytes()
    assert looked_up == []
    assert second._at_rest_set is first._at_rest_set
    assert np.max(np.abs(expected)) > 0
    for other in (resting_reverberation(seed=5), resting_reverberation(scale=2.0)):
        other.generate(100)
    assert len(looked_up) == 2
    assert len(reverberation._AT_REST) == reverberation._AT_REST_SETS  # the oldest dropped
    again = resting_reverberation(scale=2.0)
    assert np.array_equal(again.generate(5_000), 2.0 * expected[:5_000])
