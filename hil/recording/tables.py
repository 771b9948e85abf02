"""Append-only column tables inside an HDF5 group: one resizable 1-D dataset per column.

Rows are appended column by column; readers take the shortest column as the row count, so
a table read while (or after) its writer was interrupted between two column writes still
yields whole rows only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

from hil.recording.schema import TABLE_CHUNK_ROWS


def create_table(parent: h5py.Group, name: str, columns: Sequence[tuple[str, Any]]) -> h5py.Group:
    """Create the group ``name`` with an empty, resizable dataset per ``(column, dtype)``."""
    group = parent.create_group(name)
    for column, dtype in columns:
        group.create_dataset(
            column, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(TABLE_CHUNK_ROWS,)
        )
    group.attrs["columns"] = [column for column, _ in columns]
    return group


def append_rows(group: h5py.Group, columns: Mapping[str, Sequence[Any] | NDArray[Any]]) -> None:
    """Append equal-length column arrays (every column of the table) as new rows."""
    lengths = {len(v) for v in columns.values()}
    if len(lengths) != 1:
        raise ValueError(f"columns of unequal length {sorted(lengths)}")
    n = lengths.pop()
    if n == 0:
        return
    for column, values in columns.items():
        ds = group[column]
        start = ds.shape[0]
        ds.resize((start + n,))
        is_text = h5py.check_string_dtype(ds.dtype) is not None
        ds[start:] = np.asarray(values, dtype=object) if is_text else values


def table_rows(group: h5py.Group, *, refresh: bool) -> int:
    """Whole rows in the table (the shortest column)."""
    names = [str(c) for c in group.attrs["columns"]]
    if refresh:
        for c in names:
            group[c].refresh()
    return min(group[c].shape[0] for c in names)


def read_table(group: h5py.Group, *, refresh: bool) -> dict[str, NDArray[Any]]:
    """Every column as an array of the table's whole rows (strings as ``str`` objects)."""
    n = table_rows(group, refresh=refresh)
    out: dict[str, NDArray[Any]] = {}
    for c in (str(c) for c in group.attrs["columns"]):
        ds = group[c]
        if h5py.check_string_dtype(ds.dtype) is not None:
            out[c] = np.asarray(ds.asstr()[:n], dtype=object)
        else:
            out[c] = ds[:n]
    return out
