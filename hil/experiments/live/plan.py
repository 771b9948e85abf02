"""Checks that refuse a run before any device moves or transmits.

A run is validated (the experiment file), then planned against what the devices report (the
stage's ``$$`` limits, read right after connecting and before homing) and against the run
folder on disk, and only then acted on. Every refusal is a :class:`~hil.errors.ConfigError`
naming the field, the value, the allowed range and what to do.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path

from hil.errors import ConfigError
from hil.experiments.experiment import TowPlan, check_run_name
from hil.outputs import claim_output_folder, writable_folder


@dataclass(frozen=True)
class StageLimits:
    """What the stage allows, as it reported it (GRBL ``$$`` and the driver's soft limits).

    ``low_m``/``high_m``: soft limits of the axis (m); ``max_rate_mps``: ``$110`` (m/s);
    ``accel_mps2``: ``$120`` (m/s²).
    """

    low_m: float
    high_m: float
    max_rate_mps: float
    accel_mps2: float


@dataclass(frozen=True)
class TowPass:
    """One constant-speed pass: from ``first_m`` to ``last_m`` (stage m) at the plan's speed."""

    first_m: float
    last_m: float


@dataclass(frozen=True)
class CheckedTow:
    """A tow plan checked against the stage: its passes in order, and where the carriage
    waits before the first (``ready_m``: the first run-up start, stage m)."""

    plan: TowPlan
    passes: tuple[TowPass, ...]
    ready_m: float


def run_up_needed_m(speed_mps: float, accel_mps2: float) -> float:
    """Distance (m) to reach ``speed_mps`` from rest at ``accel_mps2``: ``v² / (2 a)``.

    >>> run_up_needed_m(2.5, 2.0)
    1.5625
    """
    return speed_mps * speed_mps / (2.0 * accel_mps2)


def check_tow(plan: TowPlan, limits: StageLimits) -> CheckedTow:
    """The whole tow checked against the stage's limits before anything moves.

    Refuses (ConfigError naming the ``tow.*`` field) a speed above the stage's max rate, a
    run-up or run-down shorter than the distance to reach the speed at the stage's
    acceleration, and any position of any pass outside the soft limits.

    >>> lim = StageLimits(-10.0, 0.0, 2.5, 2.0)
    >>> check_tow(TowPlan(-2.0, -5.0, 1.5, repeats=2, run_up_m=0.6, run_down_m=0.6), lim).passes
    (TowPass(first_m=-2.0, last_m=-5.0), TowPass(first_m=-5.0, last_m=-2.0))
    >>> check_tow(TowPlan(-2.0, -5.0, 2.5, run_up_m=0.6, run_down_m=0.6), lim)
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: tow.run_up_m = 0.6 is not allowed: must be >= 1.562 m, the \
distance to reach tow.speed_mps = 2.5 m/s at the stage's acceleration 2 m/s² ($120); \
lengthen tow.run_up_m / tow.run_down_m or lower tow.speed_mps
    """
    if plan.speed_mps > limits.max_rate_mps:
        raise ConfigError(
            "tow.speed_mps",
            plan.speed_mps,
            f"<= the stage's max rate {limits.max_rate_mps:.4g} m/s ($110)",
            "lower the tow speed, or raise $110 on the controller",
        )
    need = run_up_needed_m(plan.speed_mps, limits.accel_mps2)
    for key, value in (("tow.run_up_m", plan.run_up_m), ("tow.run_down_m", plan.run_down_m)):
        if value < need * (1.0 - 1e-9):
            raise ConfigError(
                key,
                value,
                f">= {need:.4g} m, the distance to reach tow.speed_mps = {plan.speed_mps:g} m/s"
                f" at the stage's acceleration {limits.accel_mps2:.4g} m/s² ($120)",
                "lengthen tow.run_up_m / tow.run_down_m or lower tow.speed_mps",
            )
    d = 1.0 if plan.end_m > plan.start_m else -1.0
    for key, x in (
        ("tow.start_m - tow.run_up_m", plan.start_m - d * plan.run_up_m),
        ("tow.end_m + tow.run_down_m", plan.end_m + d * plan.run_down_m),
    ):
        if not limits.low_m <= x <= limits.high_m:
            raise ConfigError(
                key,
                round(x, 6),
                f"within the stage's soft limits [{limits.low_m:g}, {limits.high_m:g}] m",
                "move the tow inside the stage's travel ($130)",
            )
    passes = tuple(
        TowPass(plan.start_m, plan.end_m) if k % 2 == 0 else TowPass(plan.end_m, plan.start_m)
        for k in range(plan.repeats)
    )
    return CheckedTow(plan, passes, plan.start_m - d * plan.run_up_m)


#: The run's log file (hil.logs.run_log), which may be opened in the folder before the run.
RUN_LOG = "run.log"


def new_run_folder(output_dir: Path, name: str, out: Path | None, now: dt.datetime) -> Path:
    """The run's folder, created empty; refused when it would overwrite or leave
    ``output_dir``.

    ``out`` (``--out``) must not exist, or be an empty folder (or hold only ``run.log``, the
    log the command line opened for this run before it started): an existing run is never
    overwritten. The folder is claimed atomically for this process
    (:func:`hil.outputs.claim_output_folder`): of two runs started at once into one ``--out``,
    the second is refused before anything moves or transmits. Without it the folder is
    ``output_dir/name-YYYYmmdd-HHMMSS`` (``-2``, ``-3`` ... appended when a run of the same
    name started in the same second), and ``name`` must be a plain folder name
    (:func:`~hil.experiments.experiment.check_run_name`). The caller releases the claim
    (:func:`hil.outputs.release_output_folder`) when the run is over.
    """
    if out is not None:
        return claim_output_folder(out, "--out", frozenset({RUN_LOG}), "a run")
    check_run_name(name)
    writable_folder(output_dir, "run.output_dir")
    stem = f"{name}-{now:%Y%m%d-%H%M%S}"
    for k in range(1, 1000):
        folder = output_dir / (stem if k == 1 else f"{stem}-{k}")
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        return claim_output_folder(folder, "run.output_dir")
    raise ConfigError("run.name", name, "a name not used by 1000 runs in the same second")
