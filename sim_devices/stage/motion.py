"""One-axis motion as a path of constant-acceleration pieces: planning and evaluation.

Units: positions mm, velocities mm/s, accelerations mm/s², times s. A :class:`Path` is a
sequence of pieces; piece ``i`` starts at time ``t[i]`` at position ``x[i]`` with velocity
``v[i]`` and constant acceleration ``a[i]`` and lasts until ``t[i+1]`` (the last piece lasts
for ever, so it is a rest piece). Planning functions return the pieces of a move from rest to
rest: trapezoidal (accelerate, cruise, decelerate) or, when the move is too short to reach
the speed, triangular.

Examples
--------
>>> p = Path(0.0, 0.0)
>>> p.replace_from(0.0, plan_move(0.0, 0.0, 100.0, v_max=10.0, accel=20.0))
>>> [round(float(x), 3) for x in p.position(np.array([0.25, 0.5, 5.0, 10.5, 11.0]))]
[0.625, 2.5, 47.5, 100.0, 100.0]
>>> p.end_time()
10.5
"""

from __future__ import annotations

import math
from bisect import bisect_right
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray


class Piece(NamedTuple):
    """Start time (s), position (mm), velocity (mm/s) and acceleration (mm/s²)."""

    t: float
    x: float
    v: float
    a: float


def plan_move(t0: float, x0: float, x1: float, v_max: float, accel: float) -> list[Piece]:
    """Pieces of a rest-to-rest move from ``x0`` to ``x1`` starting at ``t0``.

    Trapezoid when ``|x1 - x0| >= v_max**2 / accel``, else a triangle peaking at
    ``sqrt(accel * |x1 - x0|)``. The last piece rests exactly at ``x1``.

    >>> [tuple(round(v, 3) for v in p) for p in plan_move(0.0, 0.0, 1.0, 10.0, 100.0)]
    [(0.0, 0.0, 0.0, 100.0), (0.1, 0.5, 10.0, -100.0), (0.2, 1.0, 0.0, 0.0)]
    """
    d = abs(x1 - x0)
    if d == 0.0:
        return [Piece(t0, x1, 0.0, 0.0)]
    s = 1.0 if x1 > x0 else -1.0
    v_peak = min(v_max, math.sqrt(accel * d))
    t_acc = v_peak / accel
    d_acc = 0.5 * v_peak * t_acc
    t_cruise = max(0.0, (d - 2.0 * d_acc) / v_peak)
    pieces = [Piece(t0, x0, 0.0, s * accel)]
    t1 = t0 + t_acc
    if t_cruise > 0.0:
        pieces.append(Piece(t1, x0 + s * d_acc, s * v_peak, 0.0))
        t1 += t_cruise
    pieces.append(Piece(t1, x1 - s * d_acc, s * v_peak, -s * accel))
    pieces.append(Piece(t1 + t_acc, x1, 0.0, 0.0))
    return pieces


def plan_stop(t0: float, x0: float, v0: float, accel: float) -> list[Piece]:
    """Pieces of a deceleration at ``accel`` from velocity ``v0`` to rest.

    >>> plan_stop(1.0, 0.0, 10.0, 20.0)[-1]
    Piece(t=1.5, x=2.5, v=0.0, a=0.0)
    """
    if v0 == 0.0:
        return [Piece(t0, x0, 0.0, 0.0)]
    t_stop = abs(v0) / accel
    x_stop = x0 + 0.5 * v0 * t_stop
    return [Piece(t0, x0, v0, -math.copysign(accel, v0)), Piece(t0 + t_stop, x_stop, 0.0, 0.0)]


