"""The JSON a watch page polls, built from a run recording (finished or still being written).

Every method re-reads the recording through one SWMR reader, so each answer holds what the
writer had flushed when it was asked. Values are plain JSON: NaN and infinities become
``null`` (JavaScript's ``JSON.parse`` refuses ``NaN``); times are seconds on the receiver's
time base (0 at the recording's ``origin_sample``).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.recording import RunRecording, schema
from hil.recording.records import SyncPairs
from hil.watch.live_map import LiveCodewordMap
from hil.watch.truth import Geometry, TruthCurve, true_boundaries, truth_curve

SEVERITY: dict[str, str] = {
    "alarm": "alarm",
    "gap": "warning",
    "xrun": "warning",
    "overrun": "warning",
    "underrun": "warning",
    "note": "note",
}
"""Event kind -> how the page shows it: ``alarm`` (red), ``warning`` (amber), ``note``."""

ESTIMATE_COLUMNS = ("t_s", "range_m", "speed_mps", "codeword", "score", "snr_db")
"""The estimate columns the page gets (times s, range m, speed m/s, codeword, score, dB)."""

TELEMETRY_COLUMNS = ("host_time_s", "sample_index", "position_m", "velocity_mps")

MAX_CURVE_POINTS = 4000
"""Truth and boundary arrays longer than this are thinned evenly before they are sent."""

MAP_PNG = "time_codeword_map.png"
"""The full time–codeword map ``hil tank-run`` saves beside ``run.h5`` when a run ends."""


def json_floats(values: Iterable[float]) -> list[float | None]:
    """Floats for JSON, non-finite ones as None.

    >>> json_floats([1.5, float("nan"), float("inf")])
    [1.5, None, None]
    """
    return [float(v) if math.isfinite(v) else None for v in values]


def _thin(n: int) -> slice:
    return slice(None, None, max(1, -(-n // MAX_CURVE_POINTS)))


def telemetry_sample_index(
    host_time_s: NDArray[np.float64],
    recorded_index: NDArray[np.int64],
    sync: SyncPairs,
    fs_hz: float,
    board_url: str = "",
) -> NDArray[np.float64]:
    """Board sample index (float) of every stage report, shape ``(n,)``; -1 where unknown.

    ``host_time_s`` (s) and ``recorded_index`` are the reports' columns as recorded. With
    SYNC pairs recorded, the host times are mapped through them as ``hil tank-run`` maps
    them for its truth when the run ends
    (:func:`hil.experiments.live.board_state.sample_index_at`, as the DAC/ADC
    ``board_url`` stamps them; a board's by the least-delayed pair): the index recorded
    beside each report comes from the live clock fit, which every late SYNC drags late, so
    the truth would lead the estimates by the host's backlog. Without pairs, the recorded
    index is used (-1: not mapped).
    """
    from hil.experiments.live.board_state import sample_index_at, stamped_in_callback

    pairs = list(zip(sync.sample_index.tolist(), sync.host_time_s.tolist(), strict=True))
    in_callback = bool(board_url) and stamped_in_callback(board_url)
    mapped = sample_index_at(host_time_s, pairs, fs_hz, in_callback=in_callback)
    if mapped is None:
        recorded = np.asarray(recorded_index, dtype=np.float64)
        return np.where(recorded >= 0, recorded, -1.0)
    return mapped


def _geometry(experiment_toml: str) -> tuple[Geometry | None, str, str, str]:
    """The tank geometry, name and board URL of the recorded experiment file, or None and
    why not (and empty strings)."""
    if not experiment_toml.strip():
        return None, "the recording holds no experiment file (no tank geometry)", "", ""
    from hil.experiments.experiment import parse_experiment

    try:
        exp = parse_experiment(experiment_toml, "the recorded experiment file")
    except (ConfigError, ValueError) as exc:
        return None, f"the recorded experiment file gives no tank geometry ({exc})", "", ""
    geometry = Geometry(exp.transducer_m, exp.stage_origin_m, exp.stage_axis, exp.sound_speed_mps)
    return geometry, "", exp.name, exp.board_url


class WatchData:
    """The watch page's data from the recording at ``path`` (open it with :meth:`open`).

    Thread-safe: one lock serialises the reads (the server answers requests on threads).
    """

    def __init__(self, recording: RunRecording, live_map: bool = False) -> None:
        self._rec = recording
        self._lock = threading.Lock()
        self.live_map = LiveCodewordMap(recording, self._lock) if live_map else None
        """The map computed from the samples (``live_map=True``), else None."""
        meta = recording.metadata
        self._schedule = recording.schedule()
        self._geometry, self._no_truth, self._experiment, self._board_url = _geometry(
            meta.experiment_toml
        )
        doc_c = recording.schedule_document().get("sound_speed_mps", 1500.0)
        self.sound_speed_mps = (
            self._geometry.sound_speed_mps if self._geometry is not None else float(doc_c)
        )
        """Sound speed of the truth's boundary arrival times, m/s (the experiment's)."""

    @classmethod
    def open(cls, path: str | Path, live_map: bool = False) -> WatchData:
        """Open the recording at ``path``; :class:`ConfigError` (one line) when it is
        missing, not HDF5 or not a hil run recording. ``live_map``: also compute the
        time–codeword map from the samples (:class:`~hil.watch.live_map.LiveCodewordMap`;
        the caller runs its updates)."""
        rec: RunRecording | None = None
        try:
            rec = RunRecording.open(path)
            return cls(rec, live_map)
        except ConfigError:
            if rec is not None:
                rec.close()
            raise
        except (KeyError, ValueError, OSError) as exc:
            if rec is not None:
                rec.close()
            raise ConfigError(
                "recording",
                str(path),
                "a readable hil run recording",
                f"it is damaged or incomplete ({exc})",
            ) from None

    @property
    def path(self) -> Path:
        """The recording's path."""
        return self._rec.path

    def close(self) -> None:
        """Close the recording."""
        with self._lock:
            self._rec.close()

    # ------------------------------------------------------------------ endpoints
    def state(self) -> dict[str, Any]:
        """Run metadata, device status, every event (with its severity) and the counts."""
        with self._lock:
            rec = self._rec
            meta = rec.metadata
            fs = rec.fs_hz
            origin = rec.origin_sample
            segments = rec.segments()
            gaps = rec.gaps()
            events = rec.events()
            telemetry = rec.telemetry()
            n_estimates = int(rec.table_columns("estimates", 0, ("t_s",))["t_s"].shape[0])
        n_samples = int(segments.n_rows.sum())
        end = int(segments.stop_index[-1]) if len(segments) else origin
        event_rows = [
            {
                "kind": e.kind,
                "severity": SEVERITY.get(e.kind, "note"),
                "sample_index": e.sample_index,
                "t_s": (e.sample_index - origin) / fs,
                "length": e.length,
                "text": e.text,
            }
            for e in events
        ]
        severities = [row["severity"] for row in event_rows]
        last = telemetry[-1] if telemetry else None
        stage = None
        if last is not None:
            stage = {
                "state": last.state,
                "position_m": json_floats([last.position_m])[0],
                "velocity_mps": json_floats([last.velocity_mps])[0],
                "t_s": (last.sample_index - origin) / fs if last.sample_index >= 0 else None,
                "reports": len(telemetry),
            }
        return {
            "file": rec.path.name,
            "path": str(rec.path),
            "experiment": self._experiment,
            "created_utc": meta.created_utc,
            "receiver": meta.receiver.name if meta.receiver is not None else None,
            "fs_hz": fs,
            "n_channels": meta.n_channels,
            "sample_dtype": meta.sample_dtype,
            "n_codewords": self._schedule.period_hops,
            "board": {
                "samples": n_samples,
                "recorded_s": n_samples / fs,
                "end_t_s": (end - origin) / fs,
                "gaps": len(gaps),
                "missing_samples": int(sum(n for _, n in gaps)),
            },
            "stage": stage,
            "events": event_rows,
            "counts": {
                "estimates": n_estimates,
                "events": len(event_rows),
                "alarms": severities.count("alarm"),
                "warnings": severities.count("warning"),
                "notes": severities.count("note"),
                "telemetry": len(telemetry),
            },
            "truth": self._no_truth or "stage telemetry and the recorded tank geometry",
        }

    def estimates(self, since: int = 0) -> dict[str, Any]:
        """The estimates recorded from row ``since`` on (rows in the order recorded), as
        columns (:data:`ESTIMATE_COLUMNS` and ``track_id``, −1 for no confirmed track);
        ``total`` is the number recorded so far (the next call's ``since``)."""
        if since < 0:
            raise ConfigError("since", since, ">= 0 (an estimate row number)")
        with self._lock:
            # Recordings made before track ids were kept have no such column: -1 (no track).
            tracked = self._rec.has_track_ids
            names = (*ESTIMATE_COLUMNS, "track_id") if tracked else ESTIMATE_COLUMNS
            cols = self._rec.table_columns("estimates", since, names)
        new = cols["t_s"].shape[0]
        total = since + new if new else self._count("estimates")
        out: dict[str, Any] = {"since": since, "total": total}
        for name in ESTIMATE_COLUMNS:
            values = cols[name]
            out[name] = values.tolist() if name == "codeword" else json_floats(values.tolist())
        out["track_id"] = cols["track_id"].tolist() if tracked else [-1] * new
        return out

    def _count(self, table: str) -> int:
        """Rows of ``table`` up to the last flush."""
        with self._lock:
            first = next(c for c, _ in schema.TABLES[table])
            return int(self._rec.table_columns(table, 0, (first,))[first].shape[0])

    def _truth(self) -> TruthCurve | None:
        if self._geometry is None:
            return None
        with self._lock:
            tel = self._rec.table_columns("telemetry", 0, TELEMETRY_COLUMNS)
            sync = self._rec.sync_pairs()
            origin = self._rec.origin_sample
            fs = self._rec.fs_hz
        index = telemetry_sample_index(
            tel["host_time_s"], tel["sample_index"], sync, fs, self._board_url
        )
        mapped = index >= 0
        if mapped.sum() < 2:
            return None
        t = (index[mapped] - origin) / fs
        x = tel["position_m"][mapped]
        v = tel["velocity_mps"][mapped]
        return truth_curve(self._geometry, t, x, v)

    def truth(self) -> dict[str, Any]:
        """Range (m) and closing speed (m/s) of the target at the telemetry times (s), or
        ``available: false`` and why (no geometry, fewer than two mapped reports)."""
        curve = self._truth()
        if curve is None:
            reason = self._no_truth or "fewer than two stage reports on the sample clock yet"
            return {"available": False, "reason": reason, "t_s": [], "range_m": [], "speed_mps": []}
        keep = _thin(curve.t_s.size)
        return {
            "available": True,
            "reason": "",
            "t_s": json_floats(curve.t_s[keep]),
            "range_m": json_floats(curve.range_m[keep]),
            "speed_mps": json_floats(curve.speed_mps[keep]),
        }

    def codeword_map(self) -> dict[str, Any]:
        """What the page draws as the time–codeword map.

        ``run.h5`` stores no codeword sums (the receiver hands them to ``hil tank-run``,
        which saves ``time_codeword_map.png`` when the run ends). Always: the hop boundaries
        the truth says arrived (``boundary_t_s``, ``boundary_codeword``), drawn over the
        decoded codeword of every estimate (from :meth:`estimates`); ``png`` names the saved
        map beside the recording once it exists. With ``live_map``, ``map`` holds the map
        computed from the samples so far (:meth:`LiveCodewordMap.snapshot`), else None.
        """
        curve = self._truth()
        if curve is None:
            t_b, j_b = np.zeros(0), np.zeros(0, dtype=np.int64)
        else:
            t_b, j_b = true_boundaries(curve, self._schedule, self.sound_speed_mps)
        keep = _thin(t_b.size)
        png = self.path.parent / MAP_PNG
        return {
            "map": None if self.live_map is None else self.live_map.snapshot(),
            "n_codewords": self._schedule.period_hops,
            "boundary_t_s": json_floats(t_b[keep]),
            "boundary_codeword": [int(j) for j in j_b[keep]],
            "png": f"/files/{MAP_PNG}" if png.is_file() else None,
        }

    def map_png(self) -> bytes | None:
        """The saved time–codeword map beside the recording, if there is one."""
        png = self.path.parent / MAP_PNG
        return png.read_bytes() if png.is_file() else None
