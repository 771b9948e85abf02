"""The report of a scene sweep (trial ``scene``): per target detection, false estimates, errors.

Per grid point the trials are pooled (:func:`scene_rows`): a target's ``pd`` is ``Σ detected /
Σ expected`` boundaries over the point's trials, false estimates per hop ``Σ n_false / Σ
n_hops``, and the range and speed errors of every estimate that belongs to the target form its
RMSE and bias (m, m/s). Targets are numbered in the scene's order (``t1``, ``t2``). GOSPA
(:mod:`hil.evaluation.gospa`, cut-off 0.5 m, order 2) pooled the same way: its RMS per
boundary ``√(Σ d² / Σ boundaries)`` (m), the assigned pairs' RMS distance, missed and false
per boundary, and the track switches.
:func:`write_scene_report` writes

- ``scene_points.csv``: one row per point, the grid values then those figures;
- ``figures/scene_rates.png``: each target's pd and the false estimates per hop per point;
- ``report.md``: the sweep, the table (with the scenes' descriptions) and the figure.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from hil.evaluation.aggregate import records_by_point
from hil.evaluation.report import write_table
from hil.evaluation.report_tank import cell_text, point_label
from hil.evaluation.scenes import GATE_M, GATE_MPS, SCENES
from hil.evaluation.spec import SweepSpec
from hil.figures import new_figure, save_figure

#: Targets a scene has at most (the columns of the table).
MAX_TARGETS = 2


def _target_figures(ok: list[dict[str, Any]], i: int) -> dict[str, float]:
    """Pooled pd and errors of target ``i`` (0-based) over the trials ``ok``."""
    nan = math.nan
    res = [r["result"] for r in ok if i < len(r["result"].get("expected", []))]
    if not res:
        return {"pd": nan, "range_rmse_m": nan, "range_bias_m": nan, "speed_rmse_mps": nan,
                "speed_bias_mps": nan, "expected": 0}  # fmt: skip
    expected = sum(int(r["expected"][i]) for r in res)
    detected = sum(int(r["detected"][i]) for r in res)
    dr = np.array([v for r in res for v in r["range_errors_m"][i]], dtype=float)
    dv = np.array([v for r in res for v in r["speed_errors_mps"][i]], dtype=float)
    return {
        "pd": detected / expected if expected else nan,
        "range_rmse_m": float(np.sqrt(np.mean(dr * dr))) if dr.size else nan,
        "range_bias_m": float(np.mean(dr)) if dr.size else nan,
        "speed_rmse_mps": float(np.sqrt(np.mean(dv * dv))) if dv.size else nan,
        "speed_bias_mps": float(np.mean(dv)) if dv.size else nan,
        "expected": expected,
    }


def _gospa_figures(ok: list[dict[str, Any]]) -> dict[str, float]:
    """Pooled GOSPA of the trials ``ok``: its RMS per boundary (m), the assigned pairs' RMS
    distance (m), missed and false per boundary, and the track switches."""
    nan = math.nan

    def total(key: str) -> float:
        return float(sum(r["result"].get(key, 0) for r in ok))

    times, pairs = total("gospa_times"), total("gospa_pairs")
    return {
        "gospa_rms_m": math.sqrt(total("gospa_sum_m2") / times) if times else nan,
        "gospa_localisation_rms_m": (
            math.sqrt(total("gospa_localisation_m2") / pairs) if pairs else nan
        ),
        "gospa_missed_per_boundary": total("gospa_missed") / times if times else nan,
        "gospa_false_per_boundary": total("gospa_false") / times if times else nan,
        "track_switches": int(total("track_switches")),
    }


def scene_rows(spec: SweepSpec, records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per grid point: the grid values and the pooled figures (module docstring).

    >>> spec = SweepSpec("s", "scene", "m:t", 2, 0, {"scene": ["two-apart"]})
    >>> res = lambda d, f: {"expected": [10, 10], "detected": [d, 10], "n_false": f,
    ...     "n_duplicate": 0, "n_hops": 20, "range_errors_m": [[0.01] * d, [0.0]],
    ...     "speed_errors_mps": [[0.0], [0.02]], "beyond_span_said": 0, "clutter_said": 0}
    >>> recs = [{"point": 0, "status": "ok", "result": res(d, f)} for d, f in ((9, 1), (10, 0))]
    >>> row = scene_rows(spec, recs)[0]
    >>> row["pd_t1"], row["pd_t2"], row["false_per_hop"], row["range_rmse_t1_m"]
    (0.95, 1.0, 0.025, 0.01)
    """
    rows = []
    for point, recs in enumerate(records_by_point(spec, records)):
        ok = [r for r in recs if r.get("status") == "ok"]
        hops = sum(int(r["result"]["n_hops"]) for r in ok)
        false = sum(int(r["result"]["n_false"]) for r in ok)
        row: dict[str, Any] = {**spec.point_values(point), "n_ok": len(ok),
                               "n_failed": len(recs) - len(ok)}  # fmt: skip
        for i in range(MAX_TARGETS):
            f = _target_figures(ok, i)
            row[f"pd_t{i + 1}"] = f["pd"]
            row[f"expected_t{i + 1}"] = f["expected"]
            for key in ("range_rmse_m", "range_bias_m", "speed_rmse_mps", "speed_bias_mps"):
                name, unit = key.rsplit("_", 1)
                row[f"{name}_t{i + 1}_{unit}"] = f[key]
        row.update(_gospa_figures(ok))
        row.update(
            n_false=false,
            n_duplicate=sum(int(r["result"]["n_duplicate"]) for r in ok),
            false_per_hop=false / hops if hops else math.nan,
            beyond_span_said=sum(int(r["result"]["beyond_span_said"]) for r in ok),
            clutter_said=sum(int(r["result"]["clutter_said"]) for r in ok),
        )
        rows.append(row)
    return rows


