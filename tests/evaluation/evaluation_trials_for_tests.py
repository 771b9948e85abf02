"""Trials used only by the evaluation tests; sweeps name them as ``this_file.py:function`` so
that spawned pool workers and Dask workers load them from the file."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from hil.errors import ConfigError


def draw_trial(params: dict[str, Any], seed: np.random.SeedSequence) -> dict[str, Any]:
    """A normal draw scaled by ``sigma``: cheap and fully determined by the seed."""
    rng = np.random.default_rng(seed)
    return {"err": float(params.get("sigma", 1.0) * rng.standard_normal()), "label": "draw"}


def raising_trial(params: dict[str, Any], seed: np.random.SeedSequence) -> dict[str, Any]:
    """Raises ``ValueError`` at ``x == 2``; otherwise returns ``x`` and a draw."""
    if params["x"] == 2:
        raise ValueError(f"x = {params['x']} is cursed")
    return {"x": params["x"], "u": float(np.random.default_rng(seed).uniform())}


def marker_trial(params: dict[str, Any], seed: np.random.SeedSequence) -> dict[str, Any]:
    """Appends its spawn key to the file ``params["marker"]`` (one line per execution), sleeps
    ``sleep_s`` and returns a draw: lets a test count how often each trial really ran."""
    key = ",".join(str(k) for k in seed.spawn_key)
    with open(params["marker"], "a", encoding="utf-8") as fh:
        fh.write(key + "\n")
    time.sleep(params.get("sleep_s", 0.0))
    return {"v": float(np.random.default_rng(seed).standard_normal())}


def _check_marker(params: dict[str, Any]) -> None:
    if not isinstance(params.get("marker"), str):
        raise ConfigError("marker", params.get("marker"), "a file path (string)")


marker_trial.validate_params = _check_marker  # type: ignore[attr-defined]


def env_trial(params: dict[str, Any], seed: np.random.SeedSequence) -> dict[str, Any]:
    """Reports the BLAS thread variables and glibc's trim threshold the worker process
    *started* with (from /proc/self/environ, untouched by later os.environ changes) and its
    process id."""
    raw = Path("/proc/self/environ").read_bytes().split(b"\0")
    env = dict(item.decode().split("=", 1) for item in raw if b"=" in item)
    return {
        "omp": str(env.get("OMP_NUM_THREADS")),
        "openblas": str(env.get("OPENBLAS_NUM_THREADS")),
        "mkl": str(env.get("MKL_NUM_THREADS")),
        "malloc_trim": str(env.get("MALLOC_TRIM_THRESHOLD_")),
        "pid": os.getpid(),
    }


def bad_return_trial(params: dict[str, Any], seed: np.random.SeedSequence) -> Any:
    """Returns something that is not a result dict."""
    return [1, 2, 3]


def gated_trial(params: dict[str, Any], seed: np.random.SeedSequence) -> dict[str, Any]:
    """Returns a draw at once for repetitions below ``free_reps``; later ones first wait for
    the file ``params["gate"]`` to exist: a sweep that holds its workers busy until a test
    opens the gate (or interrupts the sweep)."""
    if seed.spawn_key[1] >= params["free_reps"]:
        gate = Path(params["gate"])
        while not gate.exists():
            time.sleep(0.01)
    return {"v": float(np.random.default_rng(seed).standard_normal())}
