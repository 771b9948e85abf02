"""Append-only column tables inside an HDF5 group: one resizable 1-D dataset per column.

Rows are appended column by column; readers take the shortest column as the row count, so
a table read while (or after) its writer was interrupted between two column writes still
yields whole rows only.

String columns are fixed-length UTF-8 (:class:`~hil.recording.schema.FixedText`, format
version 2) or variable-length UTF-8 (version 1); both read back as ``str`` objects.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import h5py
import numpy as np
from h5py import h5s
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.recording.schema import ELLIPSIS, TABLE_CHUNK_ROWS, TABLES, FixedText, column_dtype


def create_table(parent: h5py.Group, name: str, columns: Sequence[tuple[str, Any]]) -> h5py.Group:
    """Create the group ``name`` with an empty, resizable dataset per ``(column, dtype)`` (a
    dtype or a :class:`~hil.recording.schema.FixedText`)."""
    group = parent.create_group(name)
    for column, spec in columns:
        group.create_dataset(
            column,
            shape=(0,),
            maxshape=(None,),
            dtype=column_dtype(spec),
            chunks=(TABLE_CHUNK_ROWS,),
        )
    group.attrs["columns"] = [column for column, _ in columns]
    return group


def fit_text(value: Any, spec: FixedText, field: str) -> bytes:
    """``value`` as UTF-8 that fits a fixed-length column of ``spec``.

    A longer value is cut on a character boundary and ends with ``…`` when ``spec.truncate``
    (so it still decodes); otherwise :class:`ConfigError` names ``field`` (``table.column``).

    >>> fit_text("ümlaut", FixedText(16, truncate=False), "t.c").decode()
    'ümlaut'
    >>> fit_text("ab€cd", FixedText(6, truncate=True), "t.c").decode()  # 7 bytes: € has 3
    'ab…'
    >>> fit_text("ab€cd", FixedText(6, truncate=False, hint="shorten it"), "t.c")
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: t.c = 'ab€cd' is not allowed: must be at most 6 bytes of UTF-8 ...
    """
    raw = str(value).encode("utf-8")
    if len(raw) <= spec.max_bytes:
        return raw
    if not spec.truncate:
        raise ConfigError(
            field, value, f"at most {spec.max_bytes} bytes of UTF-8 (it has {len(raw)})", spec.hint
        )
    mark = ELLIPSIS.encode("utf-8")
    # Cutting the bytes may split the last character: dropping its incomplete tail on decode
    # leaves a whole-character prefix.
    head = raw[: spec.max_bytes - len(mark)].decode("utf-8", errors="ignore")
    return head.encode("utf-8") + mark


def check_row(table: str, row: Sequence[Any]) -> None:
    """Raise the :class:`ConfigError` that appending ``row`` (one value per column of
    ``schema.TABLES[table]``) would raise, without writing anything: a writer that queues
    rows refuses a bad one when it is given, not at a later flush."""
    for (column, spec), value in zip(TABLES[table], row, strict=True):
        if isinstance(spec, FixedText):
            fit_text(value, spec, f"{table}.{column}")


def _stored(
    dtype: np.dtype[Any], values: Sequence[Any] | NDArray[Any], spec: Any, field: str
) -> Sequence[Any] | NDArray[Any]:
    """``values`` as a column of ``dtype`` stores them (strings encoded, fitted to the
    length)."""
    info = h5py.check_string_dtype(dtype)
    if info is None:
        return values
    if info.length is None:  # variable-length (format version 1)
        return np.asarray(values, dtype=object)
    if not isinstance(spec, FixedText):  # a column the schema does not describe: never cut
        spec = FixedText(info.length, truncate=False)
    return np.array([fit_text(v, spec, field) for v in values], dtype=dtype)


def _append(ds: h5py.Dataset, dtype: np.dtype[Any], values: Any, n: int) -> None:
    """Grow the 1-D dataset ``ds`` (of ``dtype``) by ``n`` rows holding ``values``.

    What ``ds.resize`` and ``ds[start:] = values`` do for such a column (the same bytes in
    the file: a list is converted by NumPy to the column's dtype, an array by HDF5 as it is
    written), through h5py's low-level calls: its high-level slicing costs about 0.3 ms of
    Python a column, several tables of a dozen columns at every flush. Object (vlen)
    columns take the high-level path, which builds their memory type.
    """
    start = int(ds.id.shape[0])
    if dtype.kind == "O":
        ds.resize((start + n,))
        ds[start:] = values
        return
    ds.id.set_extent((start + n,))
    if isinstance(values, np.ndarray):
        val = np.ascontiguousarray(values)
    else:
        val = np.asarray(values, order="C", dtype=dtype.base)
    file_space = ds.id.get_space()
    file_space.select_hyperslab((start,), (n,))
    ds.id.write(h5s.create_simple((n,)), file_space, val)


def append_rows(group: h5py.Group, columns: Mapping[str, Sequence[Any] | NDArray[Any]]) -> None:
    """Append equal-length column arrays (every column of the table) as new rows.

    Text for a fixed-length string column is encoded as UTF-8 and fitted to the column as
    the schema says (:class:`~hil.recording.schema.FixedText`: cut, or refused with
    :class:`ConfigError`). Every column is converted before any is written, so a refused
    value leaves the table as it was.
    """
    lengths = {len(v) for v in columns.values()}
    if len(lengths) != 1:
        raise ValueError(f"columns of unequal length {sorted(lengths)}")
    n = lengths.pop()
    if n == 0:
        return
    table = group.name.rsplit("/", 1)[-1]
    specs = dict(TABLES.get(table, ()))
    datasets = {c: group[c] for c in columns}
    dtypes = {c: ds.dtype for c, ds in datasets.items()}
    data = {c: _stored(dtypes[c], v, specs.get(c), f"{table}.{c}") for c, v in columns.items()}
    for column, values in data.items():
        _append(datasets[column], dtypes[column], values, n)


def table_rows(group: h5py.Group, *, refresh: bool) -> int:
    """Whole rows in the table (the shortest column)."""
    names = [str(c) for c in group.attrs["columns"]]
    if refresh:
        for c in names:
            group[c].refresh()
    return min(group[c].shape[0] for c in names)


def read_table(
    group: h5py.Group, *, refresh: bool, start: int = 0, columns: Sequence[str] | None = None
) -> dict[str, NDArray[Any]]:
    """Columns (default: every one) as arrays of the table's whole rows from row ``start``
    on (strings, fixed- or variable-length, as ``str`` objects; fixed-length values lose
    their NUL padding)."""
    n = table_rows(group, refresh=refresh)
    start = min(max(int(start), 0), n)
    out: dict[str, NDArray[Any]] = {}
    names = [str(c) for c in group.attrs["columns"]] if columns is None else list(columns)
    for c in names:
        ds = group[c]
        if h5py.check_string_dtype(ds.dtype) is not None:
            out[c] = np.asarray(ds.asstr()[start:n], dtype=object)
        else:
            out[c] = ds[start:n]
    return out
