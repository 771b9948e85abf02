"""The compiled per-scatterer loops of a stationary reverberation frame give the NumPy form's
values bit for bit (sim_devices.acoustics.reverb_kernels)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_devices.acoustics.reverb_kernels import delays_and_phases, weighted_trains

FS = 192_000.0
PHASE_PER_SAMPLE = -2.0 * math.pi * 30_000.0 / FS
K_MAX = 3349


def numpy_trains(
    t_c: float, emit_s: np.ndarray, amp: np.ndarray, alpha_b: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The NumPy form: delays, phases, and the weights summed per whole-sample delay."""
    delay = (t_c - emit_s) / alpha_b * FS
    k = np.rint(delay)
    frac = delay - k
    phase = (PHASE_PER_SAMPLE * (alpha_b * frac)).astype(np.float32)
    re = np.bincount(k.astype(np.int64), amp * np.cos(phase), K_MAX + 1)
    im = np.bincount(k.astype(np.int64), amp * np.sin(phase), K_MAX + 1)
    return k.astype(np.int64), phase, re, im


@pytest.mark.parametrize(("alpha_b", "seed"), [(1.0, 1), (1.0, 2), (1.0000137, 3), (0.99991, 4)])
def test_compiled_loops_equal_the_numpy_form_bit_for_bit(alpha_b: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    m = 20_000
    t_c = 3.217 + seed
    # Two-way delays up to 3000 samples; many scatterers share a whole-sample delay.
    emit_s = t_c - rng.uniform(0.0, 3000.0 / FS, m)
    amp = rng.uniform(1e-3, 1.0, m) * 1e4
    k_ref, phase_ref, re_ref, im_ref = numpy_trains(t_c, emit_s, amp, alpha_b)
    k = np.empty(m, dtype=np.int64)
    phase = np.empty(m, dtype=np.float32)
    k_lo, k_hi = delays_and_phases(
        t_c, emit_s, alpha_b, alpha_b == 1.0, FS, PHASE_PER_SAMPLE, k, phase
    )
    assert (k_lo, k_hi) == (int(k_ref.min()), int(k_ref.max()))
    np.testing.assert_array_equal(k, k_ref)
    assert phase.tobytes() == phase_ref.tobytes()
    re, im = np.zeros(K_MAX + 1), np.zeros(K_MAX + 1)
    weighted_trains(k, amp, np.cos(phase), np.sin(phase), re, im)
    assert re.tobytes() == re_ref.tobytes() and im.tobytes() == im_ref.tobytes()
    assert np.count_nonzero(re) > 2000  # the sums did add many scatterers per cell


def test_the_delay_span_comes_back_for_the_range_check() -> None:
    k = np.empty(2, dtype=np.int64)
    phase = np.empty(2, dtype=np.float32)
    emit = np.array([1.0 - 10.0 / FS, 1.0 + 2.0 / FS])  # the second arrives before emission
    assert delays_and_phases(1.0, emit, 1.0, True, FS, PHASE_PER_SAMPLE, k, phase) == (-2, 10)
