"""Chunks == whole for the GCAS receiver in volume reverberation: the same input whole, in
997- and 10 000-sample blocks and at random cuts gives the same estimates, the same Peaks
(every field, bit for bit) and the same refusals, the reverberation band on and off.

The scene is test_scenes' still target at 40 m, 0 dB per-sample SNR, with volume
reverberation at 0 dB SRR from 1 m (a diffuse patch at 0.3 scatterers/m³, a few scatterers per
range cell at 0.01), 2 s; the Peaks are what the search hands the readout, before any
refinement rounds them away.
"""

from __future__ import annotations

import functools
import itertools
from typing import Any

import numpy as np
import pytest

from hil.estimation.gcas.threshold import Peak
from tests.estimation_gcas.conftest import block_edges
from tests.estimation_gcas.test_scenes import _motion_input, _receiver

#: The cut lists besides the whole input: fixed blocks, then random cuts (seeded).
BLOCKS = (997, 10_000)
RANDOM_CUTS = (0, 1, 2)


@functools.lru_cache(maxsize=2)
def _scene(density_per_m3: float) -> np.ndarray:
    """The 2 s input (shape ``(200 000,)``), made once per density."""
    x, _ = _motion_input("still", 0.0, 0.0, 4, min_range_m=1.0, density_per_m3=density_per_m3)
    return x


def _run(x: np.ndarray, edges: list[int], band: bool) -> dict[str, Any]:
    """The receiver's estimates, the Peaks its search gave the readout, its refusals and
    notices, with ``x`` fed in the blocks between ``edges``."""
    rx = _receiver(**({} if band else {"reverb_speed_mps": 0.0}))
    peaks: list[Peak] = []
    decide_all = rx.readout.decide_all

    def recording(found: Any, residual: bool = False) -> Any:
        found = list(found)
        peaks.extend(found)
        return decide_all(found, residual)

    rx.readout.decide_all = recording  # type: ignore[method-assign]
    est = []
    for a, b in itertools.pairwise(edges):
        est += rx.process(x[a:b])
    est += rx.flush()
    return {"estimates": est, "peaks": peaks, "refusals": rx.refusals(), "notices": rx.notices()}


def _check(density_per_m3: float, band: bool, cuts: tuple[int | str, ...]) -> dict[str, Any]:
    """Assert every cut list of ``cuts`` gives what the whole input gives; the whole run."""
    x = _scene(density_per_m3)
    whole = _run(x, [0, x.shape[0]], band)
    for cut in cuts:
        parts = _run(x, block_edges(x.shape[0], cut), band)
        for key, value in whole.items():
            assert parts[key] == value, (key, cut)
    return whole


@pytest.mark.slow
@pytest.mark.parametrize("band", [True, False], ids=["band-on", "band-off"])
@pytest.mark.parametrize("density_per_m3", [0.3, 0.01])
def test_reverberation_chunks_equal_whole(density_per_m3: float, band: bool) -> None:
    cuts = (*BLOCKS, *(f"random-{s}" for s in RANDOM_CUTS))
    whole = _check(density_per_m3, band, cuts)
    # Measured (Peaks, estimates): band on 999, 0 (0.3) and 930, 0 (0.01); band off 512, 115
    # (0.3) and 514, 189 (0.01).
    assert len(whole["peaks"]) > 500
    assert band or len(whole["estimates"]) > 100
    if band and density_per_m3 == 0.3:
        # The diffuse patch with the band on (its 997-sample blocks among the cuts above):
        # measured 999 Peaks, 366 refused on the band's edge, no estimate (a still target).
        assert len(whole["peaks"]) > 900 and whole["refusals"]["in_band"] > 300
