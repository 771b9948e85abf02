"""Read a run recording: typed views of samples (by board sample index, gap-aware), the
transmit schedule, events, estimates, sync pairs, stage telemetry and metadata.

The file is opened as an SWMR reader, so a recording still being written can be read (each
view re-reads the file and sees everything up to the writer's last flush), and so can one
whose writer was killed. Every column reads while the writer runs in format version 2;
version-1 files (variable-length table strings, outside SWMR) read once their writer stopped.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.recording import schema
from hil.recording.records import (
    ReceiverSetup,
    RunEvent,
    RunMetadata,
    SampleBlock,
    StageTelemetry,
    SyncPairs,
)
from hil.recording.tables import read_table
from hil.signals.schedule import HopSchedule


@dataclass(frozen=True)
class Segments:
    """Contiguous runs of received samples, shape ``(n_segments,)`` each: segment ``i`` is
    dataset rows ``row[i] .. row[i] + n_rows[i] - 1`` holding board samples from
    ``sample_index[i]`` on."""

    row: NDArray[np.int64]
    sample_index: NDArray[np.int64]
    n_rows: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.row.shape[0])

    @property
    def stop_index(self) -> NDArray[np.int64]:
        """Board sample index one past each segment's last sample."""
        return self.sample_index + self.n_rows


_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def hdf5_damage(path: Path) -> str | None:
    """What is wrong with the HDF5 file at ``path`` as its superblock tells (a missing
    signature, a file shorter than the end-of-file address its last flush wrote), or None
    when it looks whole. Read from the first bytes, without HDF5: the library can wait for
    ever on a file cut short, so a damaged recording is refused before it is opened.

    Only the start of the file is checked (the superblock at offset 0, where hil's writer
    puts it); a recording whose writer was killed keeps the end address of its last flush
    and reads up to there.
    """
    size = path.stat().st_size
    with path.open("rb") as f:
        head = f.read(128)
    if not head.startswith(_HDF5_SIGNATURE):
        return f"it does not start with the HDF5 signature ({size} bytes)"
    if len(head) < 12:
        return f"its superblock is cut short ({size} bytes)"
    version = head[8]
    if version in (0, 1):
        offsets = head[13]
        eof_at = 24 + (4 if version == 1 else 0) + 2 * offsets  # base, free-space, then EOF
    elif version in (2, 3):
        offsets = head[9]
        eof_at = 12 + 2 * offsets  # base, superblock extension, then EOF
    else:
        return f"its superblock version {version} is unknown"
    if offsets not in (2, 4, 8, 16) or len(head) < eof_at + offsets:
        return f"its superblock is damaged or cut short ({size} bytes)"
    # Both layouts: the base address two fields before the end-of-file address.
    base = int.from_bytes(head[eof_at - 2 * offsets : eof_at - offsets], "little")
    eof = int.from_bytes(head[eof_at : eof_at + offsets], "little")
    if eof == (1 << (8 * offsets)) - 1:
        return None  # undefined address: nothing to compare
    if base + eof > size:
        return (
            f"it is truncated: {size} bytes, but its last flush wrote {base + eof}"
            " (an interrupted copy or a full disk?)"
        )
    return None


def _open_h5(path: Path) -> h5py.File:
    """Open as an SWMR reader; files of other HDF5 formats fall back to a plain read. A
    file that is damaged as :func:`hdf5_damage` finds is refused without opening it."""
    if not path.exists():
        raise ConfigError("recording", str(path), "an existing run recording (.h5)")
    if path.is_dir():
        raise ConfigError("recording", str(path), "a file, not a folder")
    damage = hdf5_damage(path)
    if damage is not None:
        raise ConfigError(
            "recording",
            str(path),
            "an HDF5 run recording written by hil",
            f"{damage}; copy it again from where the run wrote it",
        )
    try:
        return h5py.File(path, "r", libver="latest", swmr=True)
    except OSError:
        pass
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise ConfigError(
            "recording",
            str(path),
            "an HDF5 run recording written by hil",
            f"it is not readable as HDF5 ({exc})",
        ) from None


#: File attributes every recording holds from its creation (``origin_sample`` and
#: ``receiver`` are optional).
_REQUIRED_ATTRS = ("fs_hz", "n_channels", "sample_dtype", "versions", "calibration_ids",
                   "created_utc")  # fmt: skip


