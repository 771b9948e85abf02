"""Trajectories of transmitters, receivers and targets: position and velocity against time.

Positions are in metres in a right-handed Cartesian frame, times in seconds, velocities in
m/s. Every trajectory is *elementwise*: the value at ``t[i]`` depends on ``t[i]`` alone, never
on the other entries of ``t``. The delay solver relies on this to make block-wise echo
synthesis give bit-identical results for any chunking.

Shapes: ``position(t)`` and ``velocity(t)`` take ``t`` of any shape ``S`` (a scalar gives
``()``) and return float64 arrays of shape ``S + (3,)``; for a 1-D time axis of ``n`` samples
that is ``(n, 3)``.

Examples
--------
>>> import numpy as np
>>> tow = ConstantVelocity(position_m=(10.0, 0.0, -2.0), velocity_mps=(-1.0, 0.0, 0.0))
>>> tow.position(np.array([0.0, 2.0]))
array([[10.,  0., -2.],
       [ 8.,  0., -2.]])
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError

FloatArray = NDArray[np.float64]

#: Time step (s) of the central difference used by :class:`Live` when no velocity callable is
#: given. Positions of a stage are smooth on this scale; the step is far above the float64
#: resolution of a time of a few hours (about 1e-12 s), so the difference is not noise.
LIVE_VELOCITY_STEP_S = 1e-5


@runtime_checkable
class Trajectory(Protocol):
    """A point moving in 3-D.

    ``max_speed_mps`` is an upper bound of the speed over all time (m/s), or ``None`` when it
    is not known in advance (:class:`Live`); the delay solver checks it against the sound
    speed before solving.
    """

    @property
    def max_speed_mps(self) -> float | None: ...

    def position(self, t: ArrayLike) -> FloatArray:
        """Position (m), shape ``t.shape + (3,)``, at times ``t`` (s)."""
        ...

    def velocity(self, t: ArrayLike) -> FloatArray:
        """Velocity (m/s), shape ``t.shape + (3,)``, at times ``t`` (s)."""
        ...


def as_times(t: ArrayLike, field: str = "t_s") -> FloatArray:
    """Times (s) as a float64 array, refusing NaN and infinity.

    >>> as_times([0, 0.5])
    array([0. , 0.5])
    """
    times = np.asarray(t, dtype=np.float64)
    if not np.all(np.isfinite(times)):
        raise ConfigError(field, _first_bad(times), "finite times in seconds", "remove NaN/inf")
    return times


def as_point(p: ArrayLike, field: str) -> FloatArray:
    """A 3-D point or vector as a float64 array of shape ``(3,)``, finite."""
    point = np.asarray(p, dtype=np.float64)
    if point.shape != (3,):
        raise ConfigError(field, p, "a 3-vector (x, y, z)", "give three coordinates")
    if not np.all(np.isfinite(point)):
        raise ConfigError(field, p, "finite coordinates", "remove NaN/inf")
    return point


def _first_bad(a: FloatArray) -> float:
    flat = a.reshape(-1)
    bad = flat[~np.isfinite(flat)]
    return float(bad[0]) if bad.size else float("nan")


def _broadcast_point(point: FloatArray, times: FloatArray) -> FloatArray:
    out = np.empty((*times.shape, 3))
    out[...] = point
    return out


def _affine(start: FloatArray, velocity: FloatArray, elapsed: FloatArray) -> FloatArray:
    """``start + elapsed * velocity`` with shape ``elapsed.shape + (3,)``.

    ``start`` and ``velocity`` have shape ``(3,)`` or ``elapsed.shape + (3,)``. Filled one
    coordinate at a time: several times faster than broadcasting over a trailing axis of 3.
    """
    out = np.empty((*elapsed.shape, 3))
    for k in range(3):
        col = out[..., k]
        np.multiply(elapsed, velocity[..., k], out=col)
        col += start[..., k]
    return out


class Fixed:
    """A point at rest at ``position_m`` (m).

    >>> Fixed((0.0, 0.0, -1.0)).position(np.zeros(2))
    array([[ 0.,  0., -1.],
           [ 0.,  0., -1.]])
    """

    #: The same position, bit for bit, at every time (a path between still points is solved
    #: once: :class:`~sim_devices.acoustics.grid_echo.GridEcho`).
    still = True

    def __init__(self, position_m: ArrayLike) -> None:
        self._p = as_point(position_m, "position_m")

    @property
    def max_speed_mps(self) -> float:
        return 0.0

    def position(self, t: ArrayLike) -> FloatArray:
        return _broadcast_point(self._p, as_times(t))

    def velocity(self, t: ArrayLike) -> FloatArray:
        return np.zeros((*as_times(t).shape, 3))


class ConstantVelocity:
    """Straight-line motion: ``p(t) = position_m + velocity_mps * (t - t_ref_s)``.

    ``position_m`` (m) is the position at ``t_ref_s`` (s), ``velocity_mps`` in m/s.

    >>> ConstantVelocity((5.0, 0, 0), (-2.0, 0, 0), t_ref_s=1.0).position(np.array([1.0, 2.0]))
    array([[5., 0., 0.],
           [3., 0., 0.]])
    """

    def __init__(
        self, position_m: ArrayLike, velocity_mps: ArrayLike, t_ref_s: float = 0.0
    ) -> None:
        self._p = as_point(position_m, "position_m")
        self._v = as_point(velocity_mps, "velocity_mps")
        if not np.isfinite(t_ref_s):
            raise ConfigError("t_ref_s", t_ref_s, "a finite time in seconds")
        self._t_ref = float(t_ref_s)

    @property
    def max_speed_mps(self) -> float:
        return float(np.sqrt(self._v @ self._v))

    def position(self, t: ArrayLike) -> FloatArray:
        return _affine(self._p, self._v, as_times(t) - self._t_ref)

    def velocity(self, t: ArrayLike) -> FloatArray:
        return _broadcast_point(self._v, as_times(t))


class Piecewise:
    """Waypoints joined by straight legs run at constant speed, with optional dwells.

    The point rests at ``waypoints_m[0]`` until ``t_start_s``, then for each waypoint ``i``
    dwells ``dwell_s[i]`` seconds there and runs leg ``i`` to waypoint ``i + 1`` at
    ``speeds_mps[i]``. After the last waypoint (and its dwell) it holds there
    (``hold_at_end=True``) or keeps the last leg's velocity for ever (``hold_at_end=False``).
    Velocity is piecewise constant and right-continuous at the corners.

    Parameters
    ----------
    waypoints_m:
        Shape ``(m, 3)``, ``m >= 2``, metres.
    speeds_mps:
        Shape ``(m - 1,)``, each > 0 m/s.
    dwell_s:
        Shape ``(m,)``, each >= 0 s; default no dwell.

    >>> path = Piecewise([(0, 0, 0), (2, 0, 0), (2, 1, 0)], speeds_mps=[1.0, 0.5])
    >>> path.position(np.array([-1.0, 1.0, 3.0, 9.0]))[:, :2]
    array([[0. , 0. ],
           [1. , 0. ],
           [2. , 0.5],
           [2. , 1. ]])
    >>> path.end_time_s
    4.0
    """

    def __init__(
        self,
        waypoints_m: ArrayLike,
        speeds_mps: ArrayLike,
        *,
        t_start_s: float = 0.0,
        dwell_s: ArrayLike | None = None,
        hold_at_end: bool = True,
    ) -> None:
        points = np.asarray(waypoints_m, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] < 2:
            raise ConfigError(
                "waypoints_m", points.shape, "an (m, 3) array with m >= 2", "one row per waypoint"
            )
        if not np.all(np.isfinite(points)):
            raise ConfigError("waypoints_m", _first_bad(points), "finite coordinates in metres")
        speeds = np.asarray(speeds_mps, dtype=np.float64).reshape(-1)
        if speeds.shape != (points.shape[0] - 1,):
            raise ConfigError(
                "speeds_mps", speeds.shape, f"one speed per leg: shape ({points.shape[0] - 1},)"
            )
        if not np.all(np.isfinite(speeds) & (speeds > 0)):
            bad = speeds[~(np.isfinite(speeds) & (speeds > 0))][0]
            raise ConfigError(
                "speeds_mps", float(bad), "> 0 m/s and finite", "each leg needs a speed"
            )
        dwell = np.zeros(points.shape[0]) if dwell_s is None else np.asarray(dwell_s, float)
        dwell = dwell.reshape(-1)
        if dwell.shape != (points.shape[0],):
            raise ConfigError(
                "dwell_s", dwell.shape, f"one dwell per waypoint: ({points.shape[0]},)"
            )
        if not np.all(np.isfinite(dwell) & (dwell >= 0)):
            bad = dwell[~(np.isfinite(dwell) & (dwell >= 0))][0]
            raise ConfigError("dwell_s", float(bad), ">= 0 s and finite")
        if not np.isfinite(t_start_s):
            raise ConfigError("t_start_s", t_start_s, "a finite time in seconds")

        legs = np.diff(points, axis=0)
        lengths = np.sqrt(np.sum(legs * legs, axis=1))
        durations = lengths / speeds
        # Unit direction times speed; a zero-length leg has zero velocity and zero duration.
        with np.errstate(invalid="ignore", divide="ignore"):
            leg_v = np.where(lengths[:, None] > 0, legs / lengths[:, None] * speeds[:, None], 0.0)

        # Segments alternate dwell, leg, dwell, leg, ..., dwell; each is (start time, start
        # point, velocity). Position inside a segment is start point + velocity * elapsed.
        seg_p, seg_v, seg_dur = [], [], []
        for i in range(points.shape[0]):
            seg_p.append(points[i])
            seg_v.append(np.zeros(3))
            seg_dur.append(dwell[i])
            if i < legs.shape[0]:
                seg_p.append(points[i])
                seg_v.append(leg_v[i])
                seg_dur.append(durations[i])
        self._seg_p = np.array(seg_p)
        self._seg_v = np.array(seg_v)
        self._seg_t = float(t_start_s) + np.concatenate(([0.0], np.cumsum(seg_dur)[:-1]))
        self._end_t = float(t_start_s) + float(np.sum(seg_dur))
        self._hold = bool(hold_at_end)
        self._last_leg_v = leg_v[-1]
        self._t_start = float(t_start_s)
        self._max_speed = float(np.max(speeds))

    @property
    def max_speed_mps(self) -> float:
        return self._max_speed

    @property
    def end_time_s(self) -> float:
        """Time (s) at which the last waypoint's dwell ends."""
        return self._end_t

    def _segment(self, times: FloatArray) -> tuple[FloatArray, FloatArray]:
        seg = np.searchsorted(self._seg_t, times, side="right") - 1
        before = seg < 0
        seg = np.clip(seg, 0, None)
        p0 = self._seg_p[seg]
        v = self._seg_v[seg].copy()
        t0 = self._seg_t[seg].copy()
        # Before the start: at rest on the first waypoint (elapsed time clamped to zero).
        t0[before] = times[before]
        v[before] = 0.0
        after = times >= self._end_t
        final = self._seg_p.shape[0] - 1
        v[after] = 0.0 if self._hold else self._last_leg_v
        t0[after] = self._end_t
        p0[after] = self._seg_p[final]
        return _affine(p0, v, times - t0), v

    def position(self, t: ArrayLike) -> FloatArray:
        return self._segment(as_times(t))[0]

    def velocity(self, t: ArrayLike) -> FloatArray:
        return self._segment(as_times(t))[1]


