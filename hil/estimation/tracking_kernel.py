"""Compiled association loop of the tracker (:mod:`hil.estimation.tracking`; numba).

One call takes a batch of estimates (as arrays) and the live tracks (rows of one state
table) and applies the tracker's rules estimate by estimate: death, gate, choice, Kalman
update or birth, confirmation. Why compiled: per estimate the rules touch every live track,
and as NumPy expressions each estimate paid some 60 array calls of fixed overhead (about
100 µs on the 2-core machine under load), more than the work itself. Compiled with
``cache=True``: the first call in a fresh checkout compiles (seconds) and writes
``__pycache__``; later processes load the machine code.
"""

from __future__ import annotations

import math
from typing import Any

import numba

# Columns of the track table (float64; the integer ones hold whole numbers exactly).
R, V, PRR, PRV, PVV, T_REF, T_LAST, T_FIRST, HOP_LAST, HOP_FIRST, HITS, ID = range(12)
N_COLUMNS = 12
"""Range m and closing speed m/s at ``T_REF``; their covariance (m², m²/s, m²/s²); bounce
instant of the last update, receive times of the last and first estimates (s); first and
last hop index; number of estimates; track id (−1 while tentative)."""


@numba.njit(cache=True, nogil=True)
def associate(
    table: Any,
    n_live: int,
    next_id: int,
    t_rx: Any,
    t_b: Any,
    z_r: Any,
    z_v: Any,
    var_r: Any,
    var_v: Any,
    hop: Any,
    valid: Any,
    accel_var: float,
    gate2: float,
    confirm_hits: int,
    confirm_hops: int,
    confirmed_life_s: float,
    tentative_life_s: float,
    out_id: Any,
) -> tuple[int, int]:
    """Apply the tracker's rules to estimates ``0 .. len(t_rx) − 1`` in order.

    ``table`` (shape ``(capacity, N_COLUMNS)``, capacity ≥ ``n_live + len(t_rx)``) holds the
    ``n_live`` live tracks in its first rows and is updated in place. Per estimate (shape
    ``(n,)`` each): receive time ``t_rx`` and bounce instant ``t_b`` (s), range ``z_r`` (m),
    speed ``z_v`` (m/s), their noise variances ``var_r`` (m²), ``var_v`` (m²/s²), ``hop``
    (int64) and ``valid`` (bool: finite range, speed and time). ``accel_var``: acceleration
    variance (m²/s⁴); ``gate2``: squared gate; ``confirmed_life_s``, ``tentative_life_s``:
    the death rules in receive time. Writes each estimate's track id (−1: none) to
    ``out_id`` (int64) and returns the new ``(n_live, next_id)``.
    """
    for i in range(t_rx.shape[0]):
        if not valid[i]:
            out_id[i] = -1
            continue
        # Death: keep the live rows in order.
        kept = 0
        for k in range(n_live):
            if table[k, ID] >= 0.0:
                dead = t_rx[i] - table[k, T_LAST] > confirmed_life_s
            else:
                dead = t_rx[i] - table[k, T_FIRST] > tentative_life_s
            if not dead:
                if kept != k:
                    table[kept, :] = table[k, :]
                kept += 1
        n_live = kept
        # Gate and choice: the nearest confirmed track, else the nearest tentative one.
        best_c, best_t = -1, -1
        d2_c, d2_t = math.inf, math.inf
        for k in range(n_live):
            if table[k, HOP_LAST] >= hop[i]:
                continue  # one estimate per track per hop boundary
            tentative = table[k, ID] < 0.0
            if tentative and hop[i] - table[k, HOP_FIRST] >= confirm_hops:
                continue
            d2 = _distance2(table, k, t_b[i], z_r[i], z_v[i], var_r[i], var_v[i], accel_var)
            if d2 > gate2:
                continue
            if not tentative and d2 < d2_c:
                best_c, d2_c = k, d2
            elif tentative and d2 < d2_t:
                best_t, d2_t = k, d2
        k = best_c if best_c >= 0 else best_t
        if k >= 0:
            _kalman_update(table, k, t_b[i], z_r[i], z_v[i], var_r[i], var_v[i], accel_var)
            table[k, T_LAST] = t_rx[i]
            table[k, HOP_LAST] = hop[i]
            table[k, HITS] += 1.0
        else:
            k = n_live
            n_live += 1
            table[k, R] = z_r[i]
            table[k, V] = z_v[i]
            table[k, PRR] = var_r[i]
            table[k, PRV] = 0.0
            table[k, PVV] = var_v[i]
            table[k, T_REF] = t_b[i]
            table[k, T_LAST] = t_rx[i]
            table[k, T_FIRST] = t_rx[i]
            table[k, HOP_LAST] = hop[i]
            table[k, HOP_FIRST] = hop[i]
            table[k, HITS] = 1.0
            table[k, ID] = -1.0
        if table[k, ID] < 0.0 and table[k, HITS] >= confirm_hits:
            table[k, ID] = next_id
            next_id += 1
        out_id[i] = int(table[k, ID])
    return n_live, next_id


