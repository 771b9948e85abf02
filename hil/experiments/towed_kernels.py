"""Compiled loop of the towed target's position (numba): the carriage's cubic Hermite fill and
the stage-to-tank map in one pass.

:class:`~hil.experiments.sim_tank._TowedTarget` answers every fixed-point iteration of the
world's echo delay solver; as NumPy expressions (:func:`~hil.experiments.sim_tank._hermite`
then :meth:`~hil.experiments.experiment.Experiment.target_position`) that is some twenty
passes over temporaries of a few hundred samples, each a Python call. :func:`towed_positions`
does them in one loop with the same bits: every output is the same sequence of IEEE float64
operations in NumPy's order (left to right, the integer constants as float64), compiled
without ``fastmath`` (no reassociation, no fused multiply-add); the interval index is the
float64 quotient truncated toward zero, as ``astype(np.int64)`` does, then clipped.
"""

from __future__ import annotations

from typing import Any

import numba

_JIT: dict[str, Any] = {"cache": True, "nogil": True}


@numba.njit(**_JIT)
def towed_positions(
    t: Any, grid: Any, h: float, x: Any, v: Any, origin: Any, axis: Any, out: Any
) -> None:
    """Tank positions (m) of the target at times ``t`` (s, shape ``(n,)``) into ``out``
    (shape ``(n, 3)``).

    The carriage position (m, stage coordinates) is the cubic Hermite through positions ``x``
    (m) and velocities ``v`` (m/s) on the uniform ``grid`` (s, spacing ``h``; all three shape
    ``(g,)``, ``g >= 2``; ``t`` inside it): with ``k`` the interval of ``t`` and
    ``s = (t − grid[k]) / h``,
    ``(2s³ − 3s² + 1) x[k] + (s³ − 2s² + s) h v[k] + (−2s³ + 3s²) x[k+1] + (s³ − s²) h v[k+1]``;
    the tank position is ``origin + position · axis`` (each shape ``(3,)``, m).
    """
    last = grid.shape[0] - 2
    g0 = grid[0]
    o0, o1, o2 = origin[0], origin[1], origin[2]
    a0, a1, a2 = axis[0], axis[1], axis[2]
    for i in range(t.shape[0]):
        ti = t[i]
        k = int((ti - g0) / h)  # truncation toward zero, as astype(np.int64)
        k = min(max(k, 0), last)
        s = (ti - grid[k]) / h
        s2 = s * s
        s3 = s2 * s
        p = (
            (2.0 * s3 - 3.0 * s2 + 1.0) * x[k]
            + (s3 - 2.0 * s2 + s) * h * v[k]
            + (-2.0 * s3 + 3.0 * s2) * x[k + 1]
            + (s3 - s2) * h * v[k + 1]
        )
        out[i, 0] = o0 + p * a0
        out[i, 1] = o1 + p * a1
        out[i, 2] = o2 + p * a2