def plot_rates(spec: SweepSpec, rows: list[dict[str, Any]], path: Path) -> Path:
    """Each target's pd and the false estimates per hop, per grid point."""
    x = np.arange(len(rows))
    size = (max(7.0, 0.4 * len(rows) + 2.0), 6.5)
    fig, (ax, ax_f) = new_figure(nrows=2, sharex=True, figsize=size)
    width = 0.8 / MAX_TARGETS
    for i in range(MAX_TARGETS):
        pd = [r[f"pd_t{i + 1}"] for r in rows]
        ax.bar(x - 0.4 + (i + 0.5) * width, pd, width, label=f"target {i + 1}")
    ax.axhline(0.95, color="0.5", lw=0.8, ls="--")
    ax.set_ylim(0.0, 1.05)
    ax.set_ylabel("pd (expected boundaries)")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(f"{spec.name}: detection per target, false estimates per hop")
    ax_f.bar(x, [r["false_per_hop"] for r in rows], 0.6, color="tab:red")
    ax_f.axhline(0.05, color="0.5", lw=0.8, ls="--")
    ax_f.set_ylabel("false per hop")
    ax_f.set_xticks(x, [point_label(spec, p) for p in range(len(rows))], rotation=90, fontsize=7)
    ax_f.set_xlabel(", ".join(spec.grid) or "point")
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def write_scene_report(spec: SweepSpec, records: list[dict[str, Any]], out_dir: Path) -> list[Path]:
    """Write the table, the figure and ``report.md`` into ``out_dir``; their paths."""
    out_dir = Path(out_dir)
    figures = out_dir / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    rows = scene_rows(spec, records)
    table = write_table(rows, out_dir / "scene_points.csv")
    rates_png = plot_rates(spec, rows, figures / "scene_rates.png")
    report = out_dir / "report.md"
    report.write_text(_markdown(spec, records, rows), encoding="utf-8")
    return [report, table, rates_png]


def _markdown(spec: SweepSpec, records: list[dict[str, Any]], rows: list[dict[str, Any]]) -> str:

    n_ok = sum(r.get("status") == "ok" for r in records)
    grid = ", ".join(f"{k} = {v}" for k, v in spec.grid.items()) or "none"
    fixed = ", ".join(f"{k} = {v}" for k, v in spec.fixed.items()) or "none"
    cols = [*spec.grid, "pd_t1", "pd_t2", "false_per_hop", "range_rmse_t1_m", "range_rmse_t2_m",
            "speed_rmse_t1_mps", "speed_rmse_t2_mps", "speed_bias_t1_mps", "gospa_rms_m",
            "gospa_missed_per_boundary", "gospa_false_per_boundary", "track_switches",
            "beyond_span_said",
            "clutter_said", "n_ok", "n_failed"]  # fmt: skip
    scenes = sorted({str(spec.point_values(p).get("scene", spec.fixed.get("scene", "")))
                     for p in range(spec.n_points)})  # fmt: skip
    lines = [
        f"# Scene sweep {spec.name}",
        "",
        spec.description or "",
        "",
        f"{spec.n_points} point(s) × {spec.trials_per_point} trial(s), seed {spec.seed}: "
        f"{n_ok} of {len(records)} recorded trials ran to the end. Grid: {grid}. Fixed: {fixed}.",
        "",
        f"An estimate belongs to a target when it is within {GATE_M} m and {GATE_MPS} m/s of "
        "the target's truth at its boundary; one that belongs to no target is false. pd: "
        "detected over expected boundaries (inside the span, outside the reverberation band); "
        "RMSE over every estimate that belongs to the target (m, m/s). GOSPA (cut-off 0.5 m, "
        "order 2, speed weighed 1 s) per boundary: RMS over the boundaries, missed and false "
        "per boundary; track switches: changes of a target's confirmed track. All columns: "
        "`scene_points.csv`.",
        "",
        "| " + " | ".join(cols) + " |",
        "|" + "---|" * len(cols),
    ]
    lines += ["| " + " | ".join(cell_text(row.get(c)) for c in cols) + " |" for row in rows]
    lines += ["", "Scenes:", ""]
    lines += [f"- `{name}`: {SCENES[name].what}" for name in scenes if name in SCENES]
    lines += ["", "![rates](figures/scene_rates.png)", ""]
    return "\n".join(lines)
