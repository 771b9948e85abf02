"""Per grid point statistics of a sweep's records, and the CSV table.

For every numeric result field ``f`` (int, float or bool; bool counts as 0/1) a point gets
``f_mean``, ``f_rmse`` = √(mean f²) (the RMSE when ``f`` is an error, estimate − truth),
``f_std`` (sample standard deviation, ddof = 1; empty below two values) and ``f_count`` (finite
values used; NaN and ±inf are left out). Text and list fields are not summarised. Failed trials
are counted per point (``n_failed``) and contribute no values.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from hil.evaluation.spec import SweepSpec

#: Columns every summary row starts with, before the grid parameters.
LEAD_COLUMNS = ("point",)
#: Count columns after the grid parameters.
COUNT_COLUMNS = ("n_trials", "n_done", "n_ok", "n_failed")
STATS = ("mean", "rmse", "std", "count")


def latest_records(records: list[dict[str, Any]]) -> dict[int, dict[str, Any]]:
    """The last record of every trial id (a trial recorded twice keeps its latest record)."""
    return {int(r["trial_id"]): r for r in records}


def numeric_fields(records: list[dict[str, Any]]) -> list[str]:
    """Names of the result fields that hold numbers, in order of first appearance."""
    fields: dict[str, None] = {}
    for rec in records:
        for key, value in rec.get("result", {}).items():
            if isinstance(value, (int, float)):
                fields.setdefault(key)
    return list(fields)


def records_by_point(spec: SweepSpec, records: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """The records of every grid point, in point order (a point without records: empty).

    >>> spec = SweepSpec("d", "t", "m:t", 1, 0, {"a": [1, 2, 3]})
    >>> [[r["trial_id"] for r in recs] for recs in records_by_point(
    ...     spec, [{"trial_id": 2, "point": 2}, {"trial_id": 0, "point": 0}])]
    [[0], [], [2]]
    """
    by_point: list[list[dict[str, Any]]] = [[] for _ in range(spec.n_points)]
    for rec in records:
        by_point[int(rec["point"])].append(rec)
    return by_point


def summarise(spec: SweepSpec, records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per grid point: point index, grid values, counts and statistics.

    >>> spec = SweepSpec("d", "t", "m:t", 3, 0, {"a": [1, 2]})
    >>> recs = [{"trial_id": i, "point": i // 3, "status": "ok", "result": {"e": v}}
    ...         for i, v in enumerate([1.0, -1.0, 3.0, 2.0, 2.0])]
    >>> recs.append({"trial_id": 5, "point": 1, "status": "error"})
    >>> rows = summarise(spec, recs)
    >>> [(r["a"], r["n_ok"], r["n_failed"], r["e_mean"], r["e_rmse"]) for r in rows]
    [(1, 3, 0, 1.0, 1.9148542155126762), (2, 2, 1, 2.0, 2.0)]
    """
    latest = list(latest_records(records).values())
    fields = numeric_fields(latest)
    rows = []
    for point, recs in enumerate(records_by_point(spec, latest)):
        ok = [r for r in recs if r.get("status") == "ok"]
        row: dict[str, Any] = {"point": point, **spec.point_values(point)}
        row.update(
            n_trials=spec.trials_per_point,
            n_done=len(recs),
            n_ok=len(ok),
            n_failed=len(recs) - len(ok),
        )
        for field in fields:
            values = [r["result"].get(field) for r in ok]
            row.update(_stats(field, values))
        rows.append(row)
    return rows


def _stats(field: str, values: list[Any]) -> dict[str, Any]:
    x = np.array(
        [float(v) for v in values if isinstance(v, (int, float))],
        dtype=float,
    )
    x = x[np.isfinite(x)]
    n = int(x.size)
    return {
        f"{field}_mean": float(np.mean(x)) if n else None,
        f"{field}_rmse": float(np.sqrt(np.mean(x * x))) if n else None,
        f"{field}_std": float(np.std(x, ddof=1)) if n > 1 else None,
        f"{field}_count": n,
    }


def columns(spec: SweepSpec, rows: list[dict[str, Any]]) -> list[str]:
    """The CSV header: lead, grid parameters, counts, then the statistics columns."""
    fixed = [*LEAD_COLUMNS, *spec.grid, *COUNT_COLUMNS]
    extra = [key for key in (rows[0] if rows else {}) if key not in fixed]
    return fixed + extra


def write_summary_csv(path: str | Path, spec: SweepSpec, rows: list[dict[str, Any]]) -> None:
    """Write the summary table (empty cell for a missing statistic); atomically replaced."""
    path = Path(path)
    tmp = path.with_suffix(path.suffix + ".tmp")
    with tmp.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns(spec, rows), lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _cell(v) for k, v in row.items()})
    tmp.replace(path)


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return value
