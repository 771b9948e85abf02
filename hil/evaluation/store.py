"""A sweep's folder on disk: ``manifest.json``, ``results.jsonl`` and ``summary.csv``.

- ``manifest.json``: the sweep definition (the part a resume must match), the full list of grid
  points, counts, package versions, the start time and one entry per run (start or resume).
  Written atomically (temporary file, then rename).
- ``results.jsonl``: one JSON object per finished trial (the record of
  :func:`hil.evaluation.worker.execute_trial`), appended and flushed as each trial completes, so
  a killed sweep loses at most the trials that were running. A line cut short by a kill is
  dropped (and truncated away) when the file is read again.
- ``summary.csv``: per grid point statistics (:mod:`hil.evaluation.aggregate`).
"""

from __future__ import annotations

import datetime as dt
import json
import os
import platform
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from hil.errors import ConfigError
from hil.evaluation.spec import FORMAT, SweepSpec

MANIFEST = "manifest.json"
RESULTS = "results.jsonl"
SUMMARY = "summary.csv"


def now_iso() -> str:
    """The current UTC time, ISO 8601 with seconds."""
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")


def versions() -> dict[str, str]:
    """Versions of Python and the packages that decide the numbers."""
    import numpy
    import scipy

    from hil import __version__

    return {
        "cas-hil": __version__,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
    }


class SweepStore:
    """The files of one sweep in ``out_dir``."""

    def __init__(self, out_dir: str | Path) -> None:
        self.out_dir = Path(out_dir)
        self.manifest_path = self.out_dir / MANIFEST
        self.results_path = self.out_dir / RESULTS
        self.summary_path = self.out_dir / SUMMARY

    # -- manifest -------------------------------------------------------------------------

    def has_sweep(self) -> bool:
        """True when the folder already holds a sweep (manifest or results)."""
        return self.manifest_path.exists() or self.results_path.exists()

    def new_manifest(self, spec: SweepSpec, runner: dict[str, Any]) -> dict[str, Any]:
        """Write the manifest of a sweep that starts now; return it."""
        started = now_iso()
        doc = {
            "format": FORMAT,
            "definition": spec.definition(),
            "description": spec.description,
            "n_points": spec.n_points,
            "n_trials": spec.n_trials,
            "points": spec.points(),
            "versions": versions(),
            "started": started,
            "command": sys.argv,
            "runs": [{"started": started, "runner": runner}],
        }
        self._write_manifest(doc)
        return doc

    def check_manifest(self, spec: SweepSpec) -> dict[str, Any]:
        """The manifest on disk, after checking that it describes ``spec`` exactly."""
        doc = self.read_manifest()
        stored = doc.get("definition", {})
        wanted = json.loads(json.dumps(spec.definition()))
        if doc.get("format") != FORMAT:
            raise ConfigError(
                "--resume",
                str(self.out_dir),
                f"a folder written in format {FORMAT} (it has {doc.get('format')!r})",
                "run the sweep again into a new --out folder",
            )
        # Compared as text: the order of grid parameters fixes the point numbering.
        if json.dumps(stored) != json.dumps(wanted):
            raise ConfigError(
                "--resume",
                str(self.out_dir),
                f"a folder holding this same sweep ({_first_difference(stored, wanted)})",
                "resume with the sweep file that started it, or pass a new --out folder",
            )
        return doc

    def add_run(self, doc: dict[str, Any], runner: dict[str, Any]) -> None:
        """Record in the manifest ``doc`` that a run (a resume) starts now."""
        doc["runs"].append({"started": now_iso(), "runner": runner, "versions": versions()})
        self._write_manifest(doc)

    def read_manifest(self) -> dict[str, Any]:
        """The manifest as written (ConfigError if it is missing or unreadable)."""
        try:
            doc: dict[str, Any] = json.loads(self.manifest_path.read_text())
        except FileNotFoundError:
            raise ConfigError(
                "--out",
                str(self.out_dir),
                f"a sweep folder with {MANIFEST}",
                "results without a manifest cannot be resumed; use a new --out folder",
            ) from None
        except json.JSONDecodeError as exc:
            raise ConfigError(str(self.manifest_path), "<file>", "valid JSON", str(exc)) from None
        return doc

    def _write_manifest(self, doc: dict[str, Any]) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        tmp = self.manifest_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(doc, indent=2) + "\n")
        os.replace(tmp, self.manifest_path)

    # -- results --------------------------------------------------------------------------

    def read_records(self) -> list[dict[str, Any]]:
        """Every complete record in ``results.jsonl``, in file order.

        A last line without its newline (the process was killed while writing it) is dropped
        and cut from the file so that appending resumes on a clean line; a broken line
        anywhere else is an error.
        """
        if not self.results_path.exists():
            return []
        data = self.results_path.read_bytes()
        records: list[dict[str, Any]] = []
        good_end = 0
        for number, line in enumerate(data.splitlines(keepends=True), start=1):
            if not line.endswith(b"\n"):
                break  # cut short by a kill
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError as exc:
                raise ConfigError(
                    f"{self.results_path}:{number}",
                    line[:80].decode(errors="replace"),
                    "one JSON record per line",
                    f"{exc.msg}; the file was edited or damaged: move it away to start over",
                ) from None
            good_end += len(line)
        if good_end < len(data):
            with self.results_path.open("r+b") as fh:
                fh.truncate(good_end)
        return records

    @contextmanager
    def appender(self) -> Iterator[RecordWriter]:
        """Open ``results.jsonl`` for appending records."""
        self.out_dir.mkdir(parents=True, exist_ok=True)
        with self.results_path.open("a", encoding="utf-8") as fh:
            yield RecordWriter(fh)


class RecordWriter:
    """Appends records as JSON lines, flushed one by one."""

    def __init__(self, fh: IO[str]) -> None:
        self._fh = fh

    def write(self, record: dict[str, Any]) -> None:
        """Append ``record`` and flush it to the operating system."""
        # One write call per line so a kill leaves at most one partial (final) line.
        self._fh.write(json.dumps(record) + "\n")
        self._fh.flush()


def _first_difference(stored: Any, wanted: Any, path: str = "") -> str:
    """Where two definitions differ, in words, e.g. ``grid.snr_db differs: [0] vs [0, 5]``."""
    if isinstance(stored, dict) and isinstance(wanted, dict):
        for key in list(stored) + [k for k in wanted if k not in stored]:
            if json.dumps(stored.get(key)) != json.dumps(wanted.get(key)):
                return _first_difference(stored.get(key), wanted.get(key), f"{path}{key}.")
        name = path.rstrip(".") or "definition"
        return f"{name} order differs: folder has {list(stored)}, sweep file has {list(wanted)}"
    name = path.rstrip(".") or "definition"
    return f"{name} differs: folder has {stored!r}, sweep file has {wanted!r}"
