"""GRBL 1.1h's homing cycle (``limits_go_home`` in ``grbl/limits.c``) on simulated axes.

Each homing cycle (``HOMING_CYCLE_0 = Z``, then ``HOMING_CYCLE_1 = X|Y`` in stock
``config.h``) runs four phases for its axes together, each followed by the ``$26`` debounce
delay:

1. approach at the seek rate ``$25`` over 1.5 x the largest ``$13x`` of the cycle; an axis
   stops the instant its switch reads engaged (already engaged: it does not move);
2. pull-off at the seek rate by ``$27``;
3. locate at the feed rate ``$24`` over 5 x ``$27``, stopping on the switch;
4. pull-off at the seek rate by ``$27``.

An approach that ends with an axis whose switch never engaged fails with ``ALARM:9``
(``EXEC_ALARM_HOMING_FAIL_APPROACH``); a pull-off that ends with a switch still engaged fails
with ``ALARM:8`` (``..._PULLOFF``). Each axis has one limit pin shared by its two switches,
so a carriage resting on its far switch is "engaged" too, as on the real board.

Units: mm, mm/s, s; positions are physical (the homed frame of the carriage).
"""

from __future__ import annotations

from dataclasses import dataclass

from sim_devices.stage.motion import Path, plan_move

HOMING_AXIS_SEARCH_SCALAR = 1.5
HOMING_AXIS_LOCATE_SCALAR = 5.0


@dataclass(frozen=True)
class AxisSwitches:
    """The limit switches of one axis: ``home`` and ``far`` trigger positions (mm),
    ``toward_home`` the direction of the homing switch (+1 or -1), ``wired`` whether the
    axis has switches at all."""

    home: float
    far: float
    toward_home: float
    wired: bool

    def engaged(self, x: float) -> bool:
        """The axis's (shared) limit pin reads engaged with the carriage at ``x``."""
        if not self.wired:
            return False
        if self.toward_home > 0:
            return x >= self.home or x <= self.far
        return x <= self.home or x >= self.far


@dataclass(frozen=True)
class HomingOutcome:
    """When the homing cycle ends (s) and how: ``alarm`` is ``None`` on success."""

    end: float
    alarm: int | None


def run_homing(
    paths: list[Path],
    t0: float,
    cycles: list[list[int]],
    switches: list[AxisSwitches],
    settings: dict[int, float],
) -> HomingOutcome:
    """Plan the whole homing sequence on ``paths`` (one per axis, changed in place)."""
    t = t0
    seek, feed, pull = settings[25] / 60.0, settings[24] / 60.0, settings[27]
    debounce = settings[26] / 1000.0
    for axes in cycles:
        travel = max(settings[130 + i] for i in axes)
        accel = min(settings[120 + i] for i in axes)
        phases = (
            (True, HOMING_AXIS_SEARCH_SCALAR * travel, seek),
            (False, pull, seek),
            (True, HOMING_AXIS_LOCATE_SCALAR * pull, feed),
            (False, pull, seek),
        )
        for approach, distance, rate in phases:
            ends = [
                _move_axis(paths[i], switches[i], t, approach, distance, rate, accel) for i in axes
            ]
            t_end = max(end for end, _ in ends)
            if approach and not all(hit for _, hit in ends):
                return HomingOutcome(t_end, 9)
            if not approach and any(switches[i].engaged(paths[i].state_at(t_end)[0]) for i in axes):
                return HomingOutcome(t_end, 8)
            t = t_end + debounce
    return HomingOutcome(t, None)


def _move_axis(
    path: Path,
    sw: AxisSwitches,
    t: float,
    approach: bool,
    distance: float,
    rate: float,
    accel: float,
) -> tuple[float, bool]:
    """One axis's part of a phase: (time it stops, whether it stopped on its switch)."""
    x0, _ = path.state_at(t)
    if approach and sw.engaged(x0):
        path.stop_at(t)
        return t, True
    direction = sw.toward_home if approach else -sw.toward_home
    path.replace_from(t, plan_move(t, x0, x0 + direction * distance, rate, accel))
    if approach and sw.wired:
        t_hit = path.first_crossing(t, sw.home, direction)
        if t_hit is not None:
            path.stop_at(t_hit)
            return t_hit, True
    return path.end_time(), not approach
