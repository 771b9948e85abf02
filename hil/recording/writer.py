"""Write one run to one HDF5 file: append-only, SWMR, flushed at least once a second.

Everything fixed for the run (sample layout, transmit schedule, experiment file, versions,
calibration ids, the live receiver) is written when the file is created; the file then
switches to SWMR mode (single writer, multiple readers), after which only appends happen:
samples, sync pairs, stage telemetry, events and estimates. Readers opened with
:meth:`hil.recording.RunRecording.open` see everything up to the last flush, also after the
writer was killed.

Flushing: every append checks the injected ``clock`` and flushes when ``flush_interval_s``
(default 1 s) has passed since the last flush; :meth:`RunWriter.flush` flushes at once.
Small-table rows wait in memory until the next flush (one HDF5 write per column per flush,
not per row); sample blocks wait until the next flush or until they fill an HDF5 chunk (one
write per chunk, not per captured block). A reader sees neither before a flush either way.
"""

from __future__ import annotations

import json
import logging
import math
import platform
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import ArrayLike

import hil
from hil.errors import ConfigError
from hil.estimation.base import ESTIMATE_FIELDS, Estimate
from hil.recording import schema
from hil.recording.instrument import Snapshot, attach_time_axes, write_end_time, write_entry
from hil.recording.nexus import annotate
from hil.recording.records import ReceiverSetup, RunEvent, StageTelemetry
from hil.recording.tables import append_rows, check_row, create_table
from hil.signals.schedule import HopSchedule
from hil.signals.schedule_file import FORMAT_NAME as SCHEDULE_FORMAT

DEFAULT_CHUNK_FRAMES = 65536
_LOG = logging.getLogger(__name__)
_WARNING_EVENTS = ("gap", "xrun", "alarm", "overrun", "underrun")
"""Event kinds logged as warnings (the rest, notes, as information)."""
"""Sample frames per HDF5 chunk (0.65 s at 100 kHz)."""


def software_versions(protocol_schema_hash: int | str | None = None) -> dict[str, Any]:
    """Versions of the software writing a recording (and the protocol schema hash if given)."""
    versions: dict[str, Any] = {
        "hil": hil.__version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "h5py": h5py.version.version,
        "hdf5": h5py.version.hdf5_version,
    }
    if protocol_schema_hash is not None:
        versions["protocol_schema_hash"] = protocol_schema_hash
    return versions


def _check_schedule(document: Mapping[str, Any], fs_hz: float) -> None:
    """Refuse a schedule document that would not rebuild the transmit schedule on replay."""
    fmt = document.get("format") if isinstance(document, Mapping) else type(document).__name__
    if fmt != SCHEDULE_FORMAT:
        raise ConfigError(
            "schedule_document.format",
            fmt,
            f'"{SCHEDULE_FORMAT}" (a transmit schedule document)',
            "build it with hil.signals.schedule_file.schedule_document",
        )
    if "period" not in document or "fs" not in document:
        raise ConfigError("schedule_document", "without period/fs", "a document with both")
    HopSchedule.from_period_dict(document["period"])
    if not math.isclose(float(document["fs"]), fs_hz, rel_tol=0.0, abs_tol=0.5):
        raise ConfigError(
            "fs_hz",
            fs_hz,
            f"the schedule's sample rate {float(document['fs']):g} Hz",
            "record at the rate the schedule was written for",
        )