def _missing_parts(f: h5py.File) -> list[str]:
    """What a file in the recording format lacks of what every recording holds from its
    creation (attributes, the samples, schedule and experiment datasets, every table):
    refused from the structure at open, never a KeyError on the first read."""
    missing = [f"the attribute {a}" for a in _REQUIRED_ATTRS if a not in f.attrs]
    parts = (schema.SAMPLES, schema.SCHEDULE_DOCUMENT, schema.EXPERIMENT_TOML, *schema.TABLES)
    missing += [f"/{name}" for name in parts if name not in f]
    return missing


#: Seconds a separate process may take to read a recording's structure (its attributes and
#: top-level names: metadata only, well under a second for a whole file) before the file is
#: called damaged: HDF5 can loop for ever on corrupted metadata.
PROBE_TIMEOUT_S = 20.0

_PROBE = """
import sys, h5py
with h5py.File(sys.argv[1], "r", libver="latest", swmr=True) as f:
    dict(f.attrs)
    list(f)
"""


def probe_structure(path: Path, timeout_s: float | None = None) -> None:
    """Refuse (ConfigError) a recording whose structure a separate process cannot read
    within ``timeout_s`` (default :data:`PROBE_TIMEOUT_S`): corrupted metadata that would
    hang the command that opens it. The commands that open a recording given by the user
    (report, replay, watch) probe it first; errors other than a hang are left to
    :meth:`RunRecording.open`, which names them."""
    import subprocess
    import sys

    if not path.is_file() or hdf5_damage(path) is not None:
        return  # RunRecording.open refuses it, saying why
    timeout_s = PROBE_TIMEOUT_S if timeout_s is None else timeout_s
    try:
        subprocess.run(
            [sys.executable, "-c", _PROBE, str(path)],
            capture_output=True,
            timeout=timeout_s,
            check=False,
        )
    except subprocess.TimeoutExpired:
        raise ConfigError(
            "recording",
            str(path),
            "an HDF5 run recording written by hil",
            f"its metadata is damaged: reading its structure did not end within {timeout_s:g} s"
            "; copy it again from where the run wrote it",
        ) from None