class Live:
    """Position given by a callable of time, e.g. the simulated stage's true position.

    ``position_fn(t)`` takes a float64 array of times (s) of any shape ``S`` and returns
    positions (m) of shape ``S + (3,)``. It must be vectorised and elementwise (the value at
    ``t[i]`` depends on ``t[i]`` only). ``velocity_fn`` likewise gives m/s; without it the
    velocity is a central difference with step :data:`LIVE_VELOCITY_STEP_S`.
    ``max_speed_mps``, when given, lets the delay solver refuse a trajectory faster than
    sound before solving; otherwise a non-converging solve reports the problem.

    >>> circle = Live(lambda t: np.stack([np.cos(t), np.sin(t), 0 * t], axis=-1))
    >>> np.round(circle.velocity(np.array([0.0])), 6)
    array([[0., 1., 0.]])
    """

    def __init__(
        self,
        position_fn: Callable[[FloatArray], ArrayLike],
        velocity_fn: Callable[[FloatArray], ArrayLike] | None = None,
        max_speed_mps: float | None = None,
    ) -> None:
        if not callable(position_fn):
            raise ConfigError("position_fn", position_fn, "a callable t -> positions (m)")
        if velocity_fn is not None and not callable(velocity_fn):
            raise ConfigError("velocity_fn", velocity_fn, "a callable t -> velocities (m/s)")
        if max_speed_mps is not None and not (np.isfinite(max_speed_mps) and max_speed_mps >= 0):
            raise ConfigError("max_speed_mps", max_speed_mps, ">= 0 m/s and finite, or None")
        self._pos = position_fn
        self._vel = velocity_fn
        self._max_speed = None if max_speed_mps is None else float(max_speed_mps)

    @property
    def max_speed_mps(self) -> float | None:
        return self._max_speed

    def _call(
        self, fn: Callable[[FloatArray], ArrayLike], times: FloatArray, what: str
    ) -> FloatArray:
        out = np.asarray(fn(times), dtype=np.float64)
        if out.shape != (*times.shape, 3):
            raise ConfigError(
                f"Live.{what}(t) shape", out.shape, f"t.shape + (3,) = {(*times.shape, 3)}"
            )
        if not np.all(np.isfinite(out)):
            raise ConfigError(
                f"Live.{what}(t)", _first_bad(out), "finite values", "the callable returned NaN/inf"
            )
        return out

    def position(self, t: ArrayLike) -> FloatArray:
        return self._call(self._pos, as_times(t), "position_fn")

    def velocity(self, t: ArrayLike) -> FloatArray:
        times = as_times(t)
        if self._vel is not None:
            return self._call(self._vel, times, "velocity_fn")
        h = LIVE_VELOCITY_STEP_S
        ahead = self._call(self._pos, times + h, "position_fn")
        behind = self._call(self._pos, times - h, "position_fn")
        return (ahead - behind) / (2.0 * h)