class RunWriter:
    """Append-only writer of one run recording (create it with :meth:`create`).

    Not thread-safe: one acquisition thread appends. Use it as a context manager or call
    :meth:`close`; a writer that dies without closing leaves a file readable up to the last
    flush.
    """

    def __init__(
        self,
        file: h5py.File,
        *,
        n_channels: int,
        dtype: np.dtype[Any],
        flush_interval_s: float,
        clock: Callable[[], float],
    ) -> None:
        self._file = file
        self._samples: h5py.Dataset = file[schema.SAMPLES]
        self._sample_rows = int(self._samples.shape[0])
        """Sample rows appended: those in the file and those waiting."""
        self._waiting_samples: list[np.ndarray[Any, Any]] = []
        self._waiting_rows = 0
        chunks = self._samples.chunks
        self._write_rows = int(chunks[0]) if chunks else DEFAULT_CHUNK_FRAMES
        self._n_channels = n_channels
        self._dtype = dtype
        self._flush_interval_s = flush_interval_s
        self._clock = clock
        self._pending: dict[str, list[tuple[Any, ...]]] = {
            name: [] for name in ("sync", "telemetry", "events", "estimates")
        }
        self._next_index: int | None = None
        self._last_flush = clock()
        self.flush_count = 0
        """Flushes so far (explicit and time-based)."""

    # ------------------------------------------------------------------ creation
    @classmethod
    def create(
        cls,
        path: str | Path,
        *,
        fs_hz: float,
        n_channels: int,
        dtype: str | type | np.dtype[Any],
        schedule_document: Mapping[str, Any],
        receiver: ReceiverSetup | None = None,
        experiment_toml: str = "",
        calibration_ids: Sequence[str] = (),
        instrument: Snapshot | None = None,
        title: str = "",
        protocol_schema_hash: int | str | None = None,
        origin_sample: int | None = None,
        chunk_frames: int = DEFAULT_CHUNK_FRAMES,
        flush_interval_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        overwrite: bool = False,
    ) -> RunWriter:
        """Create the recording at ``path`` and return its writer (in SWMR mode).

        Parameters
        ----------
        fs_hz:
            ADC sample rate, Hz.
        n_channels, dtype:
            Sample frame layout as captured: ``n_channels`` columns of ``int16``, ``int32``
            or ``float32``.
        schedule_document:
            The transmit schedule JSON document
            (:func:`hil.signals.schedule_file.schedule_document`); its t = 0 is board sample
            ``origin_sample``.
        receiver:
            The receiver run live (name, settings, channel, scale), if any.
        instrument, title:
            What was connected (``device -> fields``, :mod:`hil.recording.instrument`)
            and the run's name, written into the NeXus ``/entry``.
        origin_sample:
            Board sample index that is the receiver's sample 0 and the schedule's t = 0;
            None: the first sample recorded.
        chunk_frames:
            Sample frames per HDF5 chunk.
        flush_interval_s:
            Longest time between flushes while appending, s (at most 1 s).
        clock:
            Monotonic clock in seconds (injected in tests).

        Raises :class:`ConfigError` naming the setting before the file is touched.
        """
        path = Path(path)
        sample_dtype = np.dtype(dtype)
        if sample_dtype.name not in schema.SAMPLE_DTYPES:
            raise ConfigError(
                "dtype", sample_dtype.name, f"one of {', '.join(schema.SAMPLE_DTYPES)}"
            )
        if not (math.isfinite(fs_hz) and fs_hz > 0):
            raise ConfigError("fs_hz", fs_hz, "> 0 Hz")
        if n_channels < 1:
            raise ConfigError("n_channels", n_channels, ">= 1")
        if chunk_frames < 1:
            raise ConfigError("chunk_frames", chunk_frames, ">= 1 frame")
        if not 0 < flush_interval_s <= 1.0:
            raise ConfigError(
                "flush_interval_s", flush_interval_s, "0 < interval <= 1 s", "DESIGN: flush >= 1/s"
            )
        if receiver is not None and receiver.channel >= n_channels:
            raise ConfigError("receiver.channel", receiver.channel, f"0..{n_channels - 1}")
        _check_schedule(schedule_document, fs_hz)
        schedule_json = json.dumps(dict(schedule_document))
        if path.exists() and not overwrite:
            raise ConfigError(
                "path",
                str(path),
                "a new file",
                "recordings are never overwritten; choose another name",
            )
        path.parent.mkdir(parents=True, exist_ok=True)

        _LOG.info("recording %s: %g Hz, %d channel(s) of %s", path, fs_hz, n_channels,
                  sample_dtype.name)  # fmt: skip
        f = h5py.File(path, "w", libver="latest")
        try:
            attrs = f.attrs
            attrs[schema.ATTR_FORMAT] = schema.FORMAT_NAME
            attrs[schema.ATTR_VERSION] = schema.FORMAT_VERSION
            attrs["fs_hz"] = float(fs_hz)
            attrs["n_channels"] = int(n_channels)
            attrs["sample_dtype"] = sample_dtype.name
            if origin_sample is not None:
                attrs["origin_sample"] = int(origin_sample)
            created = datetime.now(UTC).isoformat(timespec="seconds")
            attrs["created_utc"] = created
            attrs["versions"] = json.dumps(software_versions(protocol_schema_hash))
            attrs["calibration_ids"] = json.dumps([str(c) for c in calibration_ids])
            if receiver is not None:
                attrs["receiver"] = receiver.to_json()
            f.create_dataset(
                schema.SAMPLES,
                shape=(0, n_channels),
                maxshape=(None, n_channels),
                dtype=sample_dtype,
                chunks=(chunk_frames, n_channels),
            )
            f.create_dataset(schema.SCHEDULE_DOCUMENT, data=schedule_json, dtype=schema.STR)
            period = f.create_group(schema.SCHEDULE_PERIOD)
            for key, value in dict(schedule_document["period"]).items():
                if isinstance(value, list):
                    period.create_dataset(key, data=np.asarray(value))
                else:
                    period.attrs[key] = json.dumps(value)
            f.create_dataset(schema.EXPERIMENT_TOML, data=experiment_toml, dtype=schema.STR)
            for name, columns in schema.TABLES.items():
                create_table(f, name, columns)
            annotate(f, schema.SAMPLES, tuple(schema.TABLES))
            write_entry(
                f,
                start_time=created,
                version=hil.__version__,
                title=title,
                calibration_ids=[str(c) for c in calibration_ids],
                instrument=instrument or {},
            )
            attach_time_axes(f)
            f.flush()
            # From here on only appends: readers may attach at any time.
            f.swmr_mode = True
        except BaseException:
            f.close()
            path.unlink(missing_ok=True)
            raise
        return cls(
            f,
            n_channels=n_channels,
            dtype=sample_dtype,
            flush_interval_s=flush_interval_s,
            clock=clock,
        )

    # ------------------------------------------------------------------ appends
    @property
    def next_sample_index(self) -> int | None:
        """Board sample index the next sample block should start at (None before the first)."""
        return self._next_index

    def append_samples(self, first_index: int, block: ArrayLike) -> None:
        """Append received samples: ``block`` of shape ``(n, n_channels)`` (or ``(n,)`` for one
        channel), dtype as captured, starting at board sample ``first_index``.

        A block that starts after the expected index opens a new segment and records a
        ``gap`` event for the missing samples; one that starts before it (samples received
        twice) is refused: drop repeats before recording.
        """
        data = np.asarray(block)
        if data.ndim == 1 and self._n_channels == 1:
            data = data[:, None]
        if data.ndim != 2 or data.shape[1] != self._n_channels:
            raise ConfigError(
                "samples.shape", data.shape, f"(n, {self._n_channels}) frames of this run"
            )
        if data.dtype != self._dtype:
            raise ConfigError(
                "samples.dtype", data.dtype.name, f"{self._dtype.name} (as the run was created)"
            )
        first_index = int(first_index)
        expected = self._next_index
        if expected is not None and first_index < expected:
            raise ConfigError(
                "samples.first_index",
                first_index,
                f">= {expected} (the next board sample not yet recorded)",
                "drop repeated samples before recording",
            )
        n = data.shape[0]
        if n == 0:
            return
        row = self._sample_rows
        if expected is None or first_index > expected:
            # The segment row goes to the file before its samples, so a reader never sees
            # rows of a new segment attributed to the previous one.
            append_rows(self._file["segments"], {"row": [row], "sample_index": [first_index]})
            if expected is not None:
                missing = first_index - expected
                _LOG.warning("gap at sample %d: %d samples missing", expected, missing)
                self._pending["events"].append(
                    ("gap", expected, missing, f"samples {expected} .. {first_index - 1} missing")
                )
        # A copy: the caller may reuse its buffer before the block is written.
        self._waiting_samples.append(np.array(data, copy=True))
        self._waiting_rows += n
        self._sample_rows = row + n
        self._next_index = first_index + n
        if self._waiting_rows >= self._write_rows:
            self._write_samples()
        self._maybe_flush()

    def _write_samples(self) -> None:
        """Write the waiting sample blocks to the file in one slab."""
        if not self._waiting_samples:
            return
        row = int(self._samples.shape[0])
        self._samples.resize((self._sample_rows, self._n_channels))
        self._samples[row:] = np.concatenate(self._waiting_samples)
        self._waiting_samples.clear()
        self._waiting_rows = 0

    def append_sync(self, sample_index: int, host_time_s: float) -> None:
        """Append one sync pair: board sample ``sample_index`` seen at host time (s)."""
        self._pending["sync"].append((int(sample_index), float(host_time_s)))
        self._maybe_flush()

    def append_telemetry(self, record: StageTelemetry) -> None:
        """Append one stage status report (:class:`ConfigError` for a ``state`` longer than
        ``schema.TELEMETRY_STATE_BYTES`` bytes of UTF-8)."""
        row = (
            float(record.host_time_s),
            int(record.sample_index),
            float(record.position_m),
            float(record.velocity_mps),
            str(record.state),
            float(record.reply_s),
        )
        check_row("telemetry", row)
        self._pending["telemetry"].append(row)
        self._maybe_flush()

    def map_telemetry_times(self, sample_index: Sequence[int]) -> None:
        """Write ``sample_index`` (one board sample index per stage report recorded so far,
        in order) over the telemetry's ``sample_index`` column, and flush: the one write that
        is not an append, for the run's end, once the SYNC pairs of the whole run give the
        mapping the run is scored with (the live column holds the clock fit of the moment).
        :class:`ConfigError` when the count differs from the reports recorded."""
        self.flush()
        ds = self._file["telemetry/sample_index"]
        values = np.asarray(sample_index, dtype=np.int64)
        if values.shape != (ds.shape[0],):
            raise ConfigError(
                "telemetry sample_index",
                f"{values.size} values",
                f"one per recorded stage report ({ds.shape[0]})",
                "map every report the recording holds, in the order recorded",
            )
        ds[:] = values
        self._file.flush()

    def append_event(self, event: RunEvent) -> None:
        """Append one sample-indexed event (gaps in the samples are recorded automatically).

        A ``text`` longer than ``schema.EVENT_TEXT_BYTES`` bytes of UTF-8 is recorded cut,
        ending with "…"."""
        row = (event.kind, event.sample_index, event.length, event.text)
        check_row("events", row)
        level = logging.WARNING if event.kind in _WARNING_EVENTS else logging.INFO
        _LOG.log(level, "%s at sample %d (%d samples): %s", event.kind, event.sample_index,
                 event.length, event.text)  # fmt: skip
        self._pending["events"].append(row)
        self._maybe_flush()

    def append_estimates(self, estimates: Iterable[Estimate]) -> None:
        """Append estimates (any receiver; the ``receiver`` field tells them apart).

        :class:`ConfigError`, with none of them appended, for a ``receiver`` name longer than
        ``schema.ESTIMATE_RECEIVER_BYTES`` bytes of UTF-8."""
        new = [tuple(getattr(e, k) for k in ESTIMATE_FIELDS) for e in estimates]
        for row in new:
            check_row("estimates", row)
        self._pending["estimates"].extend(new)
        self._maybe_flush()

    # ------------------------------------------------------------------ flushing
    @property
    def last_flush_s(self) -> float:
        """Clock reading (s) at the last flush (at creation before the first)."""
        return self._last_flush

    def _maybe_flush(self) -> None:
        if self._clock() - self._last_flush >= self._flush_interval_s:
            self.flush()

    def flush(self) -> None:
        """Write the waiting samples and table rows and flush the file: readers now see
        everything."""
        self._write_samples()
        for name, rows in self._pending.items():
            if not rows:
                continue
            columns = [c for c, _ in schema.TABLES[name]]
            append_rows(self._file[name], dict(zip(columns, zip(*rows, strict=True), strict=True)))
            rows.clear()
        now = self._clock()
        append_rows(self._file["flushes"], {"sample_rows": [self._sample_rows], "clock_s": [now]})
        self._file.flush()
        self._last_flush = now
        self.flush_count += 1

    def close(self) -> None:
        """Write the entry's end time, flush and close the file (idempotent)."""
        if self._file.id.valid:
            write_end_time(self._file, datetime.now(UTC).isoformat(timespec="seconds"))
            self.flush()
            self._file.close()

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
