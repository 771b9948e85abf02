"""Exact time-varying propagation delay of one-way and two-way (echo) paths.

For every receive time ``t_n`` the solver finds the emission time ``t_e`` of the sound heard
then, and for an echo the bounce time ``t_b`` on the target, from

    t_n − t_b = |p_rx(t_n) − p_T(t_b)| / c          (target → receiver leg)
    t_b − t_e = |p_T(t_b) − p_tx(t_e)| / c          (transmitter → target leg)

by fixed-point iteration on each leg's delay ``d`` (``d ← |p_dst − p_src(t − d)| / c``), which
contracts by |v_src|/c per iteration: a few iterations for v ≪ c, none left when the speed
reaches c. Iterating on the delay (about a second at most) rather than on the absolute time
keeps full float64 resolution even for large ``t``.

Every sample is iterated independently and frozen once its own change is below the tolerance,
so the result for a sample does not depend on which other samples are solved with it: any
chunking of the receive times gives bit-identical delays (the streaming echo relies on this).

Doppler is a time scaling: ``alpha = d t_e / d t_n``, computed exactly from the velocities
(per leg ``(1 − u·v_dst/c) / (1 − u·v_src/c)``, u the unit vector from source to
destination). For a monostatic transceiver and a target closing at constant speed v this is the
closed form ``alpha = (c + v)/(c − v)``, ``tau0 = 2 R0/(c + v)`` of :func:`closed_form_monostatic`.

Examples
--------
>>> import numpy as np
>>> from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed
>>> sonar = Fixed((0.0, 0.0, 0.0))
>>> target = ConstantVelocity((100.0, 0.0, 0.0), (-10.0, 0.0, 0.0))
>>> sol = TwoWayPath(sonar, target, sonar, sound_speed_mps=1500.0).solve(np.array([1.0]))
>>> alpha, tau0 = closed_form_monostatic(100.0, 10.0, 1500.0)
>>> bool(np.isclose(sol.t_emit_s[0], alpha * (1.0 - tau0), rtol=1e-12))
True
>>> round(float(sol.alpha[0]), 6)
1.013423
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from sim_devices.acoustics.trajectory import FloatArray, Trajectory, as_times

IntArray = NDArray[np.int64]

#: Convergence tolerance (s) on each leg's delay: far below one sample at any rate used here.
DEFAULT_TOLERANCE_S = 1e-13
#: Enough for a contraction factor |v|/c up to about 0.7 (0.7**100 ≈ 3e-16).
DEFAULT_MAX_ITERATIONS = 100


class DelayNotConvergedError(ConfigError):
    """The fixed-point delay iteration did not converge (a path point moving at or above c)."""


def check_sound_speed(sound_speed_mps: float, field: str = "sound_speed_mps") -> float:
    """Return the sound speed (m/s) as float after checking it is finite and > 0.

    >>> check_sound_speed(1500)
    1500.0
    """
    c = float(sound_speed_mps)
    if not (np.isfinite(c) and c > 0):
        raise ConfigError(field, sound_speed_mps, "> 0 m/s and finite", "water is about 1500 m/s")
    return c


def doppler_ratio(closing_speed_mps: ArrayLike, sound_speed_mps: float = 1500.0) -> FloatArray:
    """Two-way Doppler time-scale factor ``alpha = (c + v)/(c − v)`` (dimensionless).

    ``v`` (m/s) > 0 closes the range; ``|v| < c``. Shape follows ``closing_speed_mps``.

    >>> round(float(doppler_ratio(10.0, 1500.0)), 6)
    1.013423
    """
    c = check_sound_speed(sound_speed_mps)
    v = np.asarray(closing_speed_mps, dtype=np.float64)
    if not np.all(np.isfinite(v) & (np.abs(v) < c)):
        bad = v.reshape(-1)[~(np.isfinite(v) & (np.abs(v) < c)).reshape(-1)][0]
        raise ConfigError(
            "closing_speed_mps", float(bad), f"finite with |v| < c = {c:g} m/s", "check the units"
        )
    return (c + v) / (c - v)


def closed_form_monostatic(
    range_m: float, closing_speed_mps: float, sound_speed_mps: float = 1500.0
) -> tuple[float, float]:
    """``(alpha, tau0_s)`` of the constant-velocity monostatic echo ``r(t) = s(alpha (t − tau0))``.

    ``range_m`` (m, >= 0) is the range at t = 0, ``closing_speed_mps`` (m/s, > 0 approaching,
    ``|v| < c``). ``alpha = (c + v)/(c − v)``, ``tau0 = 2 R0/(c + v)`` (s): the emission time of
    the sample received at ``t`` is ``alpha (t − tau0)``.

    >>> a, tau0 = closed_form_monostatic(150.0, 0.0, 1500.0)
    >>> a, tau0
    (1.0, 0.2)
    """
    c = check_sound_speed(sound_speed_mps)
    if not (np.isfinite(range_m) and range_m >= 0):
        raise ConfigError("range_m", range_m, ">= 0 m and finite", "a range is a distance")
    alpha = float(doppler_ratio(closing_speed_mps, c))
    return alpha, 2.0 * float(range_m) / (c + float(closing_speed_mps))


@dataclass(frozen=True)
class PathSolution:
    """Geometry of a path at the receive times; every array has shape ``(n,)``.

    Attributes
    ----------
    t_rx_s: receive times (s).
    t_emit_s: emission times (s) of the sound received at ``t_rx_s``.
    t_bounce_s: bounce times (s) on the target; ``None`` for a one-way path.
    delay_s: ``t_rx − t_emit`` (s), the sum of the leg delays.
    alpha: ``d t_emit / d t_rx`` (dimensionless), > 1 when the path shortens.
    leg_lengths_m: length (m) of each leg at its own instants, source to destination order
        (``(r1, r2)`` for an echo: tx→target, target→rx; ``(r,)`` one-way).
    iterations: largest number of fixed-point iterations any sample took.
    positions_m: where the solve found the path's ends (m, each shape ``(n, 3)``): the
        transmitter at ``t_emit_s``, the target at ``t_bounce_s`` and the receiver at
        ``t_rx_s`` for an echo; None when not given. A gain hook reads them instead of
        asking the trajectories again (the same values: trajectories are elementwise).
    """

    t_rx_s: FloatArray
    t_emit_s: FloatArray
    t_bounce_s: FloatArray | None
    delay_s: FloatArray
    alpha: FloatArray
    leg_lengths_m: tuple[FloatArray, ...]
    iterations: int
    positions_m: tuple[FloatArray, FloatArray, FloatArray] | None = None


class PropagationPath(Protocol):
    """A sound path whose emission times can be solved for receive times."""

    @property
    def sound_speed_mps(self) -> float: ...

    def solve(self, t_rx_s: ArrayLike) -> PathSolution:
        """Solve the path for receive times ``t_rx_s`` (s), shape ``(n,)``."""
        ...


def _distance(a: FloatArray, b: FloatArray) -> FloatArray:
    # Written out per coordinate (no reduction) so each element is computed the same way
    # whatever the array length: chunked and whole solves agree to the bit.
    dx = a[..., 0] - b[..., 0]
    dy = a[..., 1] - b[..., 1]
    dz = a[..., 2] - b[..., 2]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@dataclass(frozen=True)
class _Leg:
    delay_s: FloatArray
    t_emit_s: FloatArray
    length_m: FloatArray
    alpha: FloatArray
    iterations: int
    src_position: FloatArray
    src_velocity: FloatArray


def _grouped(
    sources: Sequence[Trajectory], group: IntArray | None, t: FloatArray, velocity: bool = False
) -> FloatArray:
    """Position (or velocity) of element ``i`` of ``t`` on ``sources[group[i]]``, ``(n, 3)``.

    ``group`` is non-decreasing (elements sorted by source), so each source is called once on
    a contiguous run; ``None`` means a single source.
    """
    if group is None:
        src = sources[0]
        return src.velocity(t) if velocity else src.position(t)
    out = np.empty((t.shape[0], 3))
    cuts = np.searchsorted(group, np.arange(len(sources) + 1))
    for g, src in enumerate(sources):
        a, b = int(cuts[g]), int(cuts[g + 1])
        if b > a:
            out[a:b] = src.velocity(t[a:b]) if velocity else src.position(t[a:b])
    return out


def _solve_leg(
    t_arrive: FloatArray,
    dst_position: FloatArray,
    dst_velocity: FloatArray,
    sources: Sequence[Trajectory],
    c: float,
    tol_s: float,
    max_iterations: int,
    role: str,
    group: IntArray | None = None,
) -> _Leg:
    """Delay of the leg ``source(t_arrive − d) → dst_position`` arriving at ``t_arrive``.

    Element ``i`` comes from ``sources[group[i]]`` (``group`` non-decreasing; ``None`` for a
    single source). Every element is computed with the same arithmetic whatever the other
    elements and sources are.
    """
    delay = _distance(dst_position, _grouped(sources, group, t_arrive)) / c
    # The emission time t − d is rounded to the float64 grid of t; near t = 1e6 s that limits
    # the reachable accuracy, so the tolerance never goes below a few ulps of |t|.
    tol = np.maximum(tol_s, 4.0 * np.finfo(np.float64).eps * np.abs(t_arrive))
    # Work on the still-active samples only; each is written back once, when it converges.
    idx = np.arange(t_arrive.size)
    t_sub, dst_sub, d_sub, tol_sub = t_arrive, dst_position, delay.copy(), tol
    g_sub = group
    iterations = 0
    while idx.size:
        new = _distance(dst_sub, _grouped(sources, g_sub, t_sub - d_sub)) / c
        change = np.abs(new - d_sub)
        iterations += 1
        done = change < tol_sub
        if iterations >= max_iterations and not done.all():
            raise DelayNotConvergedError(
                f"{role} speed",
                f"{idx.size - int(done.sum())} of {t_arrive.size} samples still changing by "
                f"{np.max(change[~done]):.3g} s after {max_iterations} iterations",
                f"well below the sound speed c = {c:g} m/s (the iteration contracts by |v|/c)",
                "check the trajectories (e.g. a Live trajectory faster than sound) and c, "
                "or raise max_iterations",
            )
        if done.all():
            delay[idx] = new
            break
        if done.any():
            delay[idx[done]] = new[done]
            keep = ~done
            idx, t_sub, dst_sub, tol_sub = idx[keep], t_sub[keep], dst_sub[keep], tol_sub[keep]
            g_sub = None if g_sub is None else g_sub[keep]
            d_sub = new[keep]
        else:
            d_sub = new

    t_emit = t_arrive - delay
    src_position = _grouped(sources, group, t_emit)
    src_velocity = _grouped(sources, group, t_emit, velocity=True)
    length = _distance(dst_position, src_position)
    # Unit vector source → destination; a zero-length leg has no direction (no Doppler).
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(length[:, None] > 0, (dst_position - src_position) / length[:, None], 0.0)
    u_dst = (
        u[:, 0] * dst_velocity[:, 0] + u[:, 1] * dst_velocity[:, 1] + u[:, 2] * dst_velocity[:, 2]
    )
    u_src = (
        u[:, 0] * src_velocity[:, 0] + u[:, 1] * src_velocity[:, 1] + u[:, 2] * src_velocity[:, 2]
    )
    alpha = (1.0 - u_dst / c) / (1.0 - u_src / c)
    return _Leg(delay, t_emit, length, alpha, iterations, src_position, src_velocity)


def _check_speed(trajectory: Trajectory, role: str, c: float) -> None:
    if not isinstance(trajectory, Trajectory):
        raise ConfigError(
            role, trajectory, "a Trajectory (Fixed, ConstantVelocity, Piecewise, Live)"
        )
    v = trajectory.max_speed_mps
    if v is not None and not v < c:
        raise ConfigError(
            f"{role}.max_speed_mps",
            v,
            f"< sound speed c = {c:g} m/s",
            "no echo can be solved for a point moving at or above the speed of sound",
        )


def _receive_times(t_rx_s: ArrayLike) -> FloatArray:
    t = as_times(t_rx_s, "t_rx_s")
    if t.ndim != 1:
        raise ConfigError("t_rx_s", f"shape {t.shape}", "a 1-D array of receive times (s)")
    return np.ascontiguousarray(t)


class OneWayPath:
    """Direct path ``tx(t_e) → rx(t_n)``: the direct blast, or an image source.

    ``sound_speed_mps`` in m/s; ``tolerance_s`` (s) and ``max_iterations`` control the
    fixed-point solve (see the module docstring).
    """

    def __init__(
        self,
        tx: Trajectory,
        rx: Trajectory,
        sound_speed_mps: float,
        *,
        tolerance_s: float = DEFAULT_TOLERANCE_S,
        max_iterations: int = DEFAULT_MAX_ITERATIONS,
    ) -> None:
        self._c = check_sound_speed(sound_speed_mps)
        _check_speed(tx, "tx", self._c)
        _check_speed(rx, "rx", self._c)
        self.tx, self.rx = tx, rx
        self._tol, self._max_it = _check_solver(tolerance_s, max_iterations)

    @property
    def sound_speed_mps(self) -> float:
        return self._c

    def solve(self, t_rx_s: ArrayLike) -> PathSolution:
        t = _receive_times(t_rx_s)
        leg = _solve_leg(
            t, self.rx.position(t), self.rx.velocity(t), (self.tx,), self._c, self._tol,
            self._max_it, "tx",
        )  # fmt: skip
        return PathSolution(
            t, leg.t_emit_s, None, leg.delay_s, leg.alpha, (leg.length_m,), leg.iterations
        )


class TwoWayPath:
    """Echo path ``tx(t_e) → target(t_b) → rx(t_n)``; monostatic when ``tx is rx``.

    The bounce time is solved first (backwards from ``t_n``), then the emission time from it.
    ``sound_speed_mps`` in m/s.
    """

    def __init__(
        self,
        tx: Trajectory,
        target: Trajectory,
        rx: Trajectory,
        sound_speed_mps: float,
        *,
        tolerance_s: float = DEFAULT_TOLERANCE_S,
        max_iterations: int = DEFAULT_MAX_ITERATIONS,
    ) -> None:
        self._c = check_sound_speed(sound_speed_mps)
        for trajectory, role in ((tx, "tx"), (target, "target"), (rx, "rx")):
            _check_speed(trajectory, role, self._c)
        self.tx, self.target, self.rx = tx, target, rx
        self._tol, self._max_it = _check_solver(tolerance_s, max_iterations)

    @classmethod
    def monostatic(
        cls, sonar: Trajectory, target: Trajectory, sound_speed_mps: float
    ) -> TwoWayPath:
        """Transmitter and receiver are the same point ``sonar``."""
        return cls(sonar, target, sonar, sound_speed_mps)

    @property
    def sound_speed_mps(self) -> float:
        return self._c

    def solve(self, t_rx_s: ArrayLike) -> PathSolution:
        t = _receive_times(t_rx_s)
        rx_p = self.rx.position(t)
        back = _solve_leg(
            t, rx_p, self.rx.velocity(t), (self.target,), self._c, self._tol, self._max_it,
            "target",
        )  # fmt: skip
        t_b = back.t_emit_s
        # The back leg's source is the target at t_b: its position and velocity there.
        out = _solve_leg(
            t_b, back.src_position, back.src_velocity, (self.tx,), self._c, self._tol,
            self._max_it, "tx",
        )  # fmt: skip
        return PathSolution(
            t_rx_s=t,
            t_emit_s=out.t_emit_s,
            t_bounce_s=t_b,
            delay_s=back.delay_s + out.delay_s,
            alpha=back.alpha * out.alpha,
            leg_lengths_m=(out.length_m, back.length_m),
            iterations=max(back.iterations, out.iterations),
            positions_m=(out.src_position, back.src_position, rx_p),
        )


def solve_paths(paths: Sequence[PropagationPath], t_rx_s: ArrayLike) -> list[PathSolution]:
    """``[path.solve(t_rx_s) for path in paths]``, solved together: the same delays, emission
    times, leg lengths and ``alpha``, bit for bit (``iterations`` is the largest over the paths
    solved together).

    Faster for many paths that share trajectories (a target and its tank images): every
    distinct trajectory is evaluated once per iteration for all the paths that use it, and
    the iteration's bookkeeping runs once on all the paths' samples. :class:`OneWayPath` and
    :class:`TwoWayPath` objects with equal sound speed and solver settings are grouped; any
    other path is solved on its own.

    >>> from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed
    >>> sonar = Fixed((0.0, 0.0, 0.0))
    >>> a = TwoWayPath.monostatic(sonar, ConstantVelocity((9.0, 0, 0), (-2.0, 0, 0)), 1500.0)
    >>> b = TwoWayPath.monostatic(sonar, ConstantVelocity((0, 4.0, 0), (0, 1.0, 0)), 1500.0)
    >>> t = np.linspace(0.0, 1.0, 5)
    >>> both = solve_paths([a, b], t)
    >>> bool(np.array_equal(both[1].t_emit_s, b.solve(t).t_emit_s))
    True
    """
    t = _receive_times(t_rx_s)
    solved: list[PathSolution | None] = [None] * len(paths)
    buckets: dict[tuple[str, float, float, int], list[int]] = {}
    for i, p in enumerate(paths):
        if isinstance(p, TwoWayPath | OneWayPath):
            kind = "two" if isinstance(p, TwoWayPath) else "one"
            buckets.setdefault((kind, p._c, p._tol, p._max_it), []).append(i)
        else:
            solved[i] = p.solve(t)
    for (kind, c, tol, max_it), members in buckets.items():
        if len(members) == 1:
            solved[members[0]] = paths[members[0]].solve(t)
            continue
        group = [paths[i] for i in members]
        if kind == "two":
            sols = _solve_two_way(group, t, c, tol, max_it)  # type: ignore[arg-type]
        else:
            sols = _solve_one_way(group, t, c, tol, max_it)  # type: ignore[arg-type]
        for i, sol in zip(members, sols, strict=True):
            solved[i] = sol
    return [s for s in solved if s is not None]


def _distinct(objects: Sequence[Trajectory]) -> tuple[list[Trajectory], list[int]]:
    """The distinct objects (by identity) and each input's index among them."""
    seen: dict[int, int] = {}
    unique: list[Trajectory] = []
    index = []
    for obj in objects:
        if id(obj) not in seen:
            seen[id(obj)] = len(unique)
            unique.append(obj)
        index.append(seen[id(obj)])
    return unique, index