class RunRecording:
    """An open run recording (use :meth:`open`; close it, or use it as a context manager)."""

    def __init__(self, file: h5py.File, path: Path) -> None:
        self._file = file
        self.path = path
        self.metadata = self._read_metadata()

    @classmethod
    def open(cls, path: str | Path) -> RunRecording:
        """Open ``path``; :class:`ConfigError` for a file that is not a recording this hil reads.

        The format name and version are checked first, so a file of another format or of
        a format version not in ``schema.READABLE_VERSIONS`` is refused naming the attribute.
        """
        path = Path(path)
        f = _open_h5(path)
        try:
            fmt = f.attrs.get(schema.ATTR_FORMAT)
            if fmt != schema.FORMAT_NAME:
                raise ConfigError(
                    "recording.format",
                    fmt if fmt is None else str(fmt),
                    f'"{schema.FORMAT_NAME}"',
                    f"{path} is an HDF5 file but not a hil run recording",
                )
            version = f.attrs.get(schema.ATTR_VERSION)
            if version is None or int(version) not in schema.READABLE_VERSIONS:
                readable = ", ".join(str(v) for v in schema.READABLE_VERSIONS)
                raise ConfigError(
                    "recording.format_version",
                    version if version is None else int(version),
                    f"one of {readable} (the versions this hil reads)",
                    "read it with the hil release that wrote it",
                )
            missing = _missing_parts(f)
            if missing:
                raise ConfigError(
                    "recording",
                    str(path),
                    "a complete hil run recording",
                    f"it lacks {', '.join(missing)}: it was not written by hil's recorder or"
                    " was altered since; use the run.h5 the run wrote",
                )
            return cls(f, path)
        except BaseException:
            f.close()
            raise

    def close(self) -> None:
        """Close the file."""
        self._file.close()

    def __enter__(self) -> RunRecording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ metadata
    def _read_metadata(self) -> RunMetadata:
        a = self._file.attrs
        receiver = a.get("receiver")
        return RunMetadata(
            fs_hz=float(a["fs_hz"]),
            n_channels=int(a["n_channels"]),
            sample_dtype=str(a["sample_dtype"]),
            origin_sample=int(a["origin_sample"]) if "origin_sample" in a else None,
            experiment_toml=self._file[schema.EXPERIMENT_TOML].asstr()[()],
            versions=json.loads(a["versions"]),
            calibration_ids=tuple(json.loads(a["calibration_ids"])),
            receiver=None if receiver is None else ReceiverSetup.from_json(str(receiver)),
            created_utc=str(a["created_utc"]),
        )

    @property
    def fs_hz(self) -> float:
        """ADC sample rate, Hz."""
        return self.metadata.fs_hz

    @property
    def origin_sample(self) -> int:
        """Board sample index of the receiver's sample 0 (schedule t = 0): the recorded
        origin, else the first sample recorded (0 for a recording without samples)."""
        if self.metadata.origin_sample is not None:
            return self.metadata.origin_sample
        seg = self.segments()
        return int(seg.sample_index[0]) if len(seg) else 0

    def schedule_document(self) -> dict[str, Any]:
        """The transmit schedule JSON document as recorded."""
        doc: dict[str, Any] = json.loads(self._file[schema.SCHEDULE_DOCUMENT].asstr()[()])
        return doc

    def schedule(self) -> HopSchedule:
        """The transmit schedule (t = 0 at board sample :attr:`origin_sample`)."""
        return HopSchedule.from_period_dict(self.schedule_document()["period"])

    # ------------------------------------------------------------------ tables
    def _table(self, name: str) -> dict[str, NDArray[Any]]:
        return read_table(self._file[name], refresh=self._file.swmr_mode)

    def table_columns(
        self, name: str, start: int = 0, columns: Sequence[str] | None = None
    ) -> dict[str, NDArray[Any]]:
        """Rows ``start ..`` (up to the last flush) of the table ``name`` (one of
        ``schema.TABLES``: ``estimates``, ``telemetry``, ``events``, ``sync``, ...) as one
        array per column (default: every column), without building a record per row: for
        readers following a growing recording. :class:`ConfigError` for an unknown table or
        column.

        >>> import tempfile, pathlib
        >>> from hil.recording.writer import RunWriter
        >>> from hil.signals.presets import check_design, get_preset
        >>> from hil.signals.schedule_file import schedule_document
        >>> doc = schedule_document(check_design(get_preset("att").spec("random-cyclic")),
        ...                         100e3, 0.0, sound_speed_mps=1500.0)
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "run.h5"
        >>> with RunWriter.create(path, fs_hz=100e3, n_channels=1, dtype="int16",
        ...                       schedule_document=doc) as w:
        ...     for k in range(3):
        ...         w.append_sync(100 * k, 0.5 * k)
        >>> with RunRecording.open(path) as rec:
        ...     rec.table_columns("sync", start=1)["host_time_s"].tolist()
        [0.5, 1.0]
        """
        if name not in schema.TABLES:
            raise ConfigError("table", name, f"one of {', '.join(schema.TABLES)}")
        known = [c for c, _ in schema.TABLES[name]]
        for c in columns or ():
            if c not in known:
                raise ConfigError(f"{name} column", c, f"one of {', '.join(known)}")
        group = self._file[name]
        return read_table(group, refresh=self._file.swmr_mode, start=start, columns=columns)

    def _flushed_rows(self) -> int:
        """Sample rows covered by the writer's last flush."""
        flushes = self._table("flushes")["sample_rows"]
        ds = self._file[schema.SAMPLES]
        if self._file.swmr_mode:
            ds.refresh()
        return min(int(flushes[-1]), int(ds.shape[0])) if flushes.size else 0

    def segments(self) -> Segments:
        """The contiguous runs of received samples up to the last flush."""
        n = self._flushed_rows()
        t = self._table("segments")
        keep = t["row"] < n
        row = t["row"][keep].astype(np.int64)
        index = t["sample_index"][keep].astype(np.int64)
        n_rows = np.diff(np.append(row, n)).astype(np.int64)
        return Segments(row=row, sample_index=index, n_rows=n_rows)

    @property
    def n_samples(self) -> int:
        """Sample frames recorded (received samples only; gaps hold none)."""
        return int(self.segments().n_rows.sum())

    def gaps(self) -> list[tuple[int, int]]:
        """``(first missing board sample index, number missing)`` for every gap between
        recorded segments."""
        seg = self.segments()
        starts = seg.stop_index[:-1]
        lengths = seg.sample_index[1:] - starts
        return [(int(s), int(n)) for s, n in zip(starts, lengths, strict=True)]

    def samples(self, start: int | None = None, stop: int | None = None) -> list[SampleBlock]:
        """The received samples with board sample indices in ``[start, stop)`` (default: all),
        one block per contiguous run; missing samples fall between blocks."""
        return list(self.iter_blocks(None, start, stop))

    def iter_blocks(
        self, max_frames: int | None = 65536, start: int | None = None, stop: int | None = None
    ) -> Iterator[SampleBlock]:
        """Received samples in ``[start, stop)`` as blocks of at most ``max_frames`` frames
        (None: whole segments), in board-sample order, never spanning a gap."""
        if max_frames is not None and max_frames < 1:
            raise ConfigError("max_frames", max_frames, ">= 1 frame")
        seg = self.segments()
        ds = self._file[schema.SAMPLES]
        lo = -(2**62) if start is None else int(start)
        hi = 2**62 if stop is None else int(stop)
        for row, first, count in zip(seg.row, seg.sample_index, seg.n_rows, strict=True):
            a = max(int(first), lo)
            b = min(int(first + count), hi)
            step = (b - a) if max_frames is None else max_frames
            for s in range(a, b, max(step, 1)):
                e = min(s + step, b)
                r = int(row) + s - int(first)
                yield SampleBlock(s, ds[r : r + e - s])

    def events(self) -> list[RunEvent]:
        """Every sample-indexed event, in the order recorded."""
        t = self._table("events")
        return [
            RunEvent(str(k), int(i), int(n), str(x))
            for k, i, n, x in zip(t["kind"], t["sample_index"], t["length"], t["text"], strict=True)
        ]

    @property
    def has_track_ids(self) -> bool:
        """Whether the estimates table holds ``track_id`` (recordings made before tracks were
        kept do not; their estimates read ``track_id = -1``)."""
        group = self._file["estimates"]
        return "track_id" in [str(c) for c in group.attrs["columns"]]

    def estimates(self, receiver: str | None = None) -> list[Estimate]:
        """The recorded estimates (of one receiver by name, or all) in the order recorded."""
        t = self._table("estimates")
        n = t["t_s"].shape[0]
        nan = np.full(n, np.nan)  # recordings made before the bounds were columns
        crlb_r, crlb_v = t.get("crlb_range_m", nan), t.get("crlb_speed_mps", nan)
        track = t.get("track_id", np.full(n, -1, dtype=np.int64))  # made before tracks were kept
        out = [
            Estimate(
                t_s=float(t["t_s"][i]),
                range_m=float(t["range_m"][i]),
                speed_mps=float(t["speed_mps"][i]),
                hop_index=int(t["hop_index"][i]),
                score=float(t["score"][i]),
                snr_db=float(t["snr_db"][i]),
                alpha=float(t["alpha"][i]),
                t_tx_s=float(t["t_tx_s"][i]),
                codeword=int(t["codeword"][i]),
                receiver=str(t["receiver"][i]),
                crlb_range_m=float(crlb_r[i]),
                crlb_speed_mps=float(crlb_v[i]),
                track_id=int(track[i]),
            )
            for i in range(n)
        ]
        return out if receiver is None else [e for e in out if e.receiver == receiver]

    def table(self, name: str) -> dict[str, NDArray[Any]]:
        """One recorded table as columns of arrays (for notebooks and numpy): ``"estimates"``,
        ``"telemetry"``, ``"events"`` or ``"sync"``; column names as in
        ``docs/recording-format.md``, each of shape ``(n_rows,)``.

        >>> # rec.table("estimates")["range_m"] is every recorded range estimate, m
        """
        if name not in ("estimates", "telemetry", "events", "sync"):
            raise ConfigError("table", name, "one of estimates, telemetry, events, sync")
        return {key: np.asarray(col) for key, col in self._table(name).items()}

    def sync_pairs(self) -> SyncPairs:
        """The board sample index ↔ host time pairs."""
        t = self._table("sync")
        return SyncPairs(t["sample_index"].astype(np.int64), t["host_time_s"].astype(np.float64))

    def telemetry(self) -> list[StageTelemetry]:
        """The stage status reports, in the order recorded."""
        t = self._table("telemetry")
        cols = (t["host_time_s"], t["sample_index"], t["position_m"], t["velocity_mps"], t["state"])
        # Recordings made before the reply time was a column: every report counts as prompt.
        reply = t.get("reply_s", np.zeros(t["host_time_s"].shape[0]))
        return [
            StageTelemetry(float(h), int(i), float(p), float(v), str(s), float(r))
            for h, i, p, v, s, r in zip(*cols, reply, strict=True)
        ]
