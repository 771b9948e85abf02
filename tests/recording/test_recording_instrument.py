"""The recording says what was connected: the NeXus ``/entry`` (NXentry with start and end
time, program and version, calibration ids, an NXinstrument with a group per device) read
back field by field, the time axes as HDF5 dimension scales, a file without an entry still
read, and a NeXus reader's view of it."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

import hil
from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.recording.instrument import read_entry
from hil.recording.reader import RunRecording
from hil.recording.records import StageTelemetry
from hil.recording.writer import RunWriter

FS = 100_000.0
SNAPSHOT: dict[str, dict[str, Any]] = {
    "board": {
        "nx_class": "NXdetector",
        "url": "serial:///dev/ttyACM0",
        "port": "/dev/ttyACM0",
        "usb_vid_pid": "1209:ca50",
        "usb_serial": "CAS0042",
        "firmware_version": "1.0.0",
        "board_serial": 0x0B0A4D01,
        "protocol_version": "2.0",
        "schema_hash": "0x547429db",
        "max_frame_len": 8192,
        "sample_rates_hz": [1_000_000, 192_000],
    },
    "stage": {
        "nx_class": "NXpositioner",
        "url": "/dev/ttyUSB0",
        "build_info": "[VER:1.1h.20190830:]",
        "build_options": "[OPT:V,15,128]",
        "settings": {"0": "10", "22": "1", "110": "150000.000"},
    },
    "audio": {
        "nx_class": "NXdetector",
        "device": "Scarlett 2i2 USB",
        "host_api": "ALSA",
        "latency_s": 0.0053,
        "simulated": False,
    },
    "host": {"hostname": "lab-pc", "platform": "Linux-6.8-x86_64"},
}


def _write(path: Path, doc: dict[str, Any], instrument: Any = SNAPSHOT) -> None:
    with RunWriter.create(
        path, fs_hz=FS, n_channels=2, dtype="int16", schedule_document=doc,
        calibration_ids=["latency-20261128T101500", "level-20261127T090000"],
        instrument=instrument, title="towed-pass-3",
    ) as w:  # fmt: skip
        w.append_samples(0, np.ones((1000, 2), dtype=np.int16))
        w.append_telemetry(StageTelemetry(1.0, 100, -0.5, 1.5, "Run"))
        w.append_sync(100, 1.0)
        w.append_estimates(
            [Estimate(t_s=0.01 * k, range_m=5.0 + k, speed_mps=1.5, hop_index=k, score=2.0,
                      snr_db=12.0, alpha=1.002, t_tx_s=0.0, codeword=k, receiver="gcas")
             for k in range(3)]
        )  # fmt: skip


def test_every_field_of_the_entry_reads_back(tmp_path: Path, schedule_doc: dict) -> None:
    path = tmp_path / "run.h5"
    _write(path, schedule_doc)
    with h5py.File(path, "r") as f:
        entry = read_entry(f)
        created = f.attrs["created_utc"]
        classes = {k: f[f"entry/instrument/{k}"].attrs["NX_class"] for k in SNAPSHOT}
        assert f.attrs["default"] == "entry" and f["entry"].attrs["NX_class"] == "NXentry"
        assert f["entry/instrument"].attrs["NX_class"] == "NXinstrument"
        assert f["entry/instrument/stage/settings"].attrs["NX_class"] == "NXcollection"
    assert entry is not None
    end = entry.pop("end_time")
    assert entry.pop("start_time") == created
    assert datetime.fromisoformat(end) >= datetime.fromisoformat(created)
    assert entry == {
        "title": "towed-pass-3",
        "program_name": "cas-hil",
        "program_version": hil.__version__,
        "calibration": {"ids": ["latency-20261128T101500", "level-20261127T090000"]},
        "instrument": {
            "name": "cas-hil tank",
            **{k: {f: v for f, v in d.items() if f != "nx_class"} for k, d in SNAPSHOT.items()},
        },
    }
    assert classes == {
        "board": "NXdetector", "stage": "NXpositioner", "audio": "NXdetector",
        "host": "NXcollection",
    }  # fmt: skip


def test_the_entry_holds_the_root_plots_and_time_axes_are_dimension_scales(
    tmp_path: Path, schedule_doc: dict
) -> None:
    path = tmp_path / "run.h5"
    _write(path, schedule_doc)
    with h5py.File(path, "r") as f:
        for name in ("estimates", "telemetry", "recording"):
            assert f[f"entry/{name}"] == f[name]  # the same group, hard-linked
        for table, axis in (("estimates", "t_s"), ("telemetry", "host_time_s"),
                            ("sync", "host_time_s")):  # fmt: skip
            group = f[table]
            assert group[axis].is_scale
            for column in group:
                if column != axis:
                    [scale] = group[column].dims[0].values()
                    assert scale == group[axis], (table, column)
        np.testing.assert_allclose(f["estimates/range_m"].dims[0][0][:], [0.0, 0.01, 0.02])


def test_end_time_is_empty_until_the_writer_closes(tmp_path: Path, schedule_doc: dict) -> None:
    path = tmp_path / "run.h5"
    writer = RunWriter.create(path, fs_hz=FS, n_channels=2, dtype="int16",
                              schedule_document=schedule_doc)  # fmt: skip
    writer.flush()
    with h5py.File(path, "r", swmr=True) as f:
        entry = read_entry(f)
    assert (
        entry is not None
        and entry["end_time"] == ""
        and entry["instrument"] == {"name": "cas-hil tank"}
    )
    writer.close()
    with h5py.File(path, "r") as f:
        assert read_entry(f)["end_time"] != ""  # type: ignore[index]


def test_a_recording_without_an_entry_still_reads(tmp_path: Path, schedule_doc: dict) -> None:
    path = tmp_path / "run.h5"
    _write(path, schedule_doc)
    with h5py.File(path, "r+") as f:  # as written before the entry existed
        del f["entry"]
        f.attrs["default"] = "estimates"
    with h5py.File(path, "r") as f:
        assert read_entry(f) is None
    with RunRecording.open(path) as rec:
        assert rec.fs_hz == FS and len(rec.estimates()) == 3


@pytest.mark.parametrize(
    ("instrument", "message"),
    [
        ({"stage": {"$22": "1"}}, "instrument.stage.$22 = '$22' is not allowed: must be a NeXus"),
        ({"the board": {}}, "instrument.the board = 'the board' is not allowed: must be a NeXus"),
        ({"audio": {"latency_s": []}}, "instrument.audio.latency_s = [] is not allowed: must be"),
    ],
)
def test_a_snapshot_field_nexus_cannot_name_is_refused(
    tmp_path: Path, schedule_doc: dict, instrument: Any, message: str
) -> None:
    with pytest.raises(ConfigError) as err:
        _write(tmp_path / "run.h5", schedule_doc, instrument)
    assert str(err.value).startswith(message)
    assert not (tmp_path / "run.h5").exists()  # nothing half-written is left


def test_a_nexus_reader_finds_the_default_plot(tmp_path: Path, schedule_doc: dict) -> None:
    # nexusformat sets NumPy's print options for the whole process when imported: restored,
    # so the doctests that print arrays after this test see the defaults.
    options = np.get_printoptions()
    try:
        nx = pytest.importorskip("nexusformat.nexus")
    finally:
        np.set_printoptions(**options)
    path = tmp_path / "run.h5"
    _write(path, schedule_doc)
    root = nx.nxload(str(path), "r")
    data = root.plottable_data  # root @default -> entry @default -> NXdata
    assert data.nxname == "estimates" and data.nxsignal.nxname == "range_m"
    assert [a.nxname for a in data.nxaxes] == ["t_s"]
    assert str(root["entry/instrument/board/firmware_version"]) == "1.0.0"
    assert root["entry/instrument/stage"].nxclass == "NXpositioner"