class _Layout:
    """Paths stacked for one leg, sorted by that leg's source: path ``i``'s samples are
    ``slot[i] * n … slot[i] * n + n − 1``; ``group`` gives each element's source."""

    def __init__(self, sources: Sequence[Trajectory], n: int) -> None:
        self.unique, index = _distinct(sources)
        order = sorted(range(len(sources)), key=index.__getitem__)
        self.slot = [0] * len(sources)
        for pos, i in enumerate(order):
            self.slot[i] = pos
        self.order, self.n = order, n
        self.group: IntArray | None = (
            np.repeat(np.asarray([index[i] for i in order], dtype=np.int64), n)
            if len(self.unique) > 1
            else None
        )

    def rows(self, i: int) -> slice:
        return slice(self.slot[i] * self.n, (self.slot[i] + 1) * self.n)

    def take_from(self, other: _Layout) -> IntArray:
        """Indices that rearrange arrays in ``other``'s layout into this one."""
        n = self.n
        return np.concatenate(
            [np.arange(other.slot[i] * n, other.slot[i] * n + n) for i in self.order]
        )


def _at_receiver(
    receivers: Sequence[Trajectory], layout: _Layout, t: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Receiver positions and velocities at ``t`` for every path, stacked in ``layout``."""
    cache: dict[int, tuple[FloatArray, FloatArray]] = {}
    pos, vel = [], []
    for i in layout.order:
        rx = receivers[i]
        if id(rx) not in cache:
            cache[id(rx)] = (rx.position(t), rx.velocity(t))
        pos.append(cache[id(rx)][0])
        vel.append(cache[id(rx)][1])
    return np.concatenate(pos), np.concatenate(vel)


def _solve_two_way(
    paths: Sequence[TwoWayPath], t: FloatArray, c: float, tol: float, max_it: int
) -> list[PathSolution]:
    n = t.shape[0]
    back_l = _Layout([p.target for p in paths], n)
    t_all = np.tile(t, len(paths))
    rx_p, rx_v = _at_receiver([p.rx for p in paths], back_l, t)
    back = _solve_leg(t_all, rx_p, rx_v, back_l.unique, c, tol, max_it, "target", back_l.group)
    t_b = back.t_emit_s
    # The back leg's sources are the targets at t_b: their positions and velocities there.
    tgt_p, tgt_v = back.src_position, back.src_velocity
    out_l = _Layout([p.tx for p in paths], n)
    perm = out_l.take_from(back_l)
    out = _solve_leg(
        t_b[perm], tgt_p[perm], tgt_v[perm], out_l.unique, c, tol, max_it, "tx", out_l.group
    )
    iterations = max(back.iterations, out.iterations)
    sols = []
    for i in range(len(paths)):
        rb, ro = back_l.rows(i), out_l.rows(i)
        sols.append(
            PathSolution(
                t_rx_s=t,
                t_emit_s=out.t_emit_s[ro],
                t_bounce_s=t_b[rb],
                delay_s=back.delay_s[rb] + out.delay_s[ro],
                alpha=back.alpha[rb] * out.alpha[ro],
                leg_lengths_m=(out.length_m[ro], back.length_m[rb]),
                iterations=iterations,
                positions_m=(out.src_position[ro], tgt_p[rb], rx_p[rb]),
            )
        )
    return sols


def _solve_one_way(
    paths: Sequence[OneWayPath], t: FloatArray, c: float, tol: float, max_it: int
) -> list[PathSolution]:
    n = t.shape[0]
    layout = _Layout([p.tx for p in paths], n)
    rx_p, rx_v = _at_receiver([p.rx for p in paths], layout, t)
    leg = _solve_leg(
        np.tile(t, len(paths)), rx_p, rx_v, layout.unique, c, tol, max_it, "tx", layout.group
    )
    sols = []
    for i in range(len(paths)):
        r = layout.rows(i)
        sol = PathSolution(
            t, leg.t_emit_s[r], None, leg.delay_s[r], leg.alpha[r], (leg.length_m[r],),
            leg.iterations,
        )  # fmt: skip
        sols.append(sol)
    return sols


def _check_solver(tolerance_s: float, max_iterations: int) -> tuple[float, int]:
    if not (np.isfinite(tolerance_s) and tolerance_s > 0):
        raise ConfigError("tolerance_s", tolerance_s, "> 0 s and finite", "1e-13 s is the default")
    if int(max_iterations) != max_iterations or max_iterations < 1:
        raise ConfigError("max_iterations", max_iterations, "an integer >= 1")
    return float(tolerance_s), int(max_iterations)
