"""Ambiguity functions: normalisation, peak at the origin, known shapes."""

from __future__ import annotations

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.signals.ambiguity import narrowband_af, periodic_af, wideband_af
from hil.signals.presets import get_preset
from hil.signals.schedule import HopSchedule
from hil.signals.waveforms import FAMILIES, build_schedule


@pytest.mark.parametrize("family", FAMILIES)
def test_af_peaks_at_origin_with_value_one(family: str) -> None:
    sch = build_schedule(get_preset("att").spec(family))
    span = min(sch.period_s, 0.25)
    nb = narrowband_af(sch, 20_000.0, span, 0.004, np.linspace(-300, 300, 13))
    d, nu, peak = nb.peak()
    assert (d, nu) == (0.0, 0.0)
    assert peak == pytest.approx(1.0, abs=1e-12)
    wb = wideband_af(sch, 20_000.0, span, 0.004, np.linspace(0.98, 1.02, 9))
    d, alpha, peak = wb.peak()
    assert (d, alpha) == (0.0, 1.0)
    assert peak == pytest.approx(1.0, abs=1e-12)


def test_cw_pulse_af_golden_shape() -> None:
    # A rectangular CW pulse of length T: |χ(τ, 0)| = 1 − |τ|/T and |χ(0, ν)| = |sinc(νT)|.
    T = 0.01
    sch = HopSchedule.from_segments("cw", [1000.0], [0, -1], [T, 0.09], continuous_phase=False)
    fs = 100_000.0
    nb = narrowband_af(sch, fs, 0.1, 0.008, [0.0, 50.0, 100.0, 150.0])
    tau = nb.delay_s
    np.testing.assert_allclose(nb.magnitude[0], np.clip(1 - np.abs(tau) / T, 0, None), atol=1e-3)
    centre = np.argmin(np.abs(tau))
    np.testing.assert_allclose(
        nb.magnitude[1:, centre], np.abs(np.sinc([0.5, 1.0, 1.5])), atol=2e-3
    )


def test_costas_af_sidelobes_below_one_over_n() -> None:
    # Costas property: off-origin grid points (delay k·T_h, Doppler m/T_h) hold at most one
    # coincidence out of n, so |χ| <= 1/n there.
    sch = build_schedule(get_preset("att").spec("costas"))
    n, hop = sch.n_tones, sch.hop_s
    fs = 8 * float(np.diff(sch.tones_hz)[0]) * n
    dop = np.arange(-3, 4) / hop
    pulse = HopSchedule.from_segments(
        "costas-pulse",
        sch.tones_hz,
        [*sch.code.tolist(), -1],
        [*([hop] * n), n * hop],
        continuous_phase=False,
    )
    af = narrowband_af(pulse, fs, n * hop * 2, 3 * hop, dop)
    grid = np.round(af.delay_s / hop, 9)
    on_grid = np.isclose(grid, np.round(grid))
    mags = af.magnitude[:, on_grid]
    origin = (dop[:, None] == 0) & (np.round(grid[on_grid])[None, :] == 0)
    assert mags[origin].item() == pytest.approx(1.0)
    assert mags[~origin].max() <= 1.0 / n + 0.02


def test_wideband_equals_narrowband_at_unit_scale() -> None:
    sch = build_schedule(get_preset("att").spec("random-cyclic"))
    nb = narrowband_af(sch, 20_000.0, 0.17, 0.003, [0.0])
    wb = wideband_af(sch, 20_000.0, 0.17, 0.003, [1.0])
    np.testing.assert_allclose(nb.magnitude, wb.magnitude, atol=1e-12)


def test_periodic_af_of_continuous_code() -> None:
    sch = build_schedule(get_preset("att").spec("random-cyclic"))
    paf = periodic_af(sch, 20_000.0)
    assert paf.magnitude.shape == (9, 3400)
    assert paf.peak()[2] == pytest.approx(1.0)
    # A cyclic shift by one whole hop leaves at most the coincident hops: < 1.
    one_hop = int(round(sch.hop_s * 20_000.0))
    assert paf.magnitude[4, one_hop] < 0.5
    with pytest.raises(ConfigError, match="whole number of samples per period"):
        periodic_af(sch, 20_001.0)


def test_bad_af_arguments() -> None:
    sch = build_schedule(get_preset("att").spec("random-cyclic"))
    with pytest.raises(ConfigError, match=r"fs_hz = -1\.0"):
        narrowband_af(sch, -1.0, 0.1, 0.01, [0.0])
    with pytest.raises(ConfigError, match="span_s"):
        narrowband_af(sch, 1000.0, 0.0001, 0.01, [0.0])
    with pytest.raises(ConfigError, match="scales"):
        wideband_af(sch, 1000.0, 0.1, 0.01, [0.0])
