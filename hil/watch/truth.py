"""The truth a watched run is drawn against: range and closing speed of the towed target from
the recorded stage telemetry and the experiment's geometry, and the hop boundaries that
truth says reached the receiver (the circles of the time–codeword map).

This is the stage's *reported* motion mapped onto the receiver's time base (telemetry sample
index minus the recording's origin, over the sample rate), without a stage calibration: a
live view, not the scored truth of :mod:`hil.experiments.run_scoring`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from hil.signals.schedule import HopSchedule


@dataclass(frozen=True)
class Geometry:
    """Where the transducer and the towed target are (tank coordinates, m): the target sits
    at ``stage_origin_m + x_stage · stage_axis`` (unit vector)."""

    transducer_m: tuple[float, float, float]
    stage_origin_m: tuple[float, float, float]
    stage_axis: tuple[float, float, float]
    sound_speed_mps: float


@dataclass(frozen=True)
class TruthCurve:
    """Range (m) and closing speed (m/s, positive approaching) at the telemetry times
    ``t_s`` (s, receiver time base), shape ``(n,)`` each, in time order."""

    t_s: NDArray[np.float64]
    range_m: NDArray[np.float64]
    speed_mps: NDArray[np.float64]


def truth_curve(
    geometry: Geometry,
    t_s: NDArray[np.float64],
    position_m: NDArray[np.float64],
    velocity_mps: NDArray[np.float64],
) -> TruthCurve:
    """The truth at telemetry reports at times ``t_s`` (s) with stage positions (m) and
    velocities (m/s) along the tow axis, shape ``(n,)`` each (any order).

    >>> g = Geometry((0.0, 0.0, 0.0), (5.0, 0.0, 0.0), (1.0, 0.0, 0.0), 1500.0)
    >>> c = truth_curve(g, np.array([1.0, 0.0]), np.array([-1.0, 0.0]), np.array([-1.0, -1.0]))
    >>> c.t_s.tolist(), c.range_m.tolist(), c.speed_mps.tolist()
    ([0.0, 1.0], [5.0, 4.0], [1.0, 1.0])
    """
    order = np.argsort(t_s, kind="stable")
    t, x, v = (np.asarray(a, dtype=np.float64)[order] for a in (t_s, position_m, velocity_mps))
    target = np.asarray(geometry.stage_origin_m) + np.multiply.outer(
        x, np.asarray(geometry.stage_axis)
    )
    d = target - np.asarray(geometry.transducer_m)
    r = np.sqrt(np.sum(d * d, axis=-1))
    along = (d @ np.asarray(geometry.stage_axis)) / np.maximum(r, 1e-12)
    return TruthCurve(t_s=t, range_m=r, speed_mps=-along * v)


def true_boundaries(
    curve: TruthCurve, schedule: HopSchedule, sound_speed_mps: float
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Hop boundaries that reached the receiver while the truth is known: receive times (s)
    and codewords (hop index modulo the period), shape ``(b,)`` each.

    A boundary transmitted at ``T`` (the end of its hop) arrives at ``T + 2R/c`` with ``R``
    the truth range at the bounce instant ``T + R/c`` (one fixed-point step).
    """
    if curve.t_s.size < 2:
        return np.zeros(0), np.zeros(0, dtype=np.int64)
    c = sound_speed_mps
    table = schedule.hops_in_span(float(curve.t_s[0]), float(curve.t_s[-1]))
    t_end = table.start_s + table.duration_s
    r0 = np.interp(t_end, curve.t_s, curve.range_m)
    r = np.interp(t_end + r0 / c, curve.t_s, curve.range_m)
    inside = (t_end >= curve.t_s[0]) & (t_end <= curve.t_s[-1])
    codeword = table.index % schedule.period_hops
    return (t_end + 2.0 * r / c)[inside], codeword[inside].astype(np.int64)
