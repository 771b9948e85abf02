"""Ground truth of a simulated run: every hop boundary as the receiver should see it.

For each hop ``j`` emitted at ``t_tx`` (its start), the receive time ``t_rx`` of that boundary
on a target's direct echo path solves ``t_emit(t_rx) = t_tx`` (Newton's method on the exact
path solution, ``d t_emit / d t_rx = α``). Recorded with it: the bounce time, the true range
``|p_T(t_b) − p_sonar(t_b)|`` at the bounce instant (m), the radial (closing, > 0 approaching)
speed there (m/s), the Doppler scale ``α`` and the hop and tone index.
"""

from __future__ import annotations

import csv
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from hil.signals.schedule import HopSchedule
from sim_devices.acoustics.delay import TwoWayPath
from sim_devices.acoustics.trajectory import Trajectory

FIELDS = (
    "target", "hop_index", "tone_index", "t_tx_s", "t_rx_s", "t_bounce_s", "range_m",
    "radial_speed_mps", "alpha",
)  # fmt: skip


@dataclass(frozen=True)
class HopTruth:
    """One hop boundary seen on one target's echo (units in the names)."""

    target: int
    hop_index: int
    tone_index: int
    t_tx_s: float
    t_rx_s: float
    t_bounce_s: float
    range_m: float
    radial_speed_mps: float
    alpha: float


def hop_truth(
    schedule: HopSchedule,
    sonar: Trajectory,
    target: Trajectory,
    sound_speed_mps: float,
    duration_s: float,
    max_delay_s: float,
    target_index: int = 0,
) -> list[HopTruth]:
    """Hop boundaries of ``target``'s echo received in ``[0, duration_s)`` (s)."""
    hops = schedule.hops_in_span(-max_delay_s, duration_s)
    if len(hops) == 0:
        return []
    path = TwoWayPath.monostatic(sonar, target, sound_speed_mps)
    t_tx = hops.start_s
    r0 = np.sqrt(np.sum((target.position(t_tx) - sonar.position(t_tx)) ** 2, axis=1))
    t_rx = t_tx + 2.0 * r0 / sound_speed_mps
    for _ in range(30):
        sol = path.solve(t_rx)
        step = (sol.t_emit_s - t_tx) / sol.alpha
        t_rx = t_rx - step
        if np.max(np.abs(step)) < 1e-13:
            break
    sol = path.solve(t_rx)
    assert sol.t_bounce_s is not None
    t_b = sol.t_bounce_s
    d = target.position(t_b) - sonar.position(t_b)
    rng = np.sqrt(np.sum(d * d, axis=1))
    rel_v = target.velocity(t_b) - sonar.velocity(t_b)
    closing = -np.sum(d * rel_v, axis=1) / rng
    keep = (t_rx >= 0) & (t_rx < duration_s)
    return [
        HopTruth(
            target_index,
            int(hops.index[i]),
            int(hops.tone_index[i]),
            float(t_tx[i]),
            float(t_rx[i]),
            float(t_b[i]),
            float(rng[i]),
            float(closing[i]),
            float(sol.alpha[i]),
        )
        for i in np.flatnonzero(keep)
    ]


def write_truth(rows: list[HopTruth], csv_path: Path, json_path: Path) -> None:
    """Write the rows as CSV (one line per hop boundary) and as a JSON list."""
    with csv_path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=FIELDS)
        writer.writeheader()
        for r in rows:
            writer.writerow(asdict(r))
    json_path.write_text(
        json.dumps({"fields": list(FIELDS), "rows": [asdict(r) for r in rows]}, indent=1) + "\n",
        encoding="utf-8",
    )
