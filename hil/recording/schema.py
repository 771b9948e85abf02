"""The run-recording layout: format name and version, group paths and the columns of every
append-only table (the full description is docs/recording-format.md).

A recording is one HDF5 file per run. Every table is a group of 1-D datasets, one per column,
all resizable along their first axis and appended together; a table's row count is the
shortest of its columns (so a writer killed between two column writes leaves whole rows).
"""

from __future__ import annotations

from typing import Any

import h5py
import numpy as np

FORMAT_NAME = "cas-hil-run"
FORMAT_VERSION = 1

# Root attributes.
ATTR_FORMAT = "format"
ATTR_VERSION = "format_version"

SAMPLES = "samples"
"""Dataset ``(n_rows, n_channels)`` of the received ADC samples, dtype as captured."""

SCHEDULE_DOCUMENT = "schedule/document"
"""Scalar UTF-8 string: the transmit schedule JSON (docs/schedule-format.md)."""
SCHEDULE_PERIOD = "schedule/period"
"""Group: one 1-D dataset per array of ``HopSchedule.period_dict()``."""

EXPERIMENT_TOML = "metadata/experiment_toml"
"""Scalar UTF-8 string: the experiment file as given (empty for none)."""

STR = h5py.string_dtype("utf-8")
"""Variable-length UTF-8 strings."""

SAMPLE_DTYPES: tuple[str, ...] = ("int16", "int32", "float32")
"""Sample formats as captured: 16/32-bit integer ADC codes or float32 (audio interfaces)."""

EVENT_KINDS: tuple[str, ...] = ("gap", "xrun", "alarm", "overrun", "underrun", "note")
"""Kinds of sample-indexed event."""

# Table name -> ((column, dtype), ...). Units are in the column names.
TABLES: dict[str, tuple[tuple[str, Any], ...]] = {
    # Contiguous runs of received samples: dataset row ``row`` holds board sample
    # ``sample_index``; the run lasts until the next segment's row (or the last row).
    "segments": (("row", np.int64), ("sample_index", np.int64)),
    # One row per flush: sample rows in the file at that flush. Readers trust the samples up
    # to the last flush only (rows beyond it may be visible before their segment is).
    "flushes": (("sample_rows", np.int64), ("clock_s", np.float64)),
    "sync": (("sample_index", np.int64), ("host_time_s", np.float64)),
    "telemetry": (
        ("host_time_s", np.float64),
        ("sample_index", np.int64),
        ("position_m", np.float64),
        ("velocity_mps", np.float64),
        ("state", STR),
    ),
    "events": (
        ("kind", STR),
        ("sample_index", np.int64),
        ("length", np.int64),
        ("text", STR),
    ),
    "estimates": (
        ("t_s", np.float64),
        ("range_m", np.float64),
        ("speed_mps", np.float64),
        ("hop_index", np.int64),
        ("score", np.float64),
        ("snr_db", np.float64),
        ("alpha", np.float64),
        ("t_tx_s", np.float64),
        ("codeword", np.int64),
        ("receiver", STR),
    ),
}

TABLE_CHUNK_ROWS = 1024
"""Rows per chunk of the small tables (a chunk is written only once it holds data)."""
