"""GOSPA: one number for a multi-target estimate, split into localisation, missed and false.

The generalised optimal sub-pattern assignment metric (Rahmathullah, García-Fernández and
Svensson, "Generalized optimal sub-pattern assignment metric", FUSION 2017), with ``α = 2``,
between the set ``X`` of true targets (``n``) and the set ``Y`` of estimates (``m``) at one
time:

    d_p^(c)(X, Y) = ( min_γ Σ_{(i,j)∈γ} d(x_i, y_j)^p + c^p/2 · (n + m − 2|γ|) )^(1/p)

over assignments ``γ`` of targets to estimates whose base distance ``d`` is below the cut-off
``c``: an assigned pair costs its distance, a target left without an estimate (missed) and an
estimate left without a target (false) cost ``c^p/2`` each. So the metric decomposes into a
**localisation** part (the assigned pairs' ``Σ d^p``), the **missed** and the **false**
counts; ``d = 0`` only where every target has an estimate at zero distance and nothing else is
reported. The optimum is a linear assignment (:func:`scipy.optimize.linear_sum_assignment` on
``min(d, c)^p``: a pair at or beyond ``c`` costs what a miss and a false estimate cost, so it
is left unassigned).

The base distance here is between (range, speed) states: ``d = √(Δr² + (τ Δv)²)`` (m), range
in m and speed in m/s weighted by ``τ`` (s; default 1 s: a 1 m/s speed error weighs as 1 m of
range). With ``c`` = 0.5 m that is the scene scoring's gate (0.5 m, and 0.5 m/s for an
estimate at the true range).

Over time, a target followed by one track and then another is a **track switch**
(:func:`track_switches`): the trajectory form of the metric (García-Fernández, Rahmathullah
and Svensson 2020; MATLAB's ``trackGOSPAMetric``) adds a switching cost per switch, reported
here as the count beside the per-time components.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from hil.errors import ConfigError


@dataclass(frozen=True)
class Gospa:
    """GOSPA at one time (module docstring): ``distance`` (m), ``localisation`` (``Σ d^p``
    over the assigned pairs, m^p), ``missed`` and ``false`` (counts) and the assigned
    ``pairs`` (target index, estimate index), sorted by target."""

    distance: float
    localisation: float
    missed: int
    false: int
    pairs: tuple[tuple[int, int], ...]


def state_distances(
    truth: ArrayLike, estimates: ArrayLike, speed_scale_s: float = 1.0
) -> NDArray[np.float64]:
    """Base distances (m) between (range m, speed m/s) states: ``truth`` shape ``(n, 2)``,
    ``estimates`` shape ``(m, 2)``; returns shape ``(n, m)``, ``√(Δr² + (τ Δv)²)``.

    >>> state_distances([[40.0, 10.0]], [[40.3, 10.0], [40.0, 10.4]]).round(6).tolist()
    [[0.3, 0.4]]
    """
    x = np.asarray(truth, dtype=np.float64).reshape(-1, 2)
    y = np.asarray(estimates, dtype=np.float64).reshape(-1, 2)
    dr = x[:, None, 0] - y[None, :, 0]
    dv = speed_scale_s * (x[:, None, 1] - y[None, :, 1])
    return np.asarray(np.hypot(dr, dv), dtype=np.float64)


def gospa(
    truth: ArrayLike,
    estimates: ArrayLike,
    *,
    cutoff: float,
    order: float = 2.0,
    speed_scale_s: float = 1.0,
) -> Gospa:
    """GOSPA (``α = 2``) between the true states ``truth`` (shape ``(n, 2)``: range m, speed
    m/s) and ``estimates`` (shape ``(m, 2)``) with cut-off ``cutoff`` (m) and order
    ``order`` (``p >= 1``); ``speed_scale_s`` weighs speed in the base distance.

    >>> g = gospa([[40.0, 10.0], [60.0, -6.0]], [[40.3, 10.0], [70.0, 0.0]], cutoff=0.5)
    >>> round(g.distance, 6), round(g.localisation, 6), g.missed, g.false, g.pairs
    (0.583095, 0.09, 1, 1, ((0, 0),))
    >>> round(gospa([[40.0, 10.0]], [], cutoff=0.5).distance, 6)  # c / √2: one target missed
    0.353553
    """
    if not (math.isfinite(cutoff) and cutoff > 0):
        raise ConfigError("cutoff", cutoff, "> 0 m and finite")
    if not (math.isfinite(order) and order >= 1):
        raise ConfigError("order", order, ">= 1 and finite")
    x = np.asarray(truth, dtype=np.float64).reshape(-1, 2)
    y = np.asarray(estimates, dtype=np.float64).reshape(-1, 2)
    n, m = len(x), len(y)
    pairs: list[tuple[int, int]] = []
    localisation = 0.0
    if n and m:
        d = state_distances(x, y, speed_scale_s)
        rows, cols = linear_sum_assignment(np.minimum(d, cutoff) ** order)
        for i, j in zip(rows.tolist(), cols.tolist(), strict=True):
            if d[i, j] < cutoff:
                pairs.append((i, j))
                localisation += float(d[i, j]) ** order
    missed, false = n - len(pairs), m - len(pairs)
    total = localisation + cutoff**order / 2.0 * (missed + false)
    return Gospa(total ** (1.0 / order), localisation, missed, false, tuple(sorted(pairs)))


def track_switches(labels: Sequence[Sequence[int | None]]) -> int:
    """Track switches over time: ``labels[k][i]`` is the track id of the estimate assigned to
    target ``i`` at time ``k`` (None: no estimate, or one not yet of a confirmed track). Each
    change of a target's track id between two of its labelled times is one switch.

    >>> track_switches([[0, 1], [0, None], [2, 1], [2, 1]])
    1
    """
    switches = 0
    last: dict[int, int] = {}
    for row in labels:
        for i, label in enumerate(row):
            if label is None:
                continue
            if i in last and last[i] != label:
                switches += 1
            last[i] = label
    return switches
