"""Rayleigh reflection coefficient: arlpy's documented values and physical limits."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from sim_devices.acoustics.reflection import reflection_coeff


def test_arlpy_values() -> None:
    v0 = reflection_coeff(0.0, 1200.0, 1600.0, 0.0, 1023.0, 1540.0)
    v1 = reflection_coeff(0.5, 1200.0, 1600.0, 0.2, 1023.0, 1540.0)
    assert isinstance(v0, complex) and isinstance(v1, complex)
    assert round(v0.real, 4) == 0.0986 and v0.imag == 0.0
    assert (round(v1.real, 4), round(v1.imag, 4)) == (0.0855, -0.1278)


def test_normal_incidence_is_the_impedance_contrast() -> None:
    z1, z = 1800.0 * 1700.0, 1000.0 * 1480.0
    v = reflection_coeff(0.0, 1800.0, 1700.0, 0.0, 1000.0, 1480.0)
    assert v == pytest.approx((z1 - z) / (z1 + z), rel=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 1.0), st.floats(1510.0, 3000.0), st.floats(1100.0, 2500.0))
def test_total_reflection_beyond_the_critical_angle(frac: float, c1: float, rho1: float) -> None:
    critical = np.arcsin(1500.0 / c1)
    angle = critical + frac * (np.pi / 2 - critical) * 0.999 + 1e-6
    v = reflection_coeff(angle, rho1, c1, 0.0, 1000.0, 1500.0)
    assert abs(v) == pytest.approx(1.0, abs=1e-9)


def test_array_of_angles() -> None:
    v = reflection_coeff(np.array([0.0, 0.5, 1.0]), 1200.0, 1600.0, 0.1)
    assert isinstance(v, np.ndarray) and v.shape == (3,) and v.dtype == np.complex128
    assert v[1] == reflection_coeff(0.5, 1200.0, 1600.0, 0.1)


def test_angle_beyond_grazing_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"angle_rad = 2\.0 is not allowed: must be 0 to 1\.5708"):
        reflection_coeff(2.0, 1200.0, 1600.0)


def test_non_positive_density_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"rho1 = -1200\.0 is not allowed: must be > 0 kg/m³"):
        reflection_coeff(0.0, -1200.0, 1600.0)
