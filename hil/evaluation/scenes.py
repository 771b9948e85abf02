"""Issue 26's named scenes: the targets of each (range, speed, acceleration, level) and the
gates an estimate is scored with.

A scene is what the water holds, apart from how a trial synthesises and scores it
(:mod:`hil.evaluation.trials_scene`) and how a sweep's report pools it
(:mod:`hil.evaluation.report_scene`); both read this catalogue. hil must not import
``sim_devices`` at module level: :meth:`SceneTarget.trajectory` imports it when called.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Range gate (m) and speed gate (m/s) within which an estimate belongs to a target's boundary
#: (issue 26 item 6: at most 0.5 m; att's range resolution cell is 0.17 m, so the gate holds a
#: grating lobe's error, 1/Δf of delay, as a false estimate only beyond 0.5 m).
GATE_M = 0.5
GATE_MPS = 0.5
#: GOSPA's cut-off (m; :mod:`hil.evaluation.gospa`): the range gate, speed weighed 1 s.
GOSPA_CUTOFF_M = GATE_M


@dataclass(frozen=True)
class SceneTarget:
    """One target on the sonar's axis: from ``range_m`` (m) closing at ``speed_mps`` (m/s,
    negative: opening), its closing speed changing by ``accel_mps2`` (m/s², negative: slowing
    a closing target) until it comes to rest where ``stops`` is true (else it goes on through
    rest: a reversing target); its echo ``level_db`` (dB) re the scene's unit amplitude."""

    range_m: float
    speed_mps: float
    accel_mps2: float = 0.0
    stops: bool = False
    level_db: float = 0.0

    def _rest_s(self) -> float:
        """When a stopping target comes to rest (s; inf where it never does)."""
        if not self.stops or self.accel_mps2 == 0.0 or self.speed_mps * self.accel_mps2 >= 0:
            return math.inf
        return -self.speed_mps / self.accel_mps2

    def closing_speed(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Closing speed (m/s) at times ``t`` (s, any shape)."""
        t = np.minimum(np.asarray(t, dtype=np.float64), self._rest_s())
        return self.speed_mps + self.accel_mps2 * t

    def range_at(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Range (m) at times ``t`` (s, any shape)."""
        t = np.minimum(np.asarray(t, dtype=np.float64), self._rest_s())
        return self.range_m - self.speed_mps * t - 0.5 * self.accel_mps2 * t * t

    def trajectory(self) -> Any:
        """The target as a :class:`~sim_devices.acoustics.trajectory.Live` trajectory on the
        x axis (the sonar at the origin)."""
        from sim_devices.acoustics.trajectory import Live

        def position(t: NDArray[np.float64]) -> NDArray[np.float64]:
            return np.stack([self.range_at(t), 0.0 * t, 0.0 * t], axis=-1)

        def velocity(t: NDArray[np.float64]) -> NDArray[np.float64]:
            return np.stack([-self.closing_speed(t), 0.0 * t, 0.0 * t], axis=-1)

        top = max(abs(self.speed_mps), abs(float(self.closing_speed(np.array(60.0)))))
        return Live(position, velocity, max_speed_mps=top + 1.0)


@dataclass(frozen=True)
class Scene:
    """A named scene: its targets, what it is, and the settings it changes (``None`` keeps
    the trial's): the receiver's span ``max_speed_mps`` (m/s) and reverberation band
    ``reverb_speed_mps`` (m/s; 0: off), and the nearest scatterer ``reverb_min_range_m`` (m)
    where the trial has reverberation."""

    targets: tuple[SceneTarget, ...]
    what: str
    max_speed_mps: float | None = None
    reverb_speed_mps: float | None = None
    reverb_min_range_m: float | None = None


#: Issue 26's scenes (``att``, ranges and speeds as the issue names them).
SCENES: dict[str, Scene] = {
    "still": Scene((SceneTarget(40.0, 0.0),), "a target at rest at 40 m"),
    "slow-0.05": Scene((SceneTarget(40.0, 0.05),), "40 m closing at 0.05 m/s"),
    "slow-0.2": Scene((SceneTarget(40.0, 0.2),), "40 m closing at 0.2 m/s"),
    "still-design-span": Scene(
        (SceneTarget(40.0, 0.0),),
        "at rest at 40 m, span at the design speed 25.72 m/s",
        max_speed_mps=25.72,
    ),
    "braking": Scene(
        (SceneTarget(40.0, 10.0, -10.0, stops=True),),
        "40 m closing at 10 m/s, braking at 10 m/s² to rest at 1 s (35 m)",
    ),
    "reversing": Scene(
        (SceneTarget(50.0, 8.0, -8.0),), "50 m, +8 m/s closing to −8 m/s opening at 8 m/s²"
    ),
    "two-apart": Scene(
        (SceneTarget(45.0, 10.0), SceneTarget(60.0, -6.0)),
        "45 m closing 10 m/s and 60 m opening 6 m/s, equal level",
    ),
    "two-crossing": Scene(
        (SceneTarget(50.0, 10.0), SceneTarget(40.0, -6.0)),
        "50 m closing 10 m/s and 40 m opening 6 m/s: equal ranges at 0.625 s",
    ),
    "two-same-start": Scene(
        (SceneTarget(50.0, 8.0), SceneTarget(50.0, 16.0)),
        "both from 50 m, closing at 8 and 16 m/s",
    ),
    "second-10db-weaker": Scene(
        (SceneTarget(45.0, 10.0), SceneTarget(60.0, -6.0, level_db=-10.0)),
        "as two-apart, the second 10 dB weaker",
    ),
    "beyond-span": Scene(
        (SceneTarget(80.0, 35.0),), "80 m closing at 35 m/s, span 30 m/s: no estimate wanted"
    ),
    "design-speed": Scene((SceneTarget(70.0, 25.0),), "70 m closing at 25 m/s"),
    "opening": Scene((SceneTarget(40.0, -10.0),), "40 m opening at 10 m/s"),
    "still-wall": Scene(
        (SceneTarget(30.0, 0.0, level_db=16.0), SceneTarget(50.0, 8.0)),
        "a still wall at 30 m 16 dB above a target at 50 m closing at 8 m/s",
    ),
    "wall-ghost-speed": Scene(
        (SceneTarget(30.0, 0.0, level_db=10.0), SceneTarget(90.0, 27.0)),
        "a still wall at 30 m 10 dB above a target from 90 m closing at 27 m/s, beside the "
        "wall's ghost (one tone spacing's speed from rest, 27.5 m/s on att)",
    ),
    "still-band-off": Scene(
        (SceneTarget(40.0, 0.0),),
        "at rest at 40 m, the reverberation band off (the "
        "documented setting for a still target); reverberation's scatterers from 1 m",
        reverb_speed_mps=0.0,
        reverb_min_range_m=1.0,
    ),
}
