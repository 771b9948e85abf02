"""The count of Doppler hypotheses, checked in one place for every receiver with a Doppler
grid (:func:`hil.estimation.doppler_grid.check_n_doppler`): GCAS's grid, the matched-filter
bank and JIFS refuse the same values with the same words."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.estimation.doppler_grid import MAX_HYPOTHESES, check_n_doppler, doppler_grid


@pytest.mark.parametrize(
    ("value", "count"), [(1, 1), (64, 64), (np.int32(15), 15), (64.0, 64), (4096, 4096)]
)
def test_a_whole_count_up_to_the_largest_is_taken(value: Any, count: int) -> None:
    taken = check_n_doppler(value)
    assert taken == count and type(taken) is int


@pytest.mark.parametrize("value", [0, -4, 4097, 10**8, 2.5, float("nan"), True, "64", None])
def test_anything_else_is_refused_naming_the_range(value: Any) -> None:
    with pytest.raises(ConfigError) as refused:
        check_n_doppler(value)
    assert str(refused.value) == (
        f"n_doppler = {value!r} is not allowed: must be an integer in 1 .. {MAX_HYPOTHESES};"
        " hypotheses closer than the Doppler resolution add nothing: leave it out for the"
        " receiver's default"
    )


def test_gcas_s_grid_takes_the_checked_count() -> None:
    grid = doppler_grid(30.0, 5.0, 1500.0, 0.01, 10_000.0)  # a whole float is a count
    assert grid.speeds_mps.tolist() == [-30.0, -15.0, 0.0, 15.0, 30.0]
    with pytest.raises(ConfigError, match=r"^n_doppler = 4097 is not allowed: must be an"):
        doppler_grid(30.0, 4097, 1500.0, 0.01, 10_000.0)
