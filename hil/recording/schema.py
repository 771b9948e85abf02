"""The run-recording layout: format name and version, group paths and the columns of every
append-only table (the full description is docs/recording-format.md).

A recording is one HDF5 file per run. Every table is a group of 1-D datasets, one per column,
all resizable along their first axis and appended together; a table's row count is the
shortest of its columns (so a writer killed between two column writes leaves whole rows).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import h5py
import numpy as np

FORMAT_NAME = "cas-hil-run"
FORMAT_VERSION = 2
"""The version this hil writes: 2 stores the table string columns as fixed-length UTF-8."""
READABLE_VERSIONS: tuple[int, ...] = (1, 2)
"""Versions this hil reads (version 1: variable-length table strings, unsafe to read live)."""

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
"""Variable-length UTF-8 strings: the scalar strings, written once before SWMR starts (and
the table string columns of version-1 files)."""

TELEMETRY_STATE_BYTES = 16
"""Bytes of UTF-8 in a telemetry ``state`` (GRBL states are short words: ``Hold:0``)."""
EVENT_KIND_BYTES = 16
"""Bytes of UTF-8 in an event ``kind`` (the longest of :data:`EVENT_KINDS` has 8)."""
EVENT_TEXT_BYTES = 512
"""Bytes of UTF-8 in an event ``text``; a longer text is cut to fit and ends with "…"."""
ESTIMATE_RECEIVER_BYTES = 32
"""Bytes of UTF-8 in an estimate's ``receiver`` name."""


@dataclass(frozen=True)
class FixedText:
    """A table column of fixed-length UTF-8 strings of at most ``max_bytes`` bytes.

    Fixed-length data lives in the dataset's chunks, which SWMR covers, so a live reader can
    read the column after any flush (variable-length strings live in the global heap, which
    SWMR does not cover). Shorter values are padded with NULs, so a trailing NUL is not kept.

    A longer value is cut on a UTF-8 character boundary and ends with :data:`ELLIPSIS` when
    ``truncate`` (free text); otherwise it is refused with a :class:`~hil.errors.ConfigError`
    whose hint is ``hint`` (names: a cut name would no longer mean the same thing).
    """

    max_bytes: int
    truncate: bool
    hint: str = ""

    @property
    def dtype(self) -> np.dtype[Any]:
        """The HDF5/h5py dtype of the column."""
        return h5py.string_dtype("utf-8", length=self.max_bytes)


ELLIPSIS = "…"
"""Marks a cut text ("…", 3 bytes of UTF-8)."""

SAMPLE_DTYPES: tuple[str, ...] = ("int16", "int32", "float32")
"""Sample formats as captured: 16/32-bit integer ADC codes or float32 (audio interfaces)."""

EVENT_KINDS: tuple[str, ...] = ("gap", "xrun", "alarm", "overrun", "underrun", "note")
"""Kinds of sample-indexed event."""

# Table name -> ((column, NumPy dtype or FixedText), ...). Units are in the column names.
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
        (
            "state",
            FixedText(
                TELEMETRY_STATE_BYTES,
                truncate=False,
                hint="record the controller's state word; longer text goes in an event",
            ),
        ),
        # How long the report took to come back after its query (s): a tank run leaves the
        # late ones out of its truth. Absent from recordings made before it (read as 0).
        ("reply_s", np.float64),
    ),
    "events": (
        ("kind", FixedText(EVENT_KIND_BYTES, truncate=False, hint="use one of EVENT_KINDS")),
        ("sample_index", np.int64),
        ("length", np.int64),
        ("text", FixedText(EVENT_TEXT_BYTES, truncate=True)),
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
        (
            "receiver",
            FixedText(
                ESTIMATE_RECEIVER_BYTES,
                truncate=False,
                hint="a cut name would not find the receiver on replay; register a shorter name",
            ),
        ),
        ("crlb_range_m", np.float64),
        ("crlb_speed_mps", np.float64),
        # Confirmed track of the estimate, -1 for none (files without the column read -1).
        ("track_id", np.int64),
    ),
}


def column_dtype(spec: Any) -> Any:
    """The dtype a column of ``TABLES`` is stored as (its own, or a :class:`FixedText`'s)."""
    return spec.dtype if isinstance(spec, FixedText) else spec


TABLE_CHUNK_ROWS = 1024
"""Rows per chunk of the small tables (a chunk is written only once it holds data)."""
