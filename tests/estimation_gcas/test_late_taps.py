"""The direct path's amplitude with the late paths fitted as nuisance taps
(hil.estimation.late_taps): exact on a noise-free sum of switches, and its refusals."""

from __future__ import annotations

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.estimation.first_arrival import (
    LATE_TAP_MIN_SPEED_MPS,
    LATE_TAP_RATIO,
    FirstArrivalReadout,
)
from hil.estimation.late_taps import LEAD_S, direct_amplitudes
from hil.signals.presets import check_design, get_preset

FS = 192_000.0
LEAD = int(round(LEAD_S * FS))
N = LEAD + 39  # 0.2 ms after the onset
#: f_prev, f_cur, f_next of three boundaries, Hz (the tank-audio grid, 2 kHz apart).
FREQS = np.array([[57e3, 61e3, 63e3], [61e3, 59e3, 57e3], [63e3, 57e3, 59e3]])


def _tone_switch(i: np.ndarray, at: float, f_old: float, f_new: float) -> np.ndarray:
    """A unit tone f_old -> f_new at sample ``at`` (from then on f_new), phase-continuous,
    absolute samples ``i``: written out sample by sample's formula, not the module's code."""
    w_old, w_new = 2 * np.pi * f_old / FS, 2 * np.pi * f_new / FS
    out = np.exp(1j * w_new * i).astype(np.complex128)
    before = i < at
    out[before] = np.exp(1j * (w_new * at + w_old * (i[before] - at)))
    return out


def _scene(
    direct: np.ndarray, late: np.ndarray, late_at: np.ndarray, onset: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Samples (3, N) and first indices of three boundaries: the direct path's switch at
    ``onset``, one late path's f_prev -> f_cur at ``late_at`` (absolute samples), a steady
    f_cur and f_prev of other paths."""
    first = np.ceil(onset).astype(np.int64) - LEAD
    rows = []
    for k, (f_prev, f_cur, f_next) in enumerate(FREQS):
        i = first[k] + np.arange(N)
        x = (
            direct[k] * _tone_switch(i, onset[k], f_cur, f_next)
            + late[k] * _tone_switch(i, late_at[k], f_prev, f_cur)
            + (0.7 - 0.2j) * np.exp(2j * np.pi * f_cur / FS * i)
            + (0.3 + 0.4j) * np.exp(2j * np.pi * f_prev / FS * i)
        )
        rows.append(x.real)
    return np.array(rows), first


def test_the_direct_amplitude_is_exact_with_a_late_switch_ahead_of_it() -> None:
    """A late path 1.4 times the direct path's amplitude switching 0.15 ms before it (the
    built-in tank at order 3): the fit returns the direct path's complex amplitude to 1e-6,
    its taps hold more power than the readout's gate; the direct path's model alone on its
    first 0.2 ms is off by a tenth or more."""
    rng = np.random.default_rng(7)
    onset = np.array([1_000_000.3, 1_001_920.6, 1_003_840.1])
    direct = np.exp(1j * rng.uniform(0, 2 * np.pi, 3))
    late = 1.4 * np.exp(1j * rng.uniform(0, 2 * np.pi, 3))
    late_at = np.ceil(onset) - 29
    y, first = _scene(direct, late, late_at, onset)
    fit = direct_amplitudes(y, first, onset, FREQS.T.copy(), np.zeros((2, 3)), 1.0, FS, LEAD)
    np.testing.assert_allclose(fit.amplitude, direct, atol=1e-6)
    assert fit.late_ratio > LATE_TAP_RATIO
    # The direct path's own model alone on its first 0.2 ms: what the nuisance costs.
    i = first[:, None] + np.arange(N)[None, :]
    after = i >= np.ceil(onset)[:, None]
    u = np.where(after, np.exp(2j * np.pi * FREQS[:, 2:3] / FS * i), 0)
    alone = 2 * np.sum(y * np.conj(u), axis=1) / np.sum(after, axis=1)
    assert np.max(np.abs(alone - direct)) > 0.1


def test_without_late_paths_the_late_taps_stay_below_the_readouts_gate() -> None:
    """No late path: the direct path's amplitude is exact, and the taps the fit adds anyway
    (their gains partly cancel each other) hold less power than the readout's gate."""
    onset = np.array([2_000_000.0, 2_001_920.5, 2_003_840.9])
    direct = np.array([1.0, 1j, -0.5 + 0.5j])
    y, first = _scene(direct, np.zeros(3), onset - 50, onset)
    fit = direct_amplitudes(y, first, onset, FREQS.T.copy(), np.zeros((2, 3)), 1.0, FS, LEAD)
    np.testing.assert_allclose(fit.amplitude, direct, atol=1e-6)
    assert fit.late_ratio < LATE_TAP_RATIO


def test_a_stretch_that_does_not_reach_past_the_onset_is_refused() -> None:
    y = np.zeros((3, N))
    with pytest.raises(
        ConfigError,
        match=r"lead = 200 is not allowed: must be 1 \.\. 191 samples \(the stretch holds 193\)",
    ):
        direct_amplitudes(
            y, np.zeros(3, np.int64), np.full(3, 200.0), FREQS.T.copy(), np.zeros((2, 3)),
            1.0, FS, 200,
        )  # fmt: skip


def test_tables_of_another_boundary_count_are_refused() -> None:
    y = np.zeros((3, N))
    with pytest.raises(ConfigError, match=r"shapes \(3, 3\), \(2, 3\), \(3,\) for 3 boundaries"):
        direct_amplitudes(
            y, np.zeros(3, np.int64), np.full(3, 200.0), FREQS.T[:, :2].copy(), np.zeros((2, 3)),
            1.0, FS, LEAD,
        )  # fmt: skip


@pytest.mark.parametrize(
    ("speed_mps", "cancel_period", "reads"),
    [
        (LATE_TAP_MIN_SPEED_MPS + 0.01, False, True),
        (-(LATE_TAP_MIN_SPEED_MPS + 0.01), False, True),
        (LATE_TAP_MIN_SPEED_MPS - 0.01, False, False),
        (0.0, False, False),
        (1.5, True, False),
    ],
)
def test_the_second_reading_is_tried_for_a_moving_target_and_no_canceller_only(
    speed_mps: float, cancel_period: bool, reads: bool
) -> None:
    """The check before the fit: GCAS's speed (closing or opening) at least
    LATE_TAP_MIN_SPEED_MPS (1 m/s), and no period canceller."""
    c = 1482.3
    schedule = check_design(get_preset("tank-audio").spec("random-cyclic"))
    readout = FirstArrivalReadout(schedule, FS, 10, c, cancel_period=cancel_period)
    alpha = (c + speed_mps) / (c - speed_mps)
    assert LATE_TAP_MIN_SPEED_MPS == 1.0
    assert readout._reads_late_taps(alpha) is reads
