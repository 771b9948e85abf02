"""The run report: PNG figures of a tank run next to its ``summary.json``.

- ``range_speed.png``: estimated range and speed against receive time, with the truth from
  the stage telemetry (and the exact simulated truth for simulated runs);
- ``time_codeword_map.png``: the GCAS time–codeword map (seed Fig 5.17 style) with the true
  hop boundaries from the telemetry;
- ``errors.png``: histograms of range and speed errors against the truth, of every estimate
  with a known truth and of the scored ones (inside the constant-speed segments, whatever
  their error), titled with the counts, RMSEs (also the gated ones) and biases of
  ``summary.json``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.experiments.codeword_map import save_time_codeword_map
from hil.experiments.run_scoring import score_run, telemetry_truth, true_boundaries
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
    score = score_run(outcome, truth)
    figures = score.figures()
    wrong = score.wrong

    fig, (ax1, ax2) = new_figure(2, 1, figsize=(10, 6.5), sharex=True, dpi=110)
    ax1.plot(t[~wrong], r[~wrong], ".", ms=3, label="estimate")
    ax1.plot(
        t[wrong], r[wrong], "x", ms=4, color="tab:red",
        label=f"wrong (> {figures['wrong_gate_m']:g} m off): {figures['wrong_estimates']}",
    )  # fmt: skip
    ax1.plot(t, truth["range_m"], "-", lw=1.2, label="truth (stage telemetry)")
    if outcome.exact_truth is not None and len(est):
        ax1.plot(t, outcome.exact_truth["range_m"], "--", lw=0.8, label="truth (simulated, exact)")
    ax1.set_ylabel("range (m)")
    ax1.legend(loc="best", fontsize=8)
    ax1.set_title(f"{outcome.experiment.name}: {outcome.experiment.receiver} estimates")
    ax2.plot(t[~wrong], v[~wrong], ".", ms=3, label="estimate")
    ax2.plot(t[wrong], v[wrong], "x", ms=4, color="tab:red", label="wrong in range")
    ax2.plot(t, truth["speed_mps"], "-", lw=1.2, label="truth (stage telemetry)")
    ax2.set_ylabel("closing speed (m/s)")
    ax2.set_xlabel("receive time (s)")
    ax2.legend(loc="best", fontsize=8)
    fig.tight_layout()
    paths.append(folder / "range_speed.png")
    fig.savefig(paths[-1])

    if outcome.map_times:
        paths.append(folder / "time_codeword_map.png")
        save_time_codeword_map(
            paths[-1], outcome.map_times, outcome.map_power, true_boundaries(outcome, truth)
        )

    # Every estimate with a known truth; the scored ones (constant-speed segments) on top.
    fig, (a1, a2) = new_figure(1, 2, figsize=(10, 4.2), dpi=110)
    panels = (
        (a1, score.range_error_m, "range error (m)", "range", "m"),
        (a2, score.speed_error_mps, "speed error (m/s)", "speed", "m/s"),
    )
    for ax, err, label, name, unit in panels:
        e_all = err[score.known]
        e_sc = err[score.scored]
        if e_all.size:
            lo, hi = np.percentile(e_all, [0.5, 99.5])
            bins = np.linspace(float(lo), float(hi) + 1e-9, 41)
            ax.hist(np.clip(e_all, bins[0], bins[-1]), bins=bins, color="0.75", label="all known")
            ax.hist(np.clip(e_sc, bins[0], bins[-1]), bins=bins, label="scored")
        suffix = "m" if unit == "m" else "mps"
        rmse, bias = figures[f"{name}_rmse_{suffix}"], figures[f"{name}_bias_{suffix}"]
        gated = figures[f"{name}_rmse_gated_{suffix}"]
        title = "no scored estimate"
        if rmse is not None:
            title = f"scored: rmse {rmse:.3g} {unit}, bias {bias:+.3g} {unit}"
            title += f", gated rmse {gated:.3g} {unit}" if gated is not None else ", none gated"
        ax.set_title(title, fontsize=9)
        ax.set_xlabel(label)
        ax.set_ylabel("estimates")
        if e_all.size:
            ax.legend(fontsize=7)
    fig.suptitle(
        f"{figures['estimates_with_truth']} estimates with truth, "
        f"{figures['wrong_estimates']} wrong (> {figures['wrong_gate_m']:g} m), "
        f"{figures['scored_estimates']} scored, {figures['false_alarms']} wrong among them",
        fontsize=9,
    )
    fig.tight_layout()
    paths.append(folder / "errors.png")
    fig.savefig(paths[-1])
    return paths
