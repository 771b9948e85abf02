"""Lab folders from the environment: where runs are written and calibrations kept.

- ``HIL_RUNS_DIR``: the runs folder (default ``runs``, relative to the working folder);
- ``HIL_CALIBRATION_DIR``: the calibration store (default ``calibration``).

An experiment file's ``run.output_dir = "runs"`` and ``calibration.store = "calibration"``
(the built-in values) and ``hil calibrate`` without ``--store`` mean these folders; any other
value in a file is used as written.

>>> resolve_runs_dir("runs", {"HIL_RUNS_DIR": "/data/runs"}).as_posix()
'/data/runs'
>>> resolve_runs_dir("elsewhere", {"HIL_RUNS_DIR": "/data/runs"}).as_posix()
'elsewhere'
>>> resolve_calibration_dir(None, {}).as_posix()
'calibration'
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

RUNS_ENV = "HIL_RUNS_DIR"
CALIBRATION_ENV = "HIL_CALIBRATION_DIR"
DEFAULT_RUNS = "runs"
DEFAULT_CALIBRATION = "calibration"


def _resolve(value: str | os.PathLike[str] | None, default: str, variable: str,
             env: Mapping[str, str] | None) -> Path:  # fmt: skip
    env = os.environ if env is None else env
    if value is None or str(value) == default:
        return Path(env.get(variable) or default)
    return Path(value)


def resolve_runs_dir(
    value: str | os.PathLike[str] | None = None, env: Mapping[str, str] | None = None
) -> Path:
    """The runs folder for the setting ``value`` (None or ``"runs"``: ``$HIL_RUNS_DIR``)."""
    return _resolve(value, DEFAULT_RUNS, RUNS_ENV, env)


def resolve_calibration_dir(
    value: str | os.PathLike[str] | None = None, env: Mapping[str, str] | None = None
) -> Path:
    """The calibration store for ``value`` (None or ``"calibration"``: ``$HIL_CALIBRATION_DIR``)."""
    return _resolve(value, DEFAULT_CALIBRATION, CALIBRATION_ENV, env)
