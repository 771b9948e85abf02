"""The NeXus entry of a run recording: what ran, when, on what (``/entry``), and the time
axes as HDF5 dimension scales.

Layout (``NX_class`` in brackets; NeXus base classes NXentry, NXinstrument, NXpositioner,
NXdetector, NXcollection)::

    /                     [NXroot]   @default = "entry"
    /entry                [NXentry]  @default = "estimates"
        title             the run's name
        start_time        ISO 8601 (UTC), when the recording was created
        end_time          ISO 8601 (UTC), written when the writer closes ("" while it runs,
                          or if it was killed)
        program_name      "cas-hil", @version = hil.__version__
        estimates, telemetry, recording    hard links to the root NXdata groups
        calibration       [NXcollection] ids: the calibrations in force
        instrument        [NXinstrument] one group per device of the snapshot (below)

The instrument snapshot is a mapping ``device -> fields`` (built by
:mod:`hil.experiments.live.snapshot` for a live run): a field's value is a str, int, float
or bool (a scalar dataset), a list of them (a 1-D dataset), or a mapping (a subgroup,
``NXcollection``); the key ``nx_class`` gives the device group's class (default
``NXcollection``). Names follow NeXus's rule (letters, digits, ``_`` and ``.``).

Time axes: ``estimates/t_s``, ``telemetry/host_time_s`` and ``sync/host_time_s`` are
dimension scales attached to dimension 0 of every other column of their table, so xarray
(h5netcdf) and HDF5 tools see a time coordinate.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

import h5py
import numpy as np

from hil.errors import ConfigError

ENTRY = "entry"
END_TIME = f"{ENTRY}/end_time"
_END_TIME_BYTES = 40
PROGRAM_NAME = "cas-hil"
#: The NXdata groups the entry holds (hard links: the same groups as at the root).
ENTRY_DATA = ("estimates", "telemetry", "recording")
#: ``table -> time column``: the dimension scale of every other column of the table.
TIME_AXES = {"estimates": "t_s", "telemetry": "host_time_s", "sync": "host_time_s"}
_NAME = re.compile(r"^[A-Za-z0-9_]([A-Za-z0-9_.]*[A-Za-z0-9_])?$")

Snapshot = Mapping[str, Mapping[str, Any]]
"""``device -> {field: value}`` (see the module docstring)."""


def write_entry(
    f: h5py.File,
    *,
    start_time: str,
    version: str,
    title: str,
    calibration_ids: list[str],
    instrument: Snapshot,
) -> None:
    """Create ``/entry`` in the new recording ``f`` (before SWMR mode: no object can be
    created afterwards; :func:`write_end_time` only writes into one)."""
    f.attrs["default"] = ENTRY
    entry = f.create_group(ENTRY)
    entry.attrs["NX_class"] = "NXentry"
    entry.attrs["default"] = "estimates"
    entry["title"] = title
    entry["start_time"] = start_time
    entry.create_dataset("end_time", data=np.bytes_(b""), dtype=f"S{_END_TIME_BYTES}")
    entry["program_name"] = PROGRAM_NAME
    entry["program_name"].attrs["version"] = version
    for name in ENTRY_DATA:
        entry[name] = f[name]
    calibration = entry.create_group("calibration")
    calibration.attrs["NX_class"] = "NXcollection"
    calibration.create_dataset("ids", data=list(calibration_ids), dtype=h5py.string_dtype())
    group = entry.create_group("instrument")
    group.attrs["NX_class"] = "NXinstrument"
    group["name"] = f"{PROGRAM_NAME} tank"
    for device, fields in instrument.items():
        _write_group(group, device, fields, f"instrument.{device}")


def _write_group(parent: h5py.Group, name: str, fields: Mapping[str, Any], where: str) -> None:
    if not _NAME.match(name):
        raise ConfigError(where, name, "a NeXus name: letters, digits, _ and .", "rename it")
    group = parent.create_group(name)
    group.attrs["NX_class"] = str(fields.get("nx_class", "NXcollection"))
    for key, value in fields.items():
        if key == "nx_class" or value is None:
            continue
        if not _NAME.match(key):
            raise ConfigError(f"{where}.{key}", key, "a NeXus name: letters, digits, _ and .")
        if isinstance(value, Mapping):
            _write_group(group, key, value, f"{where}.{key}")
        elif isinstance(value, str | bool | int | float | np.integer | np.floating):
            group[key] = value
        elif isinstance(value, list | tuple) and value:
            kinds = {type(v) for v in value}
            data = np.asarray(value, dtype=h5py.string_dtype() if str in kinds else None)
            group.create_dataset(key, data=data)
        else:
            raise ConfigError(
                f"{where}.{key}", value, "a str, number, bool, non-empty list or mapping"
            )


def write_end_time(f: h5py.File, end_time: str) -> None:
    """Write ``end_time`` (ISO 8601) into the entry of ``f``, if it has one (older files,
    written before the entry existed, have none)."""
    if END_TIME in f:
        f[END_TIME][()] = np.bytes_(end_time.encode("ascii")[:_END_TIME_BYTES])


def attach_time_axes(f: h5py.File) -> None:
    """Make each table's time column a dimension scale of its other columns (see the
    module docstring); before SWMR mode (it writes attributes)."""
    for table, axis in TIME_AXES.items():
        group = f[table]
        scale = group[axis]
        scale.make_scale(axis)
        for column in group:
            if column != axis:
                group[column].dims[0].attach_scale(scale)


def read_entry(f: h5py.File) -> dict[str, Any] | None:
    """Everything ``/entry`` holds but its NXdata links, as plain values (strings decoded,
    groups as dicts, datasets of strings as lists); None for a file without an entry."""
    if ENTRY not in f:
        return None
    entry = f[ENTRY]
    out = _read_group(entry, skip=ENTRY_DATA)
    out["program_version"] = _text(entry["program_name"].attrs["version"])
    return out


def _read_group(group: h5py.Group, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, item in group.items():
        if key in skip:
            continue
        if isinstance(item, h5py.Group):
            out[key] = _read_group(item)
            continue
        value = item[()]
        if isinstance(value, np.ndarray):
            out[key] = [_text(v) for v in value.tolist()]
        else:
            out[key] = _text(value)
    return out


def _text(value: Any) -> Any:
    """Decoded bytes; numpy scalars as Python numbers."""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.generic):
        return value.item()
    return value
