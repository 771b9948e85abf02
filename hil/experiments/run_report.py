"""The run report: PNG figures of a tank run next to its ``summary.json``.

- ``range_speed.png``: estimated range and speed against receive time, with the truth from
  the stage telemetry (and the exact simulated truth for simulated runs);
- ``time_codeword_map.png``: the GCAS time–codeword map (seed Fig 5.17 style);
- ``errors.png``: histograms of range and speed errors against the truth, for the scored
  estimates (inside the constant-speed segments; false alarms included, the summary's RMSE
  leaves them out).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.experiments.codeword_map import save_time_codeword_map
from hil.experiments.run_scoring import scored_mask, telemetry_truth
from hil.experiments.tank_run import RunOutcome
from hil.figures import new_figure


def write_report(outcome: RunOutcome) -> list[Path]:
    """Write the figures into the run folder; return their paths."""
    folder = outcome.folder
    paths: list[Path] = []
    est = outcome.estimates
    t = np.array([e.t_s for e in est])
    r = np.array([e.range_m for e in est])
    v = np.array([e.speed_mps for e in est])
    truth = telemetry_truth(outcome)

    fig, (ax1, ax2) = new_figure(2, 1, figsize=(10, 6.5), sharex=True, dpi=110)
    ax1.plot(t, r, ".", ms=3, label="estimate")
    ax1.plot(t, truth["range_m"], "-", lw=1.2, label="truth (stage telemetry)")
    if outcome.exact_truth is not None and len(est):
        ax1.plot(t, outcome.exact_truth["range_m"], "--", lw=0.8, label="truth (simulated, exact)")
    ax1.set_ylabel("range (m)")
    ax1.legend(loc="best", fontsize=8)
    ax1.set_title(f"{outcome.experiment.name}: {outcome.experiment.receiver} estimates")
    ax2.plot(t, v, ".", ms=3, label="estimate")
    ax2.plot(t, truth["speed_mps"], "-", lw=1.2, label="truth (stage telemetry)")
    ax2.set_ylabel("closing speed (m/s)")
    ax2.set_xlabel("receive time (s)")
    ax2.legend(loc="best", fontsize=8)
    fig.tight_layout()
    paths.append(folder / "range_speed.png")
    fig.savefig(paths[-1])

    if outcome.map_times:
        paths.append(folder / "time_codeword_map.png")
        save_time_codeword_map(paths[-1], outcome.map_times, outcome.map_power)

    # The estimates the summary scores: inside the constant-speed segments.
    scored = scored_mask(outcome, truth)
    er = (r - truth["range_m"])[scored]
    ev = (v - truth["speed_mps"])[scored]
    fig, (a1, a2) = new_figure(1, 2, figsize=(10, 3.8), dpi=110)
    for ax, e, label in ((a1, er, "range error (m)"), (a2, ev, "speed error (m/s)")):
        e = e[np.isfinite(e)]
        if e.size:
            ax.hist(np.clip(e, np.percentile(e, 1), np.percentile(e, 99)), bins=40)
        ax.set_xlabel(label)
        ax.set_ylabel("estimates")
    fig.tight_layout()
    paths.append(folder / "errors.png")
    fig.savefig(paths[-1])
    return paths
