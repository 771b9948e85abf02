"""The versioned calibration store: one JSON file per result, a "current" pointer per kind.

Layout under the store directory::

    <store>/<kind>/<id>.json     one immutable record per calibration run
    <store>/<kind>/CURRENT       the id of the record in use (one line)

An id is ``<kind>-<UTC time to the microsecond>-<8 hex digits of the SHA-256 of the record>``,
e.g. ``latency-20250301T101500123456Z-1f2e3d4c``. A record holds ``id``, ``kind``,
``created_utc`` (ISO 8601), ``software_version`` (``hil.__version__``), ``settings`` (the
inputs of the run: device, options, simulated truths) and ``result`` (the kind's result
dataclass as JSON). Files are written to a temporary name and renamed, so a crash never
leaves half a record or a pointer to one.

:meth:`CalibrationStore.require` is the preflight check of a tank run: the current record of a
kind must exist and be at most ``max_age_s`` old, else a :class:`~hil.errors.ConfigError` names
the calibration and the command that makes it.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from hil import __version__
from hil.errors import ConfigError
from hil.experiments.calibration.latency import LatencyResult
from hil.experiments.calibration.level import LevelResult
from hil.experiments.calibration.response import ResponseResult
from hil.experiments.calibration.sound_speed import SoundSpeedResult
from hil.experiments.calibration.stage import StageResult

FORMAT_VERSION = 1
CURRENT = "CURRENT"


class CalibrationResult(Protocol):
    """What every result dataclass offers."""

    def to_json(self) -> dict[str, Any]: ...

    def summary(self) -> list[str]: ...


#: Kind name (also the ``hil calibrate`` sub-command) -> result class.
RESULT_TYPES: dict[str, Any] = {
    "latency": LatencyResult,
    "response": ResponseResult,
    "level": LevelResult,
    "sound-speed": SoundSpeedResult,
    "stage": StageResult,
}
KINDS = tuple(RESULT_TYPES)


def check_kind(kind: str) -> str:
    """``kind`` if it is a known calibration kind, else a :class:`ConfigError`.

    >>> check_kind("gain")
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: kind = 'gain' is not allowed: must be one of latency, response, \
level, sound-speed, stage; run 'hil calibrate --help' for what each measures
    """
    if kind not in RESULT_TYPES:
        raise ConfigError(
            "kind", kind, f"one of {', '.join(KINDS)}",
            "run 'hil calibrate --help' for what each measures",
        )  # fmt: skip
    return kind


def format_age(seconds: float) -> str:
    """A duration for messages: ``"45 s"``, ``"12.5 min"``, ``"3.2 h"``, ``"4.0 days"``.

    >>> format_age(30), format_age(750), format_age(3 * 3600), format_age(4 * 86400)
    ('30 s', '12.5 min', '3.0 h', '4.0 days')
    """
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    if seconds < 2 * 86400:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


def _utc(now: dt.datetime | None) -> dt.datetime:
    t = now if now is not None else dt.datetime.now(dt.UTC)
    if t.tzinfo is None:
        raise ConfigError("now", t, "a timezone-aware datetime", "use datetime.now(UTC)")
    return t.astimezone(dt.UTC)


@dataclass(frozen=True)
class StoredCalibration:
    """One record of the store.

    Attributes
    ----------
    id, kind, created_utc, software_version, settings:
        As in the module docstring.
    result:
        The result object (e.g. :class:`LatencyResult`).
    path:
        The record's file.
    """

    id: str
    kind: str
    created_utc: dt.datetime
    software_version: str
    settings: dict[str, Any]
    result: Any
    path: Path

    def age_s(self, now: dt.datetime | None = None) -> float:
        """Seconds since the calibration was made."""
        return (_utc(now) - self.created_utc).total_seconds()


def _write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class CalibrationStore:
    """The store rooted at ``root`` (created on the first save).

    Examples
    --------
    >>> import tempfile
    >>> from hil.experiments.calibration.sound_speed import calibrate_sound_speed_temperature
    >>> store = CalibrationStore(tempfile.mkdtemp())
    >>> rec = store.save("sound-speed", calibrate_sound_speed_temperature(20.0), {"T": 20.0})
    >>> store.current("sound-speed").id == rec.id, round(rec.result.sound_speed_mps, 2)
    (True, 1482.38)
    """

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.root = Path(root)

    def _dir(self, kind: str) -> Path:
        return self.root / check_kind(kind)

    def save(
        self,
        kind: str,
        result: CalibrationResult,
        settings: dict[str, Any],
        *,
        now: dt.datetime | None = None,
        make_current: bool = True,
    ) -> StoredCalibration:
        """Store ``result`` as a new record (and make it current); return the record."""
        folder = self._dir(kind)
        created = _utc(now)
        body = {
            "format": FORMAT_VERSION,
            "kind": kind,
            "created_utc": created.isoformat(),
            "software_version": __version__,
            "settings": settings,
            "result": result.to_json(),
        }
        canonical = json.dumps(body, sort_keys=True, default=_jsonable)
        digest = hashlib.sha256(canonical.encode("utf-8")).hexdigest()[:8]
        record_id = f"{kind}-{created.strftime('%Y%m%dT%H%M%S%fZ')}-{digest}"
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{record_id}.json"
        text = json.dumps({"id": record_id, **body}, indent=1, default=_jsonable)
        _write_atomic(path, text + "\n")
        if make_current:
            self.set_current(kind, record_id)
        return self.load(kind, record_id)

    def set_current(self, kind: str, record_id: str) -> None:
        """Point ``kind``'s current calibration at an existing record."""
        folder = self._dir(kind)
        if not (folder / f"{record_id}.json").is_file():
            raise ConfigError(
                "calibration id", record_id, f"one of the records in {folder}",
                "list them with CalibrationStore.history()",
            )  # fmt: skip
        _write_atomic(folder / CURRENT, record_id + "\n")

    def load(self, kind: str, record_id: str) -> StoredCalibration:
        """Read one record."""
        path = self._dir(kind) / f"{record_id}.json"
        data = json.loads(path.read_text(encoding="utf-8"))
        if data.get("format") != FORMAT_VERSION or data.get("kind") != kind:
            raise ConfigError(
                "calibration record", str(path),
                f"format {FORMAT_VERSION} of kind {kind!r}", "re-run the calibration",
            )  # fmt: skip
        return StoredCalibration(
            id=data["id"],
            kind=kind,
            created_utc=dt.datetime.fromisoformat(data["created_utc"]),
            software_version=data["software_version"],
            settings=data["settings"],
            result=RESULT_TYPES[kind].from_json(data["result"]),
            path=path,
        )

    def current(self, kind: str) -> StoredCalibration | None:
        """The current record of ``kind``, or ``None`` if there is none."""
        pointer = self._dir(kind) / CURRENT
        if not pointer.is_file():
            return None
        return self.load(kind, pointer.read_text(encoding="utf-8").strip())

    def history(self, kind: str) -> list[str]:
        """Ids of every record of ``kind``, oldest first."""
        folder = self._dir(kind)
        if not folder.is_dir():
            return []
        return sorted(p.stem for p in folder.glob(f"{kind}-*.json"))

    def require(
        self, kind: str, max_age_s: float, now: dt.datetime | None = None
    ) -> StoredCalibration:
        """The current record of ``kind`` if present and at most ``max_age_s`` old; else a
        :class:`ConfigError` naming the calibration and the command to run."""
        if not max_age_s > 0:
            raise ConfigError("max_age_s", max_age_s, "a duration > 0 s")
        command = f"run: hil calibrate {kind} --store {self.root}"
        record = self.current(kind)
        if record is None:
            raise ConfigError(
                f"calibration {kind!r}", "missing", f"present in the store {self.root}", command
            )
        age = record.age_s(now)
        if age > max_age_s:
            raise ConfigError(
                f"calibration {kind!r}",
                f"{format_age(age)} old (id {record.id})",
                f"at most {format_age(max_age_s)} old",
                f"it is stale; {command}",
            )
        return record


def _jsonable(value: Any) -> Any:
    """JSON fallback for numpy scalars, tuples inside numpy arrays and paths."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot store {type(value).__name__} in a calibration record")