class Path:
    """Piecewise constant-acceleration position against time, starting at rest.

    The path keeps its whole history so it can be evaluated at past times; pieces after the
    present are a plan that :meth:`replace_from` may change.
    """

    def __init__(self, t0: float, x0: float) -> None:
        self._pieces: list[Piece] = [Piece(t0, x0, 0.0, 0.0)]
        self._arrays: tuple[NDArray[np.float64], ...] | None = None

    @property
    def pieces(self) -> list[Piece]:
        """The pieces, oldest first (a copy)."""
        return list(self._pieces)

    def replace_from(self, t: float, pieces: list[Piece]) -> None:
        """Drop the plan from ``t`` on and continue with ``pieces`` (the first starts at t)."""
        keep = [p for p in self._pieces if p.t < t]
        self._pieces = keep + pieces
        self._arrays = None

    def stop_at(self, t: float) -> float:
        """Halt instantly at ``t`` (hard limit, reset); return the position, mm."""
        x, _ = self.state_at(t)
        self.replace_from(t, [Piece(t, x, 0.0, 0.0)])
        return x

    def state_at(self, t: float) -> tuple[float, float]:
        """Position (mm) and velocity (mm/s) at time ``t`` (scalar)."""
        p = self._piece_at(t)
        dt = t - p.t
        return p.x + p.v * dt + 0.5 * p.a * dt * dt, p.v + p.a * dt

    def end_time(self) -> float:
        """Start time of the final rest piece, s (when the planned motion ends)."""
        return self._pieces[-1].t

    def _piece_at(self, t: float) -> Piece:
        chosen = self._pieces[0]
        for p in self._pieces:
            if p.t <= t:
                chosen = p
            else:
                break
        return chosen

    def _as_arrays(self) -> tuple[NDArray[np.float64], ...]:
        if self._arrays is None:
            table = np.array(self._pieces, dtype=np.float64).reshape(-1, 4)
            self._arrays = tuple(np.ascontiguousarray(table[:, k]) for k in range(4))
        return self._arrays

    def position(self, times: ArrayLike) -> NDArray[np.float64]:
        """Position (mm) at ``times`` (s), any shape; before the first piece: its start."""
        t = np.asarray(times, dtype=np.float64)
        t0, x0, v0, a0 = self._as_arrays()
        idx = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, None)
        dt = np.maximum(t - t0[idx], 0.0)
        return np.asarray(x0[idx] + v0[idx] * dt + 0.5 * a0[idx] * dt * dt, dtype=np.float64)

    def velocity(self, times: ArrayLike) -> NDArray[np.float64]:
        """Velocity (mm/s) at ``times`` (s), any shape."""
        t = np.asarray(times, dtype=np.float64)
        t0, _, v0, a0 = self._as_arrays()
        idx = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, None)
        dt = np.maximum(t - t0[idx], 0.0)
        return np.asarray(v0[idx] + a0[idx] * dt, dtype=np.float64)

    def first_crossing(self, t_from: float, x_switch: float, direction: float) -> float | None:
        """First time >= ``t_from`` at which the path passes ``x_switch`` moving in
        ``direction`` (+1: upwards through it, -1: downwards), or ``None``."""
        pieces = self._pieces
        start = max(bisect_right([p.t for p in pieces], t_from) - 1, 0)
        for i in range(start, len(pieces)):
            p = pieces[i]
            t_end = pieces[i + 1].t if i + 1 < len(pieces) else math.inf
            if t_end <= t_from:
                continue
            tau = _first_root(p, x_switch, direction, max(t_from - p.t, 0.0), t_end - p.t)
            if tau is not None:
                return p.t + tau
        return None


def _first_root(p: Piece, xs: float, direction: float, lo: float, hi: float) -> float | None:
    """Smallest tau in [lo, hi) at which the piece reaches ``xs`` moving in ``direction``;
    ``None`` if it stays on the near side (times relative to the piece start, s)."""
    # Work in the coordinate y = direction * (x - xs): the crossing is y going from < 0 to 0.
    y0 = direction * (p.x - xs)
    vy = direction * p.v
    ay = direction * p.a
    y_lo = y0 + vy * lo + 0.5 * ay * lo * lo
    if y_lo >= 0.0:
        # Already at or beyond the level: it counts at once if moving (or starting to move)
        # further on in ``direction``.
        v_lo = vy + ay * lo
        return lo if v_lo > 0.0 or (v_lo == 0.0 and ay > 0.0) else None
    if ay == 0.0:
        if vy <= 0.0:
            return None
        tau = -y0 / vy
    else:
        disc = vy * vy - 2.0 * ay * y0
        if disc < 0.0:
            return None
        root = math.sqrt(disc)
        candidates = [(-vy - root) / ay, (-vy + root) / ay]
        after = [c for c in candidates if c >= lo]
        if not after:
            return None
        tau = min(after)
    return tau if lo <= tau < hi else None
