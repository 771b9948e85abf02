"""GRBL's look-ahead planner for blocks along one axis: junction speeds and block profiles.

Follows ``grbl/planner.c`` (1.1h): each block has a nominal speed; the speed at the junction
between two blocks is limited by the junction deviation ``$11`` (``plan_buffer_line``:
``sin(theta/2)``-based limit, unlimited for a straight continuation, the minimum junction
speed for a reversal) and by both blocks' nominal speeds; a backward pass from the last
block (which ends at rest) and a forward pass from the current speed then give each block's
entry and exit speeds, and each block runs accelerate / cruise / decelerate at ``$120``.

Units: mm, mm/s, mm/s², s. Blocks are given as absolute targets along the axis.

Examples
--------
Twenty 0.5 mm blocks at 5 mm/s (F300) with 10 mm/s² blend into one 10 mm move: 0.5 s up,
1.5 s cruising, 0.5 s down, 2.5 s in all (stopping between blocks would take 9 s).

>>> pieces, ends = plan_blocks(0.0, 0.0, 0.0, [0.5 * (k + 1) for k in range(20)],
...                            [5.0] * 20, accel=10.0, junction_deviation=0.01)
>>> round(ends[-1], 6)
2.5
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from sim_devices.stage.motion import Piece

#: ``MINIMUM_JUNCTION_SPEED`` of ``config.h`` (mm/min -> mm/s): 0.
MINIMUM_JUNCTION_SPEED = 0.0


def junction_speed(cos_theta: float, accel: float, junction_deviation: float) -> float:
    """Largest speed (mm/s) through a junction whose unit vectors have ``cos_theta =
    -(previous . next)`` (GRBL's sign: -1 straight on, +1 full reversal).

    >>> junction_speed(-1.0, 10.0, 0.01), junction_speed(1.0, 10.0, 0.01)
    (inf, 0.0)
    >>> round(junction_speed(0.0, 10.0, 0.01), 4)  # a right angle
    0.4913
    """
    if cos_theta > 0.999999:
        return MINIMUM_JUNCTION_SPEED
    if cos_theta < -0.999999:
        return math.inf
    sin_half = math.sqrt(0.5 * (1.0 - cos_theta))
    v2 = accel * junction_deviation * sin_half / (1.0 - sin_half)
    return math.sqrt(max(MINIMUM_JUNCTION_SPEED**2, v2))


def plan_blocks(
    t0: float,
    x0: float,
    v0: float,
    targets: Sequence[float],
    rates: Sequence[float],
    accel: float,
    junction_deviation: float,
) -> tuple[list[Piece], list[float]]:
    """Pieces from ``t0`` through every block, and the time each block ends.

    ``x0`` is the present position, ``v0 >= 0`` the present speed along the first block
    (the block in progress keeps its speed: GRBL's stepper never jumps), ``targets`` the
    blocks' end positions and ``rates`` their nominal speeds. The last block ends at rest.
    """
    starts = [x0, *targets[:-1]]
    lengths = [abs(b - a) for a, b in zip(starts, targets, strict=True)]
    signs = [1.0 if b >= a else -1.0 for a, b in zip(starts, targets, strict=True)]
    n = len(targets)
    max_entry = [v0]
    for i in range(1, n):
        cos_theta = -signs[i - 1] * signs[i]
        limit = junction_speed(cos_theta, accel, junction_deviation)
        max_entry.append(min(limit, rates[i - 1], rates[i]))
    # Backward pass: every block can still stop by the end of the last one.
    exit_v = [0.0] * n
    for i in range(n - 1, 0, -1):
        exit_v[i - 1] = min(max_entry[i], math.sqrt(exit_v[i] ** 2 + 2 * accel * lengths[i]))
    # Forward pass: what the acceleration allows from the present speed.
    pieces: list[Piece] = []
    ends: list[float] = []
    t, v = t0, v0
    for i in range(n):
        reach_up = math.sqrt(v * v + 2 * accel * lengths[i])
        reach_down = math.sqrt(max(0.0, v * v - 2 * accel * lengths[i]))
        vx = min(max(exit_v[i], reach_down), reach_up)
        t = _block_profile(pieces, t, starts[i], signs[i], lengths[i], v, vx, rates[i], accel)
        ends.append(t)
        v = vx
    pieces.append(Piece(t, targets[-1] if targets else x0, 0.0, 0.0))
    return pieces, ends


def _block_profile(
    out: list[Piece],
    t: float,
    x: float,
    sign: float,
    length: float,
    ve: float,
    vx: float,
    vn: float,
    accel: float,
) -> float:
    """Append the accelerate / cruise / decelerate pieces of one block; return its end."""
    if length <= 0.0:
        return t
    v_peak = min(max(vn, ve, vx), math.sqrt((2 * accel * length + ve * ve + vx * vx) / 2))
    v_peak = max(v_peak, ve, vx)
    d_acc = (v_peak * v_peak - ve * ve) / (2 * accel)
    d_dec = (v_peak * v_peak - vx * vx) / (2 * accel)
    d_cruise = max(0.0, length - d_acc - d_dec)
    if d_acc > 0.0:
        out.append(Piece(t, x, sign * ve, sign * accel))
        t += (v_peak - ve) / accel
        x += sign * d_acc
    if d_cruise > 0.0:
        out.append(Piece(t, x, sign * v_peak, 0.0))
        t += d_cruise / v_peak
        x += sign * d_cruise
    if d_dec > 0.0:
        out.append(Piece(t, x, sign * v_peak, -sign * accel))
        t += (v_peak - vx) / accel
    return t
