"""The report of a tank sweep (trial ``tank_run``): rates and error distributions per point.

Per grid point the trials are pooled (:func:`tank_rows`): the detection rate is
``Σ detected / Σ expected`` hop boundaries over every trial of the point, the false-alarm rate
``Σ false alarms / Σ scored estimates``, and the range and speed errors of every scored
estimate of every trial form the point's distribution: RMSE, bias (mean), median and the 5th
and 95th percentiles (m, m/s). :func:`write_tank_report` writes

- ``tank_points.csv``: one row per point, the grid values then those figures;
- ``figures/tank_range_errors.png``, ``figures/tank_speed_errors.png``: the error
  distributions per point (box: quartiles, whiskers: 5th–95th percentile);
- ``figures/tank_rates.png``: detection and false-alarm rates per point;
- ``report.md``: the sweep, the table and the figures.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from hil.evaluation.aggregate import records_by_point
from hil.evaluation.report import write_table
from hil.evaluation.spec import SweepSpec
from hil.figures import new_figure, save_figure

#: Columns of ``tank_points.csv`` after the grid parameters.
COLUMNS = (
    "n_ok", "n_failed", "expected_boundaries", "detected_boundaries", "detection_rate",
    "scored_estimates", "false_alarms", "false_alarm_rate", "range_rmse_m", "range_bias_m",
    "range_p05_m", "range_median_m", "range_p95_m", "speed_rmse_mps", "speed_bias_mps",
    "speed_p05_mps", "speed_median_mps", "speed_p95_mps",
)  # fmt: skip
_PERCENTILES = (5.0, 50.0, 95.0)


def point_errors(records: list[dict[str, Any]], key: str) -> np.ndarray:
    """Every scored estimate's error ``key`` (``range_errors_m``, ``speed_errors_mps``) of the
    successful ``records``, one array."""
    parts = [np.asarray(r["result"].get(key) or [], dtype=float) for r in records]
    return np.concatenate(parts) if parts else np.zeros(0)


def _distribution(err: np.ndarray, name: str, unit: str) -> dict[str, float]:
    err = err[np.isfinite(err)]
    if err.size == 0:
        nan = math.nan
        return {f"{name}_{s}_{unit}": nan for s in ("rmse", "bias", "p05", "median", "p95")}
    p05, p50, p95 = np.percentile(err, _PERCENTILES)
    return {
        f"{name}_rmse_{unit}": float(np.sqrt(np.mean(err * err))),
        f"{name}_bias_{unit}": float(np.mean(err)),
        f"{name}_p05_{unit}": float(p05),
        f"{name}_median_{unit}": float(p50),
        f"{name}_p95_{unit}": float(p95),
    }


def tank_rows(spec: SweepSpec, records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per grid point: the grid values and the pooled figures (module docstring).

    >>> spec = SweepSpec("t", "tank_run", "m:t", 2, 0, {"tow_speed_mps": [1.5]})
    >>> recs = [{"point": 0, "status": "ok", "result": {"expected_boundaries": 10,
    ...          "detected_boundaries": d, "scored_estimates": 10, "false_alarms": f,
    ...          "range_errors_m": e, "speed_errors_mps": [0.0]}}
    ...         for d, f, e in ((10, 0, [0.01, -0.01]), (8, 2, [0.02]))]
    >>> row = tank_rows(spec, recs)[0]
    >>> row["detection_rate"], row["false_alarm_rate"], round(row["range_rmse_m"], 6)
    (0.9, 0.1, 0.014142)
    """
    rows = []
    for point, recs in enumerate(records_by_point(spec, records)):
        ok = [r for r in recs if r.get("status") == "ok"]
        expected = sum(int(r["result"].get("expected_boundaries") or 0) for r in ok)
        detected = sum(int(r["result"].get("detected_boundaries") or 0) for r in ok)
        scored = sum(int(r["result"].get("scored_estimates") or 0) for r in ok)
        false = sum(int(r["result"].get("false_alarms") or 0) for r in ok)
        row: dict[str, Any] = {**spec.point_values(point), "n_ok": len(ok)}
        row.update(
            n_failed=len(recs) - len(ok),
            expected_boundaries=expected,
            detected_boundaries=detected,
            detection_rate=detected / expected if expected else math.nan,
            scored_estimates=scored,
            false_alarms=false,
            false_alarm_rate=false / scored if scored else math.nan,
        )
        row.update(_distribution(point_errors(ok, "range_errors_m"), "range", "m"))
        row.update(_distribution(point_errors(ok, "speed_errors_mps"), "speed", "mps"))
        rows.append(row)
    return rows


def point_label(spec: SweepSpec, point: int) -> str:
    """The swept values of a point, short: ``"1.5, closing"`` (all grid parameters).

    >>> point_label(SweepSpec("t", "t", "m:t", 1, 0, {"a": [[12, 4, 2.5]], "b": ["x"]}), 0)
    '12×4×2.5, x'
    """
    parts = []
    for value in spec.point_values(point).values():
        if isinstance(value, list):
            parts.append("×".join(f"{v:g}" for v in value))
        elif isinstance(value, float):
            parts.append(f"{value:g}")
        else:
            parts.append(str(value))
    return ", ".join(parts) or "all"


