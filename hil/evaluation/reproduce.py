"""``hil reproduce``: run the chapter-6 evaluation (SPEC §5) and write its report.

Every item of SPEC §5 (plus the comparisons the seed motivates) is one sweep file in the
repository's ``evaluation/`` folder (:data:`ITEMS` names them). :func:`reproduce` validates every
selected file first (a bad file stops the run before any trial), then runs the sweeps one after
the other on one runner, each into ``OUT/<item>/`` (manifest, results.jsonl, summary.csv: the
engine's layout), and finally writes ``OUT/figures/*.png``, ``OUT/tables/*.csv`` and
``OUT/report.md`` (:mod:`hil.evaluation.report`).

``quick`` replaces each item's grid values and trial count by its :attr:`Item.quick_grid` and
:attr:`Item.quick_trials` (a smoke run, labelled as such in the report); ``trials_per_point``
overrides the count of every item.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from hil.data import sweeps_dir
from hil.errors import ConfigError
from hil.evaluation.engine import run_sweep
from hil.evaluation.report import ItemResult, write_report
from hil.evaluation.runners import Runner
from hil.evaluation.spec import SweepSpec
from hil.evaluation.sweep_file import sweep_from_dict
from hil.toml_table import read_toml


@dataclass(frozen=True)
class Item:
    """One reproduced item: sweep file ``<id>.toml``, plot kind and quick-mode reduction.

    ``kind``: ``"rmse"`` (RMSE and detection against ``x``), ``"cost"`` or ``"fmcw"``;
    ``map_filter``: parameter values a map record must have to be drawn.
    """

    id: str
    title: str
    seed_ref: str
    x: str
    kind: str = "rmse"
    quick_grid: dict[str, list[Any]] = field(default_factory=dict)
    quick_trials: int = 2
    map_filter: dict[str, Any] = field(default_factory=dict)


_Q_SNR = [-25.0, -15.0, -5.0, 5.0]
ITEMS: tuple[Item, ...] = (
    Item("fig6_1_2_stft_rmse", "STFT method RMSE, N_s = 10 and 50", "Figs 6.1–6.2", "snr_db",
         quick_grid={"snr_db": _Q_SNR}),
    Item("fig6_3_gcas_vs_stft", "GCAS vs STFT", "Fig 6.3", "snr_db",
         quick_grid={"snr_db": [-30.0, -20.0, -10.0, 0.0]}),
    Item("fig6_4_gcas_m", "GCAS with M = 5 and 10", "Fig 6.4", "snr_db",
         quick_grid={"snr_db": [-30.0, -20.0, -10.0, 0.0]}),
    Item("sim01_codeword_map", "sim-01: time–codeword map, random cyclic code", "Fig 6.5",
         "snr_db", quick_grid={"snr_db": [-20.0]}, quick_trials=1),
    Item("sim02_bandwidth", "sim-02: B_w = 4.4 vs 5.2 kHz", "Figs 6.6–6.7", "snr_db",
         quick_grid={"snr_db": [-15.0, 0.0]}, quick_trials=1),
    Item("sim03_reverberation", "sim-03: reverberation", "Figs 6.8–6.9", "srr_db",
         quick_grid={"srr_db": [-5.0, 0.0, 5.0]}, quick_trials=1, map_filter={"srr_db": 0.0}),
    Item("sim04_long_m", "sim-04: M = 15, 22, 29", "Figs 6.10–6.12", "snr_db",
         quick_grid={"snr_db": [-20.0, -10.0]}, quick_trials=1),
    Item("sim05_range_rmse_vs_m", "sim-05: range RMSE vs M", "Fig 6.13", "m_hops",
         quick_grid={"snr_db": [-10.0], "m_hops": [5, 10, 29]}),
    Item("sim06_07_two_settings", "sim-06/07: two settings (three-state vs random cyclic)",
         "Fig 6.14", "snr_db", quick_grid={"snr_db": [-25.0, -10.0, 5.0]}),
    Item("fig5_15_cost", "Multiplications per sample vs M", "Fig 5.15", "m_hops", kind="cost",
         quick_grid={"m_hops": [5, 10, 29]}, quick_trials=1),
    Item("cmp_jifs", "GCAS vs the earlier HFC-CW receiver (JIFS)", "SPEC §4 (comparison)",
         "snr_db", quick_grid={"snr_db": [-20.0, -5.0, 10.0]}, quick_trials=1),
    Item("cmp_mfbank", "GCAS vs the full matched-filter bank", "SPEC §4 (comparison)", "snr_db",
         quick_grid={"snr_db": [-15.0, 0.0]}, quick_trials=1),
    Item("cmp_fmcw", "FMCW sawtooth vs triangle: range bias vs speed", "seed §3.2, SPEC §4",
         "speed_mps", kind="fmcw", quick_grid={"speed_mps": [-10.0, 0.0, 10.0]}, quick_trials=1),
)  # fmt: skip
ITEM_IDS = tuple(item.id for item in ITEMS)


def default_sweeps_dir() -> Path:
    """The shipped sweep files (``hil/data/sweeps/``, found through importlib.resources)."""
    return sweeps_dir()


def select_items(names: Sequence[str] | None) -> list[Item]:
    """The items called ``names`` in :data:`ITEMS` order (all of them for None).

    >>> [i.id for i in select_items(["cmp_fmcw", "fig5_15_cost"])]
    ['fig5_15_cost', 'cmp_fmcw']
    """
    if not names:
        return list(ITEMS)
    unknown = [n for n in names if n not in ITEM_IDS]
    if unknown:
        raise ConfigError("--items", ",".join(unknown), f"items among {', '.join(ITEM_IDS)}")
    return [item for item in ITEMS if item.id in names]


def load_item(
    item: Item,
    sweeps_dir: Path,
    *,
    quick: bool = False,
    trials_per_point: int | None = None,
) -> tuple[SweepSpec, Path]:
    """Read, reduce (quick) and validate the sweep file of ``item``; return it and its path."""
    path = Path(sweeps_dir) / f"{item.id}.toml"
    try:
        doc = read_toml(path, "sweep")
    except FileNotFoundError:
        raise ConfigError(
            "--sweeps", str(sweeps_dir), f"a folder holding {item.id}.toml",
            "leave --sweeps out to use the shipped sweep files",
        ) from None  # fmt: skip
    head = doc.setdefault("sweep", {})
    if quick:
        doc.setdefault("grid", {}).update(item.quick_grid)
        head["trials_per_point"] = item.quick_trials
    if trials_per_point is not None:
        if isinstance(trials_per_point, bool) or not isinstance(trials_per_point, int):
            raise ConfigError("--trials-per-point", trials_per_point, "an integer >= 1")
        if trials_per_point < 1:
            raise ConfigError("--trials-per-point", trials_per_point, "an integer >= 1")
        head["trials_per_point"] = trials_per_point
    return sweep_from_dict(doc, base_dir=path.parent), path


@dataclass(frozen=True)
class ReproduceOutcome:
    """What :func:`reproduce` did: the report path, per-item results, trial counts."""

    report: Path
    results: list[ItemResult]
    n_trials: int
    n_failed: int
    elapsed_s: float


def reproduce(
    out_dir: str | Path,
    runner: Runner,
    *,
    quick: bool = False,
    items: Sequence[str] | None = None,
    trials_per_point: int | None = None,
    sweeps_dir: str | Path | None = None,
    resume: bool = False,
    show_progress: bool = True,
    progress_stream: TextIO | None = None,
    command: str = "",
) -> ReproduceOutcome:
    """Run the selected items into ``out_dir`` and write the report (module docstring)."""
    out = Path(out_dir)
    where = Path(sweeps_dir) if sweeps_dir is not None else default_sweeps_dir()
    chosen = select_items(items)
    loaded = [
        (item, *load_item(item, where, quick=quick, trials_per_point=trials_per_point))
        for item in chosen
    ]
    results: list[ItemResult] = []
    elapsed = 0.0
    for item, spec, path in loaded:
        outcome = run_sweep(
            spec, out / item.id, runner, resume=resume, show_progress=show_progress,
            progress_stream=progress_stream,
        )  # fmt: skip
        elapsed += outcome.elapsed_s
        results.append(
            ItemResult(
                item.id,
                item.title,
                item.seed_ref,
                item.kind,
                item.x,
                spec,
                outcome.records,
                _display_path(path),
                outcome.elapsed_s,
                item.map_filter,
            )
        )
    desc = runner.describe()
    report = write_report(
        out, results, quick=quick, runner=f"{desc['runner']} ({desc['workers']} workers)",
        command=command,
    )  # fmt: skip
    n_trials = sum(len(r.records) for r in results)
    n_failed = sum(r["status"] != "ok" for res in results for r in res.records)
    return ReproduceOutcome(report, results, n_trials, n_failed, elapsed)


def _display_path(path: Path) -> str:
    """``hil/data/sweeps/x.toml`` for a shipped sweep file, else the absolute path."""
    repo = default_sweeps_dir().parents[2]
    try:
        return path.resolve().relative_to(repo).as_posix()
    except ValueError:
        return str(path)
