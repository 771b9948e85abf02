"""Waveform families, presets and the design checks."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import hilbert

from hil.errors import ConfigError
from hil.signals.costas import is_costas
from hil.signals.presets import PRESETS, check_design, get_preset
from hil.signals.synthesis import synthesize
from hil.signals.waveforms import FAMILIES, WaveformSpec, build_schedule, doppler_scale


def _inst_freq(x: np.ndarray, fs: float) -> np.ndarray:
    phase = np.unwrap(np.angle(hilbert(x)))
    return np.diff(phase) * fs / (2 * np.pi)


@pytest.mark.parametrize("preset", list(PRESETS))
@pytest.mark.parametrize("family", FAMILIES)
def test_every_preset_family_passes_its_checks(preset: str, family: str) -> None:
    spec = get_preset(preset).spec(family)
    sch = check_design(spec)
    assert sch.family == family
    assert sch.unambiguous_range_m(spec.sound_speed_mps) >= spec.max_range_m
    assert spec.fs_hz > 2 * sch.max_frequency_hz()


def test_spec_section6_products() -> None:
    # SPEC §6: 4.4 kHz/3 × 15 ms = 22; 4.4 kHz/4 × 10 ms = 11.
    three = check_design(get_preset("att").spec("three-state"))
    four = check_design(get_preset("att").spec("random-cyclic"))
    assert np.diff(three.tones_hz)[0] * three.hop_s == pytest.approx(22.0)
    assert np.diff(four.tones_hz)[0] * four.hop_s == pytest.approx(11.0)
    assert four.period_hops == 17 and four.n_tones == 4
    assert three.period_hops == 32  # L_c = 5


def test_fmcw_instantaneous_frequency_follows_the_sweep() -> None:
    fs = 100_000.0
    for family in ("fmcw-saw", "fmcw-tri"):
        spec = get_preset("att").spec(family)
        sch = build_schedule(spec)
        x = synthesize(sch, fs, 2 * sch.period_s)
        f = _inst_freq(x, fs)
        t = (np.arange(f.shape[0]) + 0.5) / fs
        lo, hi = spec.center_hz - spec.bandwidth_hz / 2, spec.center_hz + spec.bandwidth_hz / 2
        rate = spec.bandwidth_hz / spec.sweep_s
        if family == "fmcw-saw":
            expect = lo + rate * np.mod(t, spec.sweep_s)
        else:
            tau = np.mod(t, 2 * spec.sweep_s)
            expect = np.where(tau < spec.sweep_s, lo + rate * tau, hi - rate * (tau - spec.sweep_s))
        # Away from the sweep turn-arounds and the Hilbert edge effects.
        edge = np.minimum(np.mod(t, spec.sweep_s), spec.sweep_s - np.mod(t, spec.sweep_s))
        keep = (edge > 0.005) & (t > 0.01) & (t < t[-1] - 0.01)
        np.testing.assert_allclose(f[keep], expect[keep], atol=2.0)


def test_hop_tones_measured_by_fft() -> None:
    spec = get_preset("att").spec("random-cyclic")
    sch = build_schedule(spec)
    fs = 100_000.0
    x = synthesize(sch, fs, sch.period_s)
    n_hop = int(round(sch.hop_s * fs))
    for k in range(sch.period_hops):
        seg = x[k * n_hop : (k + 1) * n_hop]
        spec_mag = np.abs(np.fft.rfft(seg))
        peak = np.argmax(spec_mag) * fs / n_hop
        assert peak == pytest.approx(sch.tones_hz[sch.code[k]], abs=fs / n_hop / 2)


def test_costas_families() -> None:
    spec = get_preset("att").spec("costas")
    sch = build_schedule(spec)
    assert sch.n_tones == 10 and is_costas(sch.code)
    lfm = build_schedule(get_preset("att").spec("costas-lfm"))
    df = np.diff(lfm.tones_hz)[0]
    np.testing.assert_allclose(lfm.chirp_hz_per_s, df / lfm.hop_s)
    np.testing.assert_allclose(lfm.freq_hz, lfm.tones_hz[lfm.code] - df / 2)


def test_pulses_are_silent_between_pulses() -> None:
    for family in ("cw-pulse", "lfm-pulse"):
        spec = get_preset("att").spec(family)
        sch = build_schedule(spec)
        x = synthesize(sch, 100_000.0, 2 * spec.pri_s)
        on = int(spec.pulse_s * 100_000)
        pri = int(spec.pri_s * 100_000)
        assert np.all(x[on + 1 : pri] == 0.0)
        assert np.max(np.abs(x[:on])) > 0.99
        np.testing.assert_allclose(x[:on], x[pri : pri + on], atol=1e-9)  # phase restarts


def test_doppler_scale_reference_values() -> None:
    assert doppler_scale(10.0, 1500.0) == pytest.approx(1.013423, abs=1e-6)
    assert doppler_scale(25.72, 1500.0) == pytest.approx(1.03490, abs=1e-5)
    with pytest.raises(ConfigError, match=r"speed_mps = 1500\.0"):
        doppler_scale(1500.0, 1500.0)


@pytest.mark.parametrize(
    ("preset", "family", "overrides", "field", "fragment"),
    [
        ("att", "three-state", {"n_tones": 2}, "n_tones", "exactly 3"),
        (
            "att",
            "three-state",
            {"order": 3},
            "max_range_m",
            "unambiguous range c·period/2 = 90.00 m",
        ),
        ("att", "random-cyclic", {"hop_s": 0.0105}, "hop_s", "Δf·T_h = 11.55"),
        ("att", "random-cyclic", {"fs_hz": 60_000.0}, "fs_hz", "Nyquist"),
        ("att", "random-cyclic", {"min_speed_mps": 1.0}, "min_speed_mps", "resolution cell"),
        ("att", "random-cyclic", {"hop_s": -0.01}, "hop_s", "> 0 s"),
        ("att", "random-cyclic", {"window": 2}, "window", "distinct windows"),
        ("att", "fmcw-saw", {"sweep_s": -1.0}, "sweep_s", "> 0 s"),
        ("att", "cw-pulse", {"pri_s": 0.005}, "pri_s", "> pulse_s"),
        ("tank-audio", "random-cyclic", {"sound_speed_mps": 0.0}, "sound_speed_mps", "> 0 m/s"),
        ("tank-board", "random-cyclic", {"max_speed_mps": 2000.0}, "max_speed_mps", "v < c"),
    ],
)
def test_design_violations_name_the_field(
    preset: str, family: str, overrides: dict, field: str, fragment: str
) -> None:
    with pytest.raises(ConfigError) as info:
        check_design(get_preset(preset).spec(family, **overrides))
    assert info.value.field == field
    assert fragment in str(info.value)


def test_unknown_preset_family_and_override() -> None:
    with pytest.raises(
        ConfigError,
        match="preset = 'pool' is not allowed: must be one of att, tank-audio, tank-board",
    ):
        get_preset("pool")
    with pytest.raises(ConfigError, match="family = 'chirp'"):
        get_preset("att").spec("chirp")
    with pytest.raises(ConfigError, match="override"):
        WaveformSpec().with_overrides(colour="blue")
