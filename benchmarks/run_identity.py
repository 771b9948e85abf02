"""Whether two tank runs on virtual time are the same run, bit for bit.

A run folder holds ``run.h5`` (the recording), ``background.npy`` (the empty-tank
background), ``summary.json`` and ``estimates.csv`` (:func:`write_outputs`). Two folders are
the same run when every ``run.h5`` dataset has the same dtype, shape and bytes, but those
that follow the wall clock (:data:`WALL_CLOCK_DATASETS`: the writer's flush table, the
entry's start and end times), ``background.npy`` holds the same array, ``estimates.csv`` the
same bytes, and ``summary.json`` the same values but its wall-clock and place keys
(:data:`WALL_CLOCK_KEYS`), the run's folder in its other values (the background file's path)
read as a placeholder.

Used by ``benchmarks/bench_virtual_run.py --check DIR``: the first checkout run saves its
folders under ``DIR``, every later one is compared with them (the way to show that a faster
code gives the same run).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from hil.experiments.run_scoring import summarize, write_summary
from hil.experiments.tank_run import RunOutcome

#: run.h5 datasets that follow the wall clock (the writer's flushes, the run's start and end).
WALL_CLOCK_DATASETS = ("flushes/", "entry/start_time", "entry/end_time")
#: summary.json keys that follow the wall clock or the folder.
WALL_CLOCK_KEYS = ("wall_s", "real_time_factor", "folder")
#: The files compared, in order.
FILES = ("run.h5", "background.npy", "summary.json", "estimates.csv")


def write_outputs(outcome: RunOutcome) -> None:
    """``summary.json`` and ``estimates.csv`` of ``outcome`` in its folder (as ``hil
    tank-run`` writes them, without the figures)."""
    write_summary(outcome, summarize(outcome))


def _datasets(path: Path) -> dict[str, Any]:
    """Every dataset of the HDF5 file at ``path`` but the wall-clock ones: name -> value."""
    out: dict[str, Any] = {}
    with h5py.File(path, "r") as f:

        def visit(name: str, item: Any) -> None:
            if isinstance(item, h5py.Dataset) and not name.startswith(WALL_CLOCK_DATASETS):
                out[name] = item[()]

        f.visititems(visit)
    return out


def _same_value(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    return bool(a == b) and type(a) is type(b)


def _summary(path: Path) -> dict[str, Any]:
    """The summary at ``path`` without its :data:`WALL_CLOCK_KEYS`, the run's folder in its
    other values (the background file's path) written ``{folder}``."""
    text = path.read_text()
    folder = json.loads(text).get("folder")
    if folder:
        text = text.replace(json.dumps(folder)[1:-1], "{folder}")
    summary: dict[str, Any] = json.loads(text)
    for key in WALL_CLOCK_KEYS:
        summary.pop(key, None)
    return summary


def differences(folder: Path, reference: Path) -> list[str]:
    """What differs between the run in ``folder`` and the one in ``reference`` (empty: the
    same run, bit for bit); a file missing on either side is a difference."""
    found: list[str] = []
    for name in FILES:
        if not (folder / name).is_file() or not (reference / name).is_file():
            found.append(f"{name}: missing")
    if found:
        return found
    got, ref = _datasets(folder / "run.h5"), _datasets(reference / "run.h5")
    for name in sorted(set(got) | set(ref)):
        if name not in got or name not in ref:
            found.append(f"run.h5 {name}: in one file only")
        elif not _same_value(got[name], ref[name]):
            found.append(f"run.h5 {name}: differs")
    if not _same_value(np.load(folder / "background.npy"), np.load(reference / "background.npy")):
        found.append("background.npy: differs")
    summaries = [_summary(f / "summary.json") for f in (folder, reference)]
    if summaries[0] != summaries[1]:
        keys = sorted(k for k in summaries[0].keys() | summaries[1].keys()
                      if summaries[0].get(k) != summaries[1].get(k))  # fmt: skip
        found.append(f"summary.json: {', '.join(keys)} differ")
    if (folder / "estimates.csv").read_bytes() != (reference / "estimates.csv").read_bytes():
        found.append("estimates.csv: differs")
    return found


def check_or_save(folder: Path, reference: Path) -> list[str] | None:
    """Compare ``folder``'s run with the one saved at ``reference`` (:func:`differences`);
    where nothing is saved there yet, save this one (its :data:`FILES`) and return None."""
    if not reference.exists():
        reference.mkdir(parents=True)
        for name in FILES:
            shutil.copy2(folder / name, reference / name)
        return None
    return differences(folder, reference)
