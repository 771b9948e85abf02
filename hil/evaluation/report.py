"""Figures, CSV tables and ``report.md`` of a ``hil reproduce`` run (chapter 6 of the seed).

Per grid point the trials' sums are pooled (:func:`pool_rows`): the range RMSE of a point is
``√(Σ range_sse / Σ n_detected)`` over every detected boundary of every trial, not the mean of
per-trial RMSEs; ``pd = Σ n_detected / Σ n_truth``; false alarms per second of scored signal.
Figures (PNG, matplotlib's Agg backend, imported inside the functions):

- RMSE of range and speed against the item's x parameter (SNR, SRR or M), one line per series
  (the other grid parameters), the Cramér–Rao bound of each series dashed;
- detection probability and false alarms per second against the same x;
- time–codeword maps ``P[n, j]`` (dB over the map's median) with the true codeword of every
  received hop boundary marked, in the style of seed Fig 5.17;
- multiplications per sample against M (cost items); FMCW range bias against speed.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hil.evaluation.aggregate import records_by_point
from hil.evaluation.spec import SweepSpec
from hil.figures import new_figure

#: Pooled columns of an HFC-CW or FMCW table, after the grid parameters.
POOLED = (
    "n_ok", "n_failed", "n_truth", "n_detected", "pd", "false_per_s", "range_rmse_m",
    "range_bias_m", "speed_rmse_mps", "speed_bias_mps", "range_rmse_all_m", "crlb_range_m",
    "crlb_speed_mps", "e_over_n0_db", "predicted_saw_bias_m", "receiver_cpu_s",
)  # fmt: skip
#: Detection probability at and above which an SNR counts as past the threshold.
PD_THRESHOLD = 0.9


@dataclass
class ItemResult:
    """What the report needs of one item: its definition, records and run facts."""

    item_id: str
    title: str
    seed_ref: str
    kind: str
    x: str
    spec: SweepSpec
    records: list[dict[str, Any]]
    sweep_file: str
    elapsed_s: float
    map_filter: dict[str, Any] = field(default_factory=dict)


def _ok(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [r for r in records if r.get("status") == "ok"]


def _sum(recs: list[dict[str, Any]], key: str) -> float:
    return float(sum(float(r["result"].get(key, 0.0)) for r in recs))


def _mean(recs: list[dict[str, Any]], key: str) -> float:
    vals = [float(r["result"][key]) for r in recs if isinstance(r["result"].get(key), (int, float))]
    vals = [v for v in vals if math.isfinite(v)]
    return float(np.mean(vals)) if vals else math.nan


def pool_rows(spec: SweepSpec, records: list[dict[str, Any]], kind: str) -> list[dict[str, Any]]:
    """One row per grid point: the grid values and the pooled statistics (module docstring).

    >>> spec = SweepSpec("d", "t", "m:t", 2, 0, {"snr_db": [0.0]})
    >>> recs = [{"point": 0, "status": "ok", "result": {"n_truth": 10, "n_detected": n,
    ...          "n_false": 1, "window_s": 0.5, "range_sse_m2": s, "range_err_sum_m": 0.0,
    ...          "speed_sse": 0.0, "speed_err_sum": 0.0, "range_sse_all_m2": s}}
    ...         for n, s in ((10, 1.0), (5, 1.4))]
    >>> row = pool_rows(spec, recs, "rmse")[0]
    >>> row["pd"], row["range_rmse_m"], row["false_per_s"]
    (0.75, 0.4, 2.0)
    """
    rows = []
    for point, recs in enumerate(records_by_point(spec, records)):
        ok = _ok(recs)
        row: dict[str, Any] = {**spec.point_values(point), "n_ok": len(ok)}
        row["n_failed"] = len(recs) - len(ok)
        if kind == "cost":
            for key in ok[0]["result"] if ok else []:
                row[key] = _mean(ok, key)
        else:
            row.update(_pooled(ok))
        rows.append(row)
    return rows


def _pooled(ok: list[dict[str, Any]]) -> dict[str, Any]:
    nan = math.nan
    n_det = _sum(ok, "n_detected")
    n_truth = _sum(ok, "n_truth")
    n_all = _sum(ok, "n_estimates")
    window = _sum(ok, "window_s")
    out: dict[str, Any] = {
        "n_truth": int(n_truth),
        "n_detected": int(n_det),
        "pd": n_det / n_truth if n_truth else nan,
        "false_per_s": _sum(ok, "n_false") / window if window else nan,
        "range_rmse_m": math.sqrt(_sum(ok, "range_sse_m2") / n_det) if n_det else nan,
        "range_bias_m": _sum(ok, "range_err_sum_m") / n_det if n_det else nan,
        "speed_rmse_mps": math.sqrt(_sum(ok, "speed_sse") / n_det) if n_det else nan,
        "speed_bias_mps": _sum(ok, "speed_err_sum") / n_det if n_det else nan,
        "range_rmse_all_m": math.sqrt(_sum(ok, "range_sse_all_m2") / n_all) if n_all else nan,
    }
    for key in ("crlb_range_m", "crlb_speed_mps", "e_over_n0_db", "predicted_saw_bias_m",
                "receiver_cpu_s"):  # fmt: skip
        out[key] = _mean(ok, key)
    return out


def write_table(rows: list[dict[str, Any]], path: Path) -> Path:
    """Write pooled rows as CSV (lists as JSON, NaN as empty)."""
    keys = list(dict.fromkeys(k for row in rows for k in row))
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _cell(row.get(k)) for k in keys})
    return path


def _cell(v: Any) -> Any:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, (list, dict)):
        return json.dumps(v)
    if isinstance(v, float):
        return f"{v:.6g}"
    return v


# ----------------------------------------------------------------------------- series
def _label(value: Any) -> str:
    if isinstance(value, list):
        return "–".join(f"{v:g}" for v in value)
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def series(rows: list[dict[str, Any]], grid: Sequence[str], x: str) -> dict[str, list[dict]]:
    """Rows grouped by the grid parameters other than ``x``, each group sorted by ``x``.

    >>> rows = [{"m": 5, "snr": 0.0}, {"m": 5, "snr": -5.0}, {"m": 10, "snr": 0.0}]
    >>> {k: [r["snr"] for r in v] for k, v in series(rows, ["m", "snr"], "snr").items()}
    {'m=5': [-5.0, 0.0], 'm=10': [0.0]}
    """
    keys = [k for k in grid if k != x]
    groups: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        name = ", ".join(f"{k}={_label(row[k])}" for k in keys) or "all"
        groups.setdefault(name, []).append(row)
    return {k: sorted(v, key=lambda r: float(r[x])) for k, v in groups.items()}


def threshold_x(group: list[dict[str, Any]], x: str, pd_min: float = PD_THRESHOLD) -> float:
    """Lowest ``x`` from which ``pd >= pd_min`` at every larger ``x`` (NaN if never).

    >>> threshold_x([{"s": -10, "pd": 0.2}, {"s": -5, "pd": 0.95}, {"s": 0, "pd": 1.0}], "s")
    -5.0
    """
    best = math.nan
    for row in reversed(group):
        pd = row.get("pd")
        if not (isinstance(pd, float) and pd >= pd_min):
            break
        best = float(row[x])
    return best


# ----------------------------------------------------------------------------- figures

_X_LABELS = {
    "snr_db": "per-sample input SNR over 0…fs/2 (dB)",
    "srr_db": "signal-to-reverberation ratio (dB)",
    "m_hops": "correlator length M (hops)",
    "speed_mps": "closing speed (m/s)",
}


def _finite(xs: list[float], ys: list[float]) -> tuple[list[float], list[float]]:
    pairs = [(a, b) for a, b in zip(xs, ys, strict=True) if math.isfinite(b) and b > 0]
    return [p[0] for p in pairs], [p[1] for p in pairs]


def plot_rmse(res: ItemResult, rows: list[dict[str, Any]], path: Path) -> Path:
    """Range and speed RMSE against ``res.x`` with each series' CRLB dashed."""
    groups = series(rows, list(res.spec.grid), res.x)
    fig, axes = new_figure(1, 2, figsize=(11, 4.2))
    panels = (("range_rmse_m", "crlb_range_m", "range RMSE (m)"),
              ("speed_rmse_mps", "crlb_speed_mps", "speed RMSE (m/s)"))  # fmt: skip
    for ax, (key, bound, ylabel) in zip(axes, panels, strict=True):
        drawn: set[tuple[float, ...]] = set()
        for i, (name, group) in enumerate(groups.items()):
            colour = f"C{i % 10}"
            xs = [float(r[res.x]) for r in group]
            ax.semilogy(*_finite(xs, [r[key] for r in group]), "o-", color=colour, label=name)
            # Series sharing one bound (same window and E/N0) get one dashed line.
            curve = tuple(round(float(r[x]), 9) for r in group for x in (res.x, bound))
            if curve in drawn:
                continue
            drawn.add(curve)
            ax.semilogy(*_finite(xs, [r[bound] for r in group]), "--", color=colour, lw=1,
                        label=f"CRLB ({name})")  # fmt: skip
        ax.set_xlabel(_X_LABELS.get(res.x, res.x))
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{res.title} — detected boundaries only; dashed: CRLB", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def plot_detection(res: ItemResult, rows: list[dict[str, Any]], path: Path) -> Path:
    """Detection probability and false alarms per second against ``res.x``."""
    groups = series(rows, list(res.spec.grid), res.x)
    fig, axes = new_figure(1, 2, figsize=(11, 4.0))
    for i, (name, group) in enumerate(groups.items()):
        xs = [float(r[res.x]) for r in group]
        axes[0].plot(xs, [r["pd"] for r in group], "o-", color=f"C{i % 10}", label=name)
        axes[1].plot(xs, [r["false_per_s"] for r in group], "o-", color=f"C{i % 10}", label=name)
    axes[0].set_ylabel("detection probability per hop boundary")
    axes[0].set_ylim(-0.02, 1.02)
    axes[1].set_ylabel("false alarms per second")
    for ax in axes:
        ax.set_xlabel(_X_LABELS.get(res.x, res.x))
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{res.title} — detection", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def plot_cost(res: ItemResult, rows: list[dict[str, Any]], path: Path) -> Path:
    """Complex multiplies per sample against M (log scale); measured GCAS time if present."""
    rows = sorted(rows, key=lambda r: float(r["m_hops"]))
    m = [float(r["m_hops"]) for r in rows]
    measured = all(math.isfinite(r.get("gcas_cpu_s_per_s", math.nan)) for r in rows)
    fig, axes = new_figure(1, 2 if measured else 1, figsize=(11 if measured else 6, 4.2))
    ax = axes[0] if measured else axes
    curves = (
        ("gcas_mults", "GCAS (2 N_F D)"),
        ("fft_bank_mults", "FFT overlap-save bank"),
        ("direct_bank_mults", "direct matched-filter bank (J D M N_h)"),
        ("gcas_adds", "GCAS additions"),
    )
    for key, label in curves:
        ax.semilogy(m, [r[key] for r in rows], "o-" if "mults" in key else "x:", label=label)
    ax.set_xlabel(_X_LABELS["m_hops"])
    ax.set_ylabel("operations per sample")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    if measured:
        axes[1].plot(m, [r["gcas_cpu_s_per_s"] for r in rows], "o-")
        axes[1].set_xlabel(_X_LABELS["m_hops"])
        axes[1].set_ylabel("GCAS CPU s per s of signal (measured)")
        axes[1].set_ylim(bottom=0)
        axes[1].grid(True, alpha=0.3)
    fig.suptitle(res.title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def plot_fmcw(res: ItemResult, rows: list[dict[str, Any]], path: Path) -> Path:
    """FMCW range bias (with the predicted sawtooth bias) and range RMSE against speed."""
    groups = series(rows, list(res.spec.grid), res.x)
    fig, axes = new_figure(1, 2, figsize=(11, 4.2))
    for i, (name, group) in enumerate(groups.items()):
        c = f"C{i % 10}"
        xs = [float(r[res.x]) for r in group]
        axes[0].plot(xs, [r["range_bias_m"] for r in group], "o-", color=c, label=name)
        if "saw" in name:
            axes[0].plot(xs, [r["predicted_saw_bias_m"] for r in group], "--", color=c,
                         label="predicted −T v f0/B")  # fmt: skip
        axes[1].semilogy(*_finite(xs, [r["range_rmse_m"] for r in group]), "o-", color=c,
                         label=name)  # fmt: skip
        axes[1].semilogy(*_finite(xs, [r["crlb_range_m"] for r in group]), "--", color=c, lw=1)
    axes[0].set_ylabel("range bias (m)")
    axes[1].set_ylabel("range RMSE (m); dashed: CRLB of one sweep")
    for ax in axes:
        ax.set_xlabel(_X_LABELS["speed_mps"])
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(res.title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def map_records(res: ItemResult) -> list[dict[str, Any]]:
    """Records holding a time–codeword map that pass the item's ``map_filter``."""
    out = []
    for rec in _ok(res.records):
        if "map_db" not in rec["result"]:
            continue
        if all(rec["params"].get(k) == v for k, v in res.map_filter.items()):
            out.append(rec)
    return sorted(out, key=lambda r: int(r["point"]))


def plot_map(res: ItemResult, rec: dict[str, Any], path: Path) -> Path:
    """Time–codeword map (dB over its median) with the true codewords marked (seed Fig 5.17)."""
    r = rec["result"]
    t = np.asarray(r["map_t_s"])
    p = np.asarray(r["map_db"], dtype=float).T  # (J, n)
    fig, ax = new_figure(figsize=(10, 4.2))
    step = float(t[1] - t[0]) if t.shape[0] > 1 else 1e-3
    extent = (t[0] - step / 2, t[-1] + step / 2, -0.5, p.shape[0] - 0.5)
    top = float(np.nanmax(p)) if np.isfinite(p).any() else 1.0
    img = ax.imshow(p, aspect="auto", origin="lower", extent=extent, cmap="viridis",
                    vmin=max(0.0, top - 25.0), vmax=top, interpolation="nearest")  # fmt: skip
    ax.plot(r["truth_t_rx_s"], r["truth_codeword"], "r+", ms=7, label="true boundary / codeword")
    ax.set_xlim(extent[0], extent[1])
    ax.set_xlabel("receive time (s)")
    ax.set_ylabel("codeword j (M-hop window ending at hop j)")
    fig.colorbar(img, ax=ax, label="P[n, j] (dB over median)")
    params = ", ".join(f"{k}={_label(rec['params'][k])}" for k in res.spec.grid)
    speed = r.get("true_speed_mps", math.nan)
    ax.set_title(f"{res.title} ({params}; target closing at {speed:.1f} m/s)", fontsize=9)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


# ----------------------------------------------------------------------------- report
def item_outputs(res: ItemResult, out_dir: Path) -> dict[str, Any]:
    """Write the table and figures of one item under ``out_dir``; return what was written."""
    figs = out_dir / "figures"
    tables = out_dir / "tables"
    figs.mkdir(parents=True, exist_ok=True)
    tables.mkdir(parents=True, exist_ok=True)
    rows = pool_rows(res.spec, res.records, res.kind)
    written: dict[str, Any] = {"rows": rows, "figures": [], "table": None}
    written["table"] = write_table(rows, tables / f"{res.item_id}.csv")
    if not any(r["n_ok"] for r in rows):
        return written
    if res.kind == "cost":
        written["figures"].append(plot_cost(res, rows, figs / f"{res.item_id}_cost.png"))
    elif res.kind == "fmcw":
        written["figures"].append(plot_fmcw(res, rows, figs / f"{res.item_id}_bias.png"))
    else:
        written["figures"].append(plot_rmse(res, rows, figs / f"{res.item_id}_rmse.png"))
        written["figures"].append(plot_detection(res, rows, figs / f"{res.item_id}_detection.png"))
    for rec in map_records(res):
        name = f"{res.item_id}_map_p{int(rec['point'])}.png"
        written["figures"].append(plot_map(res, rec, figs / name))
    return written


def _summary_lines(res: ItemResult, rows: list[dict[str, Any]]) -> list[str]:
    """Markdown summary table of one item: per series the threshold and the best accuracy."""
    if res.kind == "cost":
        lines = [
            "| M | GCAS mults/sample | FFT bank | direct bank | GCAS CPU s/s |",
            "|---|---|---|---|---|",
        ]
        for r in sorted(rows, key=lambda r: float(r["m_hops"])):
            lines.append(
                f"| {r['m_hops']} | {r['gcas_mults']:.0f} | {r['fft_bank_mults']:.3g} | "
                f"{r['direct_bank_mults']:.3g} | {_fmt(r.get('gcas_cpu_s_per_s'))} |"
            )
        return lines
    if res.kind == "fmcw":
        lines = [
            "| series | speed (m/s) | range bias (m) | predicted saw bias (m) | range RMSE (m) |",
            "|---|---|---|---|---|",
        ]
        for name, group in series(rows, list(res.spec.grid), res.x).items():
            for r in group:
                lines.append(
                    f"| {name} | {_label(r[res.x])} | {_fmt(r['range_bias_m'])} | "
                    f"{_fmt(r['predicted_saw_bias_m'])} | {_fmt(r['range_rmse_m'])} |"
                )
        return lines
    lines = [
        f"| series | {res.x} where Pd ≥ {PD_THRESHOLD} from | at best {res.x}: range RMSE (m) | "
        "CRLB (m) | RMSE/CRLB | speed RMSE (m/s) | Pd | false/s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, group in series(rows, list(res.spec.grid), res.x).items():
        best = (
            group[-1]
            if res.x != "m_hops"
            else min(
                group,
                key=lambda r: r["range_rmse_m"] if math.isfinite(r["range_rmse_m"]) else math.inf,
            )
        )
        ratio = best["range_rmse_m"] / best["crlb_range_m"] if best["crlb_range_m"] else math.nan
        lines.append(
            f"| {name} | {_fmt(threshold_x(group, res.x))} | {_fmt(best['range_rmse_m'])} "
            f"({res.x} = {_label(best[res.x])}) | {_fmt(best['crlb_range_m'])} | {_fmt(ratio)} | "
            f"{_fmt(best['speed_rmse_mps'])} | {_fmt(best['pd'])} | {_fmt(best['false_per_s'])} |"
        )
    return lines


def _fmt(v: Any) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)


def write_report(
    out_dir: Path, results: list[ItemResult], *, quick: bool, runner: str, command: str
) -> Path:
    """Write every item's table and figures and ``out_dir/report.md`` linking them."""
    out_dir = Path(out_dir)
    mode = (
        "QUICK (reduced grids and trial counts: a smoke run, not the results)" if quick else "full"
    )
    lines = [
        "# Chapter-6 evaluation (hil reproduce)",
        "",
        f"Mode: **{mode}**. Runner: {runner}. Command: `{command}`.",
        "",
        "SNR is the per-sample input SNR over the full band 0…fs/2, (A²/2)/σ² (white noise); "
        "in-band over B_w it is +10.6 dB for 4.4 kHz at 100 kHz. RMSE is pooled over every "
        "detected hop boundary of every trial of a point; CRLB is Stein's bound of the M-hop "
        "transmit window at that window's E/N0. Definitions: `hil/evaluation/trials_ch6.py`.",
        "",
    ]
    for res in results:
        written = item_outputs(res, out_dir)
        n_ok = sum(r["status"] == "ok" for r in res.records)
        lines += [
            f"## {res.title}",
            "",
            f"Seed: {res.seed_ref}. Sweep file: `{res.sweep_file}`. "
            f"{res.spec.n_points} points × {res.spec.trials_per_point} trials = "
            f"{res.spec.n_trials} ({n_ok} ok) in {res.elapsed_s:.1f} s.",
            "",
            f"{res.spec.description}",
            "",
        ]
        for fig in written["figures"]:
            rel = Path(fig).relative_to(out_dir).as_posix()
            lines.append(f"![{Path(fig).stem}]({rel})")
        table = Path(written["table"]).relative_to(out_dir).as_posix()
        lines += ["", f"Table: [{table}]({table})", ""]
        if any(r["n_ok"] for r in written["rows"]):
            lines += [*_summary_lines(res, written["rows"]), ""]
    path = out_dir / "report.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
