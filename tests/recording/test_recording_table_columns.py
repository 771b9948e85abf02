"""``RunRecording.table_columns``: rows from a start row as column arrays, for readers that
follow a growing recording (``hil watch``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.recording.reader import RunRecording
from hil.recording.writer import RunWriter

FS = 100_000.0


def _estimate(i: int) -> Estimate:
    return Estimate(0.01 * i, 5.0 + i, -1.0, i, 1.0, 10.0, 1.0, 0.01 * i - 0.007, i % 17, "gcas")


def test_chunks_from_start_rows_equal_the_whole(
    tmp_path: Path, schedule_doc: dict[str, Any]
) -> None:
    path = tmp_path / "run.h5"
    with RunWriter.create(
        path, fs_hz=FS, n_channels=1, dtype="int16", schedule_document=schedule_doc
    ) as w:
        w.append_estimates([_estimate(i) for i in range(10)])
    with RunRecording.open(path) as rec:
        whole = rec.table_columns("estimates")
        assert whole["range_m"].tolist() == [5.0 + i for i in range(10)]
        assert whole["receiver"].tolist() == ["gcas"] * 10
        parts = [rec.table_columns("estimates", start, ("t_s", "codeword")) for start in (0, 4, 7)]
        got = np.concatenate(
            [parts[0]["codeword"][:4], parts[1]["codeword"][:3], parts[2]["codeword"]]
        )
        assert got.tolist() == whole["codeword"].tolist()
        assert set(parts[0]) == {"t_s", "codeword"}
        assert rec.table_columns("estimates", 10)["t_s"].tolist() == []
        assert rec.table_columns("estimates", 99)["t_s"].tolist() == []


def test_unknown_tables_and_columns_are_refused(
    tmp_path: Path, schedule_doc: dict[str, Any]
) -> None:
    path = tmp_path / "run.h5"
    with RunWriter.create(
        path, fs_hz=FS, n_channels=1, dtype="int16", schedule_document=schedule_doc
    ):
        pass
    with RunRecording.open(path) as rec:
        with pytest.raises(
            ConfigError,
            match=r"^table = 'estimate' is not allowed: must be one of segments, flushes, "
            r"sync, telemetry, events, estimates$",
        ):
            rec.table_columns("estimate")
        with pytest.raises(
            ConfigError,
            match=r"^sync column = 'time' is not allowed: must be one of sample_index, "
            r"host_time_s$",
        ):
            rec.table_columns("sync", 0, ("time",))
