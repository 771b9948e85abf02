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

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from hil.errors import ConfigError
from sim_devices.acoustics.trajectory import FloatArray, Trajectory, as_times

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
    """

    t_rx_s: FloatArray
    t_emit_s: FloatArray
    t_bounce_s: FloatArray | None
    delay_s: FloatArray
    alpha: FloatArray
    leg_lengths_m: tuple[FloatArray, ...]
    iterations: int


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


def _solve_leg(
    t_arrive: FloatArray,
    dst_position: FloatArray,
    dst_velocity: FloatArray,
    source: Trajectory,
    c: float,
    tol_s: float,
    max_iterations: int,
    role: str,
) -> _Leg:
    """Delay of the leg ``source(t_arrive − d) → dst_position`` arriving at ``t_arrive``."""
    delay = _distance(dst_position, source.position(t_arrive)) / c
    # The emission time t − d is rounded to the float64 grid of t; near t = 1e6 s that limits
    # the reachable accuracy, so the tolerance never goes below a few ulps of |t|.
    tol = np.maximum(tol_s, 4.0 * np.finfo(np.float64).eps * np.abs(t_arrive))
    # Work on the still-active samples only; each is written back once, when it converges.
    idx = np.arange(t_arrive.size)
    t_sub, dst_sub, d_sub, tol_sub = t_arrive, dst_position, delay.copy(), tol
    iterations = 0
    while idx.size:
        new = _distance(dst_sub, source.position(t_sub - d_sub)) / c
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
        if done.any():
            delay[idx[done]] = new[done]
            keep = ~done
            idx, t_sub, dst_sub, tol_sub = idx[keep], t_sub[keep], dst_sub[keep], tol_sub[keep]
            d_sub = new[keep]
        else:
            d_sub = new

    t_emit = t_arrive - delay
    src_position = source.position(t_emit)
    src_velocity = source.velocity(t_emit)
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
    return _Leg(delay, t_emit, length, alpha, iterations)


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
            t, self.rx.position(t), self.rx.velocity(t), self.tx, self._c, self._tol,
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
        back = _solve_leg(
            t, self.rx.position(t), self.rx.velocity(t), self.target, self._c, self._tol,
            self._max_it, "target",
        )  # fmt: skip
        t_b = back.t_emit_s
        out = _solve_leg(
            t_b, self.target.position(t_b), self.target.velocity(t_b), self.tx, self._c,
            self._tol, self._max_it, "tx",
        )  # fmt: skip
        return PathSolution(
            t_rx_s=t,
            t_emit_s=out.t_emit_s,
            t_bounce_s=t_b,
            delay_s=back.delay_s + out.delay_s,
            alpha=back.alpha * out.alpha,
            leg_lengths_m=(out.length_m, back.length_m),
            iterations=max(back.iterations, out.iterations),
        )


def _check_solver(tolerance_s: float, max_iterations: int) -> tuple[float, int]:
    if not (np.isfinite(tolerance_s) and tolerance_s > 0):
        raise ConfigError("tolerance_s", tolerance_s, "> 0 s and finite", "1e-13 s is the default")
    if int(max_iterations) != max_iterations or max_iterations < 1:
        raise ConfigError("max_iterations", max_iterations, "an integer >= 1")
    return float(tolerance_s), int(max_iterations)
