"""run.h5 carries units and NeXus-style attributes a generic viewer (h5web, silx) plots from,
and the writer logs what happens on the stream."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from hil.estimation.base import Estimate
from hil.recording.reader import RunRecording
from hil.recording.records import RunEvent
from hil.recording.writer import RunWriter

FS = 100_000.0


def _write(path: Path, doc: dict[str, Any], dtype: str) -> None:
    clock = iter(np.arange(0.0, 100.0, 0.25)).__next__
    with RunWriter.create(path, fs_hz=FS, n_channels=2, dtype=dtype, schedule_document=doc,
                          clock=clock) as w:  # fmt: skip
        w.append_samples(0, np.ones((1000, 2), dtype=dtype))
        w.append_samples(1500, np.ones((500, 2), dtype=dtype))  # a gap of 500 samples
        w.append_event(RunEvent("alarm", 1600, 0, "stage alarm 1"))
        w.append_estimates(
            [Estimate(t_s=0.01 * k, range_m=5.0 + k, speed_mps=1.5, hop_index=k, score=2.0,
                      snr_db=12.0, alpha=1.002, t_tx_s=0.0, codeword=k, receiver="gcas")
             for k in range(3)]
        )  # fmt: skip


@pytest.mark.parametrize(("dtype", "units"), [("int16", "counts"), ("float32", "FS")])
def test_units_and_nexus_attributes(
    tmp_path: Path, schedule_doc: dict[str, Any], dtype: str, units: str
) -> None:
    path = tmp_path / "run.h5"
    _write(path, schedule_doc, dtype)
    with h5py.File(path, "r") as f:
        assert f.attrs["NX_class"] == "NXroot" and f.attrs["default"] == "entry"
        assert f["entry"].attrs["default"] == "estimates"
        est = f["estimates"]
        assert est.attrs["NX_class"] == "NXdata" and est.attrs["signal"] == "range_m"
        assert list(est.attrs["axes"]) == ["t_s"] and est.attrs["t_s_indices"] == 0
        assert list(est.attrs["auxiliary_signals"]) == ["speed_mps", "snr_db"]
        assert {c: est[c].attrs["units"] for c in ("t_s", "range_m", "speed_mps", "snr_db")} == {
            "t_s": "s", "range_m": "m", "speed_mps": "m/s", "snr_db": "dB"}  # fmt: skip
        np.testing.assert_allclose(est["range_m"][:], [5.0, 6.0, 7.0])
        tel = f["telemetry"]
        assert tel.attrs["signal"] == "position_m" and tel["position_m"].attrs["units"] == "m"
        assert f["events"].attrs["NX_class"] == "NXcollection"
        assert f["samples"].attrs["units"] == units
        view = f["recording"]
        assert view.attrs["NX_class"] == "NXdata" and view.attrs["signal"] == "samples"
        assert view["samples"].shape == (1500, 2)  # the link resolves to /samples
    # The reader is unaffected.
    with RunRecording.open(path) as rec:
        assert rec.fs_hz == FS


def test_writer_logs_gaps_and_events(
    tmp_path: Path, schedule_doc: dict[str, Any], caplog: pytest.LogCaptureFixture
) -> None:
    logger = logging.getLogger("hil")
    propagate, logger.propagate = logger.propagate, True
    try:
        with caplog.at_level(logging.INFO, logger="hil.recording.writer"):
            _write(tmp_path / "run.h5", schedule_doc, "int16")
    finally:
        logger.propagate = propagate
    messages = [(r.levelname, r.getMessage()) for r in caplog.records]
    assert messages[0][1].startswith(f"recording {tmp_path / 'run.h5'}: 100000 Hz, 2 channel(s)")
    assert ("WARNING", "gap at sample 1000: 500 samples missing") in messages
    assert ("WARNING", "alarm at sample 1600 (0 samples): stage alarm 1") in messages