def plot_errors(
    spec: SweepSpec, records: list[dict[str, Any]], key: str, ylabel: str, path: Path
) -> Path:
    """Box plot of the error ``key`` per grid point (whiskers at the 5th and 95th percentiles)."""
    data, labels = [], []
    for point, recs in enumerate(records_by_point(spec, records)):
        err = point_errors([r for r in recs if r.get("status") == "ok"], key)
        data.append(err[np.isfinite(err)])
        labels.append(point_label(spec, point))
    fig, ax = new_figure(figsize=(max(6.0, 0.35 * spec.n_points + 2.0), 4.5))
    ax.boxplot(data, whis=(5, 95), showfliers=False)
    ax.axhline(0.0, color="0.6", lw=0.8)
    ax.set_xticks(range(1, len(labels) + 1), labels, rotation=90, fontsize=7)
    ax.set_ylabel(ylabel)
    ax.set_xlabel(", ".join(spec.grid) or "point")
    ax.set_title(f"{spec.name}: {ylabel} per point ({spec.trials_per_point} trial(s) each)")
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def plot_rates(spec: SweepSpec, rows: list[dict[str, Any]], path: Path) -> Path:
    """Detection and false-alarm rates per grid point."""
    x = np.arange(len(rows))
    fig, ax = new_figure(figsize=(max(6.0, 0.35 * len(rows) + 2.0), 4.5))
    ax.bar(x - 0.2, [r["detection_rate"] for r in rows], 0.4, label="detection rate")
    ax.bar(x + 0.2, [r["false_alarm_rate"] for r in rows], 0.4, label="false-alarm rate")
    ax.set_xticks(x, [point_label(spec, p) for p in range(len(rows))], rotation=90, fontsize=7)
    ax.set_ylim(0.0, 1.05)
    ax.set_xlabel(", ".join(spec.grid) or "point")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(f"{spec.name}: detection / expected boundaries, false alarms / scored")
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def write_tank_report(spec: SweepSpec, records: list[dict[str, Any]], out_dir: Path) -> list[Path]:
    """Write the table, the three figures and ``report.md`` into ``out_dir``; their paths."""
    out_dir = Path(out_dir)
    figures = out_dir / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    rows = tank_rows(spec, records)
    table = write_table(rows, out_dir / "tank_points.csv")
    range_png = plot_errors(
        spec, records, "range_errors_m", "range error (m)", figures / "tank_range_errors.png"
    )
    speed_png = plot_errors(
        spec, records, "speed_errors_mps", "speed error (m/s)", figures / "tank_speed_errors.png"
    )
    rates_png = plot_rates(spec, rows, figures / "tank_rates.png")
    report = out_dir / "report.md"
    report.write_text(_markdown(spec, records, rows), encoding="utf-8")
    return [report, table, range_png, speed_png, rates_png]


def _markdown(spec: SweepSpec, records: list[dict[str, Any]], rows: list[dict[str, Any]]) -> str:
    n_ok = sum(r.get("status") == "ok" for r in records)
    grid = ", ".join(f"{k} = {v}" for k, v in spec.grid.items()) or "none"
    fixed = ", ".join(f"{k} = {v}" for k, v in spec.fixed.items()) or "none"
    cols = [*spec.grid, "detection_rate", "false_alarm_rate", "range_rmse_m", "range_bias_m",
            "range_p05_m", "range_p95_m", "speed_rmse_mps", "speed_bias_mps", "n_ok",
            "n_failed"]  # fmt: skip
    lines = [
        f"# Tank sweep {spec.name}",
        "",
        spec.description or "",
        "",
        f"{spec.n_points} point(s) × {spec.trials_per_point} trial(s), seed {spec.seed}: "
        f"{n_ok} of {len(records)} recorded trials ran to the end. Grid: {grid}. Fixed: {fixed}.",
        "",
        "Detection rate: detected / expected hop boundaries; false-alarm rate: false alarms / "
        "scored estimates; errors over every scored estimate of the point's trials (m, m/s), "
        "estimate less truth: p05 and p95 are the signed errors' 5th and 95th percentiles. "
        "All columns: `tank_points.csv`.",
        "",
        "| " + " | ".join(cols) + " |",
        "|" + "---|" * len(cols),
    ]
    lines += ["| " + " | ".join(cell_text(row.get(c)) for c in cols) + " |" for row in rows]
    lines += [
        "",
        "![range errors](figures/tank_range_errors.png)",
        "",
        "![speed errors](figures/tank_speed_errors.png)",
        "",
        "![rates](figures/tank_rates.png)",
        "",
    ]
    return "\n".join(lines)


def cell_text(value: Any) -> str:
    """A table cell: 4 significant digits, "–" for none or NaN, lists joined by "×".

    >>> cell_text(0.123456), cell_text(math.nan), cell_text([12, 4, 2.5]), cell_text(3)
    ('0.1235', '–', '12×4×2.5', '3')
    """
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list):
        return "×".join(f"{v:g}" for v in value)
    return str(value)
