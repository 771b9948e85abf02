"""Volume reverberation: the cell synthesis against the exact sum, levels, statistics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import hilbert

from hil.signals.presets import check_design, get_preset
from hil.signals.schedule import HopSchedule
from sim_devices.acoustics.beam import (
    OmniBeam,
    PistonBeam,
    TwoWayAmplitudeTable,
    equivalent_two_way_beam_angle,
)
from sim_devices.acoustics.channel import source_amplitude
from sim_devices.acoustics.reverberation import (
    ReverberationSettings,
    VolumeReverberation,
    exact_reverberation,
)

FS = 100_000.0
C = 1500.0
SL = 200.0
SV = -60.0
TAU = 0.001


def _reverb(waveform, settings, velocity=(0.0, 0.0, 0.0), beam=None) -> VolumeReverberation:
    b = beam or OmniBeam()
    return VolumeReverberation(
        waveform, FS, source_amplitude_upa=source_amplitude(SL), reference_hz=30_000.0,
        sonar_position_m=(0.0, 0.0, -50.0), sonar_velocity_mps=velocity,
        beam=TwoWayAmplitudeTable(b, b), beam_axis=(1.0, 0.0, 0.0), sound_speed_mps=C,
        settings=settings,
    )  # fmt: skip


def _att() -> HopSchedule:
    return check_design(get_preset("att").spec("random-cyclic"))


@pytest.mark.parametrize("speed", [0.0, 10.0])
def test_cells_match_the_exact_per_scatterer_sum(speed: float) -> None:
    st = ReverberationSettings(
        density_per_m3=0.002, scattering_strength_db=SV, max_range_m=14.0, min_range_m=2.0,
        seed=5, frame_samples=2048,
    )  # fmt: skip
    rev = _reverb(_att(), st, (speed, 0.0, 0.0))
    n = 6000
    approx = rev.generate(n)
    x, y, z = rev.scatterers_at(0.03)
    assert 5 <= x.size <= 60
    exact = exact_reverberation(rev, x, y, z, np.arange(n) / FS)
    err_db = 10 * np.log10(np.sum((approx - exact) ** 2) / np.sum(exact**2))
    assert err_db < -20.0, err_db


def test_any_chunking_gives_the_same_samples() -> None:
    st = ReverberationSettings(0.01, SV, 20.0, 2.0, seed=1, frame_samples=1024)
    whole = _reverb(_att(), st, (3.0, 1.0, 0.0)).generate(9000)
    rev = _reverb(_att(), st, (3.0, 1.0, 0.0))
    parts = np.concatenate([rev.generate(k) for k in (1, 999, 4000, 0, 4000)])
    assert np.array_equal(whole, parts)


def test_a_sonar_at_rest_gives_the_bits_of_the_general_geometry() -> None:
    """At rest, the scatterers' ranges, cull and amplitudes are kept from frame to frame and
    only the emission times move: the same samples, bit for bit, as solving each frame's
    geometry afresh (the path a moving sonar takes)."""
    st = ReverberationSettings(0.01, SV, 20.0, 2.0, seed=4, frame_samples=1024)
    kept = _reverb(_att(), st)
    afresh = _reverb(_att(), st)
    assert kept._at_rest
    afresh._at_rest = False
    a = np.concatenate([kept.generate(k) for k in (700, 3000, 5300)])
    b = afresh.generate(9000)
    assert np.array_equal(a, b) and np.any(a != 0.0)


def _cw_pulse() -> HopSchedule:
    return HopSchedule.from_segments(
        "cw-pulse", [30_000.0], [0, -1], [TAU, 0.05 - TAU], continuous_phase=False
    )


def _ensemble_ratio(beam, density: float, seeds: int) -> tuple[float, float]:
    """Mean of measured/expected intensity, and the scintillation index of I/expected."""
    psi = equivalent_two_way_beam_angle(beam, beam)
    n = int(0.04 * FS)
    t = np.arange(n) / FS
    r = C * (t - TAU / 2) / 2
    sel = (r > 8.0) & (r < 26.0)
    rl = SL - 40 * np.log10(r[sel]) + SV + 10 * np.log10(C * TAU / 2 * psi * r[sel] ** 2)
    expected = 10 ** (rl / 10)
    ratios, intensities = [], []
    for seed in range(seeds):
        st = ReverberationSettings(
            density, SV, 30.0, 4.0, seed=seed, frame_samples=4096, beam_floor_db=-90.0
        )
        y = _reverb(_cw_pulse(), st, beam=beam).generate(n)
        ratios.append(y[sel] ** 2 / expected)
        intensities.append(np.abs(hilbert(y))[sel] ** 2 / 2 / expected)
    i_all = np.concatenate(intensities)
    return float(np.mean(np.concatenate(ratios))), float(np.var(i_all) / np.mean(i_all) ** 2)


@pytest.mark.parametrize("beam", [OmniBeam(), PistonBeam(ka=6.0)], ids=["omni", "piston"])
def test_mean_reverberation_level_matches_the_formula(beam) -> None:
    ratio, _ = _ensemble_ratio(beam, 0.05 if isinstance(beam, OmniBeam) else 0.5, 12)
    assert abs(10 * math.log10(ratio)) < 0.5


def test_scintillation_index_tends_to_one_for_dense_scatterers() -> None:
    _, dense = _ensemble_ratio(OmniBeam(), 0.1, 6)
    _, sparse = _ensemble_ratio(OmniBeam(), 0.0005, 6)
    assert abs(dense - 1.0) < 0.2
    assert sparse > 1.4
    assert sparse > dense


def test_expected_power_is_the_sum_of_scatterer_powers() -> None:
    st = ReverberationSettings(0.01, SV, 20.0, 2.0, seed=2)
    rev = _reverb(_att(), st)
    x, _, _ = rev.scatterers_at(0.0)
    assert x.size > 100
    rev2 = _reverb(_att(), ReverberationSettings(0.01, SV + 10.0, 20.0, 2.0, seed=2))
    assert rev2.expected_power(0.0) == pytest.approx(10 * rev.expected_power(0.0), rel=1e-12)


def test_bad_settings_name_the_field() -> None:
    with pytest.raises(Exception, match=r"reverberation.max_range_m = 1.0 .*> min_range_m"):
        ReverberationSettings(0.01, SV, 1.0, 2.0)
    with pytest.raises(Exception, match=r"reverberation.density_per_m3 = -1"):
        ReverberationSettings(-1, SV, 10.0)
