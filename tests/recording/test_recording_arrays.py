"""load_arrays: the recording as NumPy arrays equals what was written, block by block."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.base import Estimate
from hil.recording.arrays import load_arrays
from hil.recording.records import StageTelemetry
from hil.recording.writer import RunWriter


@pytest.mark.slow
@settings(max_examples=15, deadline=None)
@given(
    blocks=st.lists(st.tuples(st.integers(0, 40), st.integers(1, 300)), min_size=1, max_size=6),
    seed=st.integers(0, 2**16),
)
def test_arrays_equal_the_blocks_written(
    tmp_path_factory: Any, schedule_doc: dict[str, Any], blocks: list[tuple[int, int]], seed: int
) -> None:
    rng = np.random.default_rng(seed)
    path = Path(tmp_path_factory.mktemp("arr")) / "run.h5"
    written, index, first = [], [], 100
    with RunWriter.create(path, fs_hz=100_000.0, n_channels=2, dtype="int16",
                          schedule_document=schedule_doc, origin_sample=100) as w:  # fmt: skip
        for skip, n in blocks:
            first += skip
            data = rng.integers(-32768, 32767, size=(n, 2), dtype=np.int16)
            w.append_samples(first, data)
            written.append(data)
            index.append(np.arange(first, first + n))
            first += n
        w.append_telemetry(StageTelemetry(1.5, 120, -2.0, -1.5, "Run"))
        w.append_estimates([Estimate(0.1, 5.0, 1.5, 3, 2.0, 10.0, 1.002, 0.05, 7, "gcas")])
    a = load_arrays(path)
    np.testing.assert_array_equal(a.samples, np.concatenate(written))
    np.testing.assert_array_equal(a.sample_index, np.concatenate(index))
    np.testing.assert_allclose(a.time_s, (np.concatenate(index) - 100) / 100_000.0)
    expected_gaps = [(int(s), int(e - s)) for s, e in zip(a.sample_index[:-1], a.sample_index[1:],
                                                            strict=True) if e - s > 1]  # fmt: skip
    assert a.gaps == [(s + 1, n - 1) for s, n in expected_gaps]
    assert a.telemetry["position_m"].tolist() == [-2.0] and a.telemetry["state"].tolist() == ["Run"]
    assert a.estimates["range_m"].tolist() == [5.0] and a.estimates["receiver"].tolist() == ["gcas"]