@numba.njit(cache=True, nogil=True)
def _predict(table: Any, k: int, t_b: float, accel_var: float) -> tuple[float, ...]:
    """Track ``k`` predicted to bounce instant ``t_b``: (range, prr, prv, pvv).

    Constant velocity (range falls at the closing speed) with white-noise acceleration over
    ``|dt|`` (an estimate slightly out of order widens the gate as a later one would)."""
    dt = t_b - table[k, T_REF]
    a = abs(dt)
    r_pred = table[k, R] - table[k, V] * dt
    prr = (
        table[k, PRR]
        - 2.0 * dt * table[k, PRV]
        + dt * dt * table[k, PVV]
        + accel_var * a * a * a * a / 4.0
    )
    prv = table[k, PRV] - dt * table[k, PVV] - accel_var * a * a * a / 2.0
    pvv = table[k, PVV] + accel_var * a * a
    return r_pred, prr, prv, pvv


@numba.njit(cache=True, nogil=True)
def _distance2(
    table: Any,
    k: int,
    t_b: float,
    z_r: float,
    z_v: float,
    var_r: float,
    var_v: float,
    accel_var: float,
) -> float:
    """Squared Mahalanobis distance of an estimate from track ``k``'s prediction."""
    _, _, prv, _, y_r, y_v, s_rr, s_vv, det = _innovation(
        table, k, t_b, z_r, z_v, var_r, var_v, accel_var
    )
    return (s_vv * y_r * y_r - 2.0 * prv * y_r * y_v + s_rr * y_v * y_v) / det


@numba.njit(cache=True, nogil=True)
def _innovation(
    table: Any,
    k: int,
    t_b: float,
    z_r: float,
    z_v: float,
    var_r: float,
    var_v: float,
    accel_var: float,
) -> tuple[float, ...]:
    """Track ``k``'s prediction (:func:`_predict`: range, prr, prv, pvv), the estimate's
    innovation (range, speed) and its covariance's diagonal and determinant."""
    r_pred, prr, prv, pvv = _predict(table, k, t_b, accel_var)
    y_r, y_v = z_r - r_pred, z_v - table[k, V]
    s_rr, s_vv = prr + var_r, pvv + var_v
    return r_pred, prr, prv, pvv, y_r, y_v, s_rr, s_vv, s_rr * s_vv - prv * prv


@numba.njit(cache=True, nogil=True)
def _kalman_update(
    table: Any,
    k: int,
    t_b: float,
    z_r: float,
    z_v: float,
    var_r: float,
    var_v: float,
    accel_var: float,
) -> None:
    """Kalman step of track ``k`` with the estimate (``T_REF`` becomes ``t_b``)."""
    r_pred, prr, prv, pvv, y_r, y_v, s_rr, s_vv, det = _innovation(
        table, k, t_b, z_r, z_v, var_r, var_v, accel_var
    )
    # Gain K = P S⁻¹ (2×2, S⁻¹ = [[s_vv, −prv], [−prv, s_rr]] / det).
    k_rr = (prr * s_vv - prv * prv) / det
    k_rv = (prv * s_rr - prr * prv) / det
    k_vr = (prv * s_vv - pvv * prv) / det
    k_vv = (pvv * s_rr - prv * prv) / det
    table[k, R] = r_pred + k_rr * y_r + k_rv * y_v
    table[k, V] = table[k, V] + k_vr * y_r + k_vv * y_v
    # P = (I − K) P.
    table[k, PRR] = (1.0 - k_rr) * prr - k_rv * prv
    table[k, PRV] = (1.0 - k_rr) * prv - k_rv * pvv
    table[k, PVV] = -k_vr * prv + (1.0 - k_vv) * pvv
    table[k, T_REF] = t_b
