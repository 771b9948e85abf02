"""The vectorised and the compiled three-point peak interpolation equal the scalar one bit for
bit, for any triple (non-finite values and flat or convex triples included)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.detection import parabolic_offset, parabolic_offsets
from hil.estimation.kernels import parabolic_offset_scalar

values = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.sampled_from([0.0, -0.0, 1.0, 2.0, -1.0, 1e308, -1e308, 5e-324]),
)


@pytest.mark.slow
@settings(max_examples=500, deadline=None)
@given(st.lists(st.tuples(values, values, values), min_size=1, max_size=20))
def test_vector_equals_scalar(triples: list[tuple[float, float, float]]) -> None:
    a = np.array(triples, dtype=np.float64)
    got = parabolic_offsets(a[:, 0], a[:, 1], a[:, 2])
    want = [parabolic_offset(*t) for t in triples]
    assert np.array_equal(got, np.array(want)), (got, want)
    # Never NaN, never beyond one sample, never a negative zero.
    assert np.all(np.abs(got) <= 1.0)
    assert not any(math.copysign(1.0, v) < 0 and v == 0 for v in got.tolist())
    # The compiled scalar used by the stage-2 readout, too.
    compiled = [parabolic_offset_scalar(*t) for t in triples]
    assert np.array_equal(np.array(compiled), np.array(want)), (compiled, want)


def test_golden() -> None:
    got = parabolic_offsets(
        np.array([1.0, 0.0, 2.0, 1.0, 0.0, np.nan]),
        np.array([2.0, 3.0, 3.0, 1.0, 1.0, 1.0]),
        np.array([1.0, 2.0, 0.0, 1.0, 10.0, 0.0]),
    )
    # Symmetric peak; peak leaning right by 1/4; leaning left by 1/4... as the formula
    # 0.5·(y− − y+)/(y− − 2y0 + y+): (0 − 2)/(2·(0 − 6 + 2)) = 0.25, (2 − 0)/(2·(2 − 6 + 0))
    # = −0.25; flat → 0; convex (not a peak) → 0; NaN → 0.
    assert got.tolist() == [0.0, 0.25, -0.25, 0.0, 0.0, 0.0]
