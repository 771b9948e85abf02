"""The exact truth of a simulated tank that runs in another process: a table of the target's
true range and closing speed against the run's time, written by the tank, read by ``hil
report RUN.h5 --exact-truth FILE``.

A tank simulated in the run's own process (``sim://``) gives the run its exact truth
directly (``summary.json``'s ``range_rmse_vs_exact_m``). The JACK tank (``hil sim-serve tank
--jack``) runs in its own process behind a real audio stack: it writes one table per run it
served (``truth-run-N.csv`` beside the experiment file it printed), so a run through JACK
can be scored against the physics it was given as well as against its stage telemetry, and
the telemetry's own error told apart from the receiver's.

Time base: seconds from the run's first transmitted waveform sample, the receiver's time
base (an estimate's bounce instant ``(t_s + t_tx_s) / 2``). The tank's world starts at that
sample (it finds it on its transmitter input), and the run's latency probe maps what it
receives back onto it, so the table needs no offset.

File format (CSV, one header line, then one row per ``step_s``)::

    time_s,range_m,closing_speed_mps
    0.000000,9.5000000,0.0000000

``closing_speed_mps`` is positive while the target approaches (the receiver's sign).
"""

from __future__ import annotations

import io
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt

from hil.errors import ConfigError
from hil.experiments.experiment import Experiment
from hil.toml_table import read_text_file

#: The table's columns, in order (see the module docstring).
COLUMNS = ("time_s", "range_m", "closing_speed_mps")
#: Time between rows, s: linear interpolation between rows is then exact to well under a
#: micrometre for any motion a stage plans (a ≤ 10 m/s² piece errs by a·step²/8 ≤ 1.3 µm).
STEP_S = 1e-3
#: The file name of run ``n``'s table (1 for the first run served).
FILE_PATTERN = "truth-run-{n}.csv"

FloatArray = npt.NDArray[np.float64]
#: Carriage position (m) and velocity (m/s) at stage times (s): the stage's own plan.
CarriageMotion = Callable[[FloatArray], tuple[FloatArray, FloatArray]]


def truth_table(exp: Experiment, motion: CarriageMotion, duration_s: float) -> FloatArray:
    """The table of a run ``duration_s`` (s) long whose carriage follows ``motion`` (stage
    time from the run's first sample, s): shape ``(n, 3)`` in :data:`COLUMNS` order, one row
    per :data:`STEP_S` from 0 to ``duration_s`` inclusive. The closing speed is the carriage
    velocity projected on the line of sight (analytic, no differencing)."""
    if not np.isfinite(duration_s) or duration_s < 0:
        raise ConfigError("duration_s", duration_s, "a finite number of seconds >= 0")
    t = np.arange(int(np.floor(duration_s / STEP_S)) + 1, dtype=np.float64) * STEP_S
    x, v = motion(t)
    d = exp.target_position(np.asarray(x, dtype=np.float64)) - np.asarray(exp.transducer_m)
    r = np.sqrt(np.sum(d * d, axis=-1))
    along = (d @ np.asarray(exp.stage_axis, dtype=np.float64)) / r
    return np.column_stack([t, r, -along * np.asarray(v, dtype=np.float64)])


def write_truth(path: Path, table: FloatArray) -> Path:
    """Write ``table`` (:func:`truth_table`) as CSV to ``path``; return ``path``."""
    header = ",".join(COLUMNS)
    np.savetxt(path, table, fmt=("%.6f", "%.7f", "%.7f"), delimiter=",", header=header,
               comments="")  # fmt: skip
    return path


def read_truth(path: Path) -> FloatArray:
    """The table in ``path`` (written by :func:`write_truth`): shape ``(n, 3)``, n ≥ 2, times
    increasing. Raises :class:`~hil.errors.ConfigError` naming the file and what is wrong."""
    field = "--exact-truth"
    try:
        text = read_text_file(path, field)  # a folder, binary content: refused by name
    except FileNotFoundError:
        raise ConfigError(field, str(path), "an existing file", "check the path") from None
    header, _, body = text.partition("\n")
    header = header.strip()
    if header != ",".join(COLUMNS):
        raise ConfigError(
            field, str(path), f"a CSV whose header is {','.join(COLUMNS)!r}",
            f"its header is {header[:80]!r}: give the truth-run-N.csv that hil "
            "sim-serve tank --jack wrote beside its experiment file",
        )  # fmt: skip
    try:
        table = np.loadtxt(io.StringIO(body), delimiter=",", ndmin=2, dtype=np.float64)
    except ValueError as exc:
        raise ConfigError(
            field, str(path), "rows of three numbers", f"the file is damaged ({exc})"
        ) from None
    if table.shape[1] != len(COLUMNS) or table.shape[0] < 2:
        raise ConfigError(
            field, str(path), f"at least 2 rows of {len(COLUMNS)} numbers",
            f"it holds {table.shape[0]} row(s) of {table.shape[1]}",
        )  # fmt: skip
    if not np.all(np.isfinite(table)) or not np.all(np.diff(table[:, 0]) > 0):
        raise ConfigError(
            field, str(path), "finite numbers with time_s increasing",
            "the file is damaged: write it again with the run",
        )  # fmt: skip
    return table


def truth_at(table: FloatArray, t_b: npt.ArrayLike) -> dict[str, FloatArray]:
    """Range (m) and closing speed (m/s) of ``table`` at bounce instants ``t_b`` (s, the
    receiver's time base, shape ``(n,)``), interpolated; NaN outside the table's span. The
    keys are those of :attr:`~hil.experiments.tank_run.RunOutcome.exact_truth`."""
    t = np.asarray(t_b, dtype=np.float64)
    inside = (t >= table[0, 0]) & (t <= table[-1, 0])
    return {
        "range_m": np.where(inside, np.interp(t, table[:, 0], table[:, 1]), np.nan),
        "speed_mps": np.where(inside, np.interp(t, table[:, 0], table[:, 2]), np.nan),
    }
