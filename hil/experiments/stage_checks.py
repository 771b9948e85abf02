"""The checks a tank run makes of the GRBL stage before anything moves, one list for the run
and for ``hil stage settings --check``.

Each :class:`StageCheck` names the experiment field (or ``$`` setting) checked, its value,
what is allowed and whether it passed; ``required`` checks stop a run, the others are
advice for a lab setting up a machine.

>>> from hil.experiments.experiment import TowPlan
>>> from hil.devices.grbl_settings import GrblSettings
>>> s = GrblSettings({13: "0", 20: "1", 21: "1", 22: "1", 110: "600", 120: "50", 130: "400"})
>>> plan = TowPlan(start_m=-0.005, end_m=-0.35, speed_mps=0.005, run_up_m=0.01, run_down_m=0.1)
>>> [c.field for c in tow_checks(plan, s, (-s.travel, 0.0)) if not c.ok]
['tow.start_m - tow.run_up_m', 'tow.end_m + tow.run_down_m']
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hil.devices.grbl_settings import GrblSettings
from hil.errors import ConfigError
from hil.experiments.experiment import TowPlan


@dataclass(frozen=True)
class StageCheck:
    """One check: ``field`` = ``value`` must be ``allowed``; ``ok`` if it is."""

    field: str
    value: Any
    allowed: str
    ok: bool
    required: bool = True
    hint: str = ""

    def error(self) -> ConfigError:
        """The check as the error a run raises for it."""
        return ConfigError(self.field, self.value, self.allowed, self.hint)

    def line(self) -> str:
        """One line for a terminal: ``ok``, ``FAIL`` or ``advice``, field, value, rule."""
        mark = "ok    " if self.ok else ("FAIL  " if self.required else "advice")
        text = f"{mark}  {self.field} = {self.value!r}: must be {self.allowed}"
        return text if self.ok or not self.hint else f"{text}; {self.hint}"


def settings_checks(settings: GrblSettings) -> list[StageCheck]:
    """What the driver and a run need of the controller's ``$`` settings."""
    raw = settings.raw
    return [
        StageCheck(
            "report_inches ($13)", raw.get(13), "0 (reports in mm)", raw.get(13) == "0",
            hint="send $13=0",
        ),
        StageCheck(
            "homing_enabled ($22)", raw.get(22), "1 (positions absolute after $H)",
            str(raw.get(22, "0")).startswith("1"), required=False,
            hint="without homing the origin is wherever GRBL powered up",
        ),
        StageCheck(
            "hard_limits ($21)", raw.get(21), "1 (a limit switch halts the carriage)",
            str(raw.get(21, "0")).startswith("1"), required=False,
            hint="wire the limit switches and send $21=1",
        ),
        StageCheck(
            "soft_limits ($20)", raw.get(20), "1 (GRBL refuses targets outside $130)",
            str(raw.get(20, "0")).startswith("1"), required=False,
            hint="needs homing ($22=1); send $20=1",
        ),
    ]  # fmt: skip


def tow_checks(
    plan: TowPlan, settings: GrblSettings, limits: tuple[float, float]
) -> list[StageCheck]:
    """The tow of ``plan`` against the stage's soft ``limits`` (m), ``$110`` and ``$120``."""
    low, high = limits
    d = 1.0 if plan.end_m > plan.start_m else -1.0
    v_max, accel = settings.max_rate, settings.acceleration
    need = plan.speed_mps**2 / (2.0 * accel)
    within = f"within the stage's soft limits [{low}, {high}] m"
    checks = [
        StageCheck(
            "tow.start_m - tow.run_up_m", plan.start_m - d * plan.run_up_m, within,
            low <= plan.start_m - d * plan.run_up_m <= high,
        ),
        StageCheck(
            "tow.end_m + tow.run_down_m", plan.end_m + d * plan.run_down_m, within,
            low <= plan.end_m + d * plan.run_down_m <= high,
        ),
        StageCheck(
            "tow.speed_mps", plan.speed_mps, f"<= the stage max rate {v_max:.3f} m/s ($110)",
            plan.speed_mps <= v_max * (1.0 + 1e-9), hint="lower the speed or raise $110",
        ),
    ]  # fmt: skip
    for name, value in (("tow.run_up_m", plan.run_up_m), ("tow.run_down_m", plan.run_down_m)):
        allowed = (
            f">= {need:.4g} m, the distance to reach {plan.speed_mps:g} m/s at the "
            f"acceleration $120 = {settings.acceleration_x:g} mm/s^2"
        )
        ok = value >= need * (1.0 - 1e-9)
        checks.append(StageCheck(name, value, allowed, ok, hint="lengthen it or raise $120"))
    return checks


def raise_first_failure(checks: list[StageCheck]) -> None:
    """Raise the error of the first required check that failed, if any."""
    for check in checks:
        if check.required and not check.ok:
            raise check.error()