class Mirrored:
    """Mirror image of a trajectory in a plane: the image source of a reflecting surface.

    The plane passes through ``plane_point_m`` (m) with normal ``plane_normal`` (any length,
    normalised here). ``p' = p − 2 ((p − q)·n) n`` and ``v' = v − 2 (v·n) n``: a
    :class:`~sim_devices.acoustics.delay.OneWayPath` or ``TwoWayPath`` through the image gives
    the surface- or bottom-reflected path (reflection coefficient left to the gain hook).

    >>> surface = Mirrored(Fixed((3.0, 0.0, -2.0)), (0, 0, 0), (0, 0, 1))
    >>> surface.position(np.array([0.0]))
    array([[3., 0., 2.]])
    """

    def __init__(
        self, trajectory: Trajectory, plane_point_m: ArrayLike, plane_normal: ArrayLike
    ) -> None:
        self._q = as_point(plane_point_m, "plane_point_m")
        n = as_point(plane_normal, "plane_normal")
        norm = float(np.sqrt(n @ n))
        if norm == 0:
            raise ConfigError(
                "plane_normal", tuple(n.tolist()), "a non-zero vector", "e.g. (0, 0, 1)"
            )
        self._n = n / norm
        self._inner = trajectory
        #: A still trajectory's image is still (see :attr:`Fixed.still`).
        self.still = bool(getattr(trajectory, "still", False))

    @property
    def max_speed_mps(self) -> float | None:
        return self._inner.max_speed_mps

    def _reflect(self, vectors: FloatArray, offset: FloatArray) -> FloatArray:
        # Written per coordinate, not with @: a BLAS dot may sum in a length-dependent order,
        # which would break bit-exact chunking.
        d = vectors - offset
        n = self._n
        along = d[..., 0] * n[0] + d[..., 1] * n[1] + d[..., 2] * n[2]
        return vectors - 2.0 * along[..., np.newaxis] * n

    def position(self, t: ArrayLike) -> FloatArray:
        return self._reflect(self._inner.position(t), self._q)

    def velocity(self, t: ArrayLike) -> FloatArray:
        return self._reflect(self._inner.velocity(t), np.zeros(3))
