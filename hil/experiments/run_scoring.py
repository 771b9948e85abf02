"""Scoring a tank run against the stage telemetry: the truth at every estimate, which
estimates are scored, the detection gate (0.5 m, or one range resolution cell when smaller),
the hop boundaries the truth expects, the run summary (``summary.json``) and
``estimates.csv``."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hil.acquisition.annotations import ADC_CLIPPING_TEXT
from hil.estimation.gcas.beyond_span import BEYOND_SPAN_TEXT
from hil.estimation.gcas.clutter_seen import CLUTTER_TEXT
from hil.estimation.track_summary import track_figures
from hil.experiments.run_calibrations import true_stage_motion
from hil.experiments.tank_run import STAGE_POLL_S, TELEMETRY_MAX_REPLY_S, RunOutcome

#: Telemetry truth is not interpolated across reports farther apart than this (s of sample
#: time): a stalled host or stage leaves the carriage's motion in between unknown.
TELEMETRY_GAP_S = 3 * STAGE_POLL_S
#: The widest detection gate, m: an estimate farther than the gate from the truth in range is
#: wrong (a false alarm inside the scored window). The gate is one range resolution cell of
#: the waveform when that is smaller (:func:`detection_gate_m`).
MAX_DETECTION_GATE_M = 0.5

_TRUTH_KEYS = ("range_m", "speed_mps", "stage_x_m", "stage_v_mps")


def range_cell_m(tones_hz: np.ndarray, sound_speed_mps: float) -> float:
    """One range resolution cell of a waveform, ``c / (2 B)`` (m), ``B`` the band its tones
    ``tones_hz`` (Hz) span; ``inf`` for a single tone, which resolves no range by bandwidth.

    >>> round(range_cell_m(np.array([57e3, 59e3, 61e3, 63e3]), 1482.0), 4)  # tank-audio
    0.1235
    """
    tones = np.asarray(tones_hz, dtype=float)
    band = float(tones.max() - tones.min()) if tones.size else 0.0
    return sound_speed_mps / (2.0 * band) if band > 0 else math.inf


def detection_gate_m(outcome: RunOutcome) -> float:
    """The detection gate (m): :data:`MAX_DETECTION_GATE_M`, or one range resolution cell
    (:func:`range_cell_m`) when that is smaller."""
    exp = outcome.experiment
    return min(MAX_DETECTION_GATE_M, range_cell_m(exp.schedule.tones_hz, exp.sound_speed_mps))


def bounce_times(outcome: RunOutcome) -> np.ndarray:
    """Every estimate's bounce instant (s, receiver time base), shape ``(n_estimates,)``:
    halfway between the boundary's transmit and receive times."""
    return np.array([(e.t_s + e.t_tx_s) / 2.0 for e in outcome.estimates], dtype=float)


def telemetry_truth(outcome: RunOutcome) -> dict[str, np.ndarray]:
    """The truth (:func:`truth_at`) at every estimate's bounce instant."""
    return truth_at(outcome, bounce_times(outcome))


def truth_at(outcome: RunOutcome, t_b: np.ndarray) -> dict[str, np.ndarray]:
    """Range (m) and closing speed (m/s) at bounce instants ``t_b`` (s, receiver time base,
    shape ``(n,)``), from the stage telemetry mapped onto sample time (what a lab has as
    ground truth): positions interpolated between status reports, speed from the reported
    feed rate projected on the line of sight (differencing 5 Hz positions would be far
    noisier); reports answered later than :data:`TELEMETRY_MAX_REPLY_S` are not used. With
    a stage calibration applied (:attr:`RunOutcome.calibrations`), range and speed are the
    carriage's true ones. Also the stage's own reported position (``stage_x_m``, m) and
    velocity (``stage_v_mps``, m/s), in the tow plan's commanded coordinates. All shape
    ``(n,)``; NaN outside the telemetry and inside a gap between reports longer than
    :data:`TELEMETRY_GAP_S` (the motion there is unknown)."""
    tel = outcome.telemetry
    idx = np.asarray(tel.sample_index, dtype=float)
    pos = np.asarray(tel.position_m, dtype=float)
    vel = np.asarray(tel.velocity_mps, dtype=float)
    reply = np.asarray(tel.reply_s, dtype=float) if tel.reply_s else np.zeros(idx.size)
    ok = (idx >= 0) & (reply <= TELEMETRY_MAX_REPLY_S)
    t_b = np.asarray(t_b, dtype=float)
    n = t_b.size
    if n == 0 or ok.sum() < 2:
        return {key: np.full(n, np.nan) for key in _TRUTH_KEYS}
    t_tel = (idx[ok] - outcome.start_index) / outcome.fs_hz
    order = np.argsort(t_tel)
    t_tel, x_tel, v_tel = t_tel[order], pos[ok][order], vel[ok][order]
    exp = outcome.experiment
    x = np.interp(t_b, t_tel, x_tel)
    v = np.interp(t_b, t_tel, v_tel)
    # The range and speed of the carriage itself: through the stage calibration, if the run
    # applied one (the reported position is the commanded one, in steps).
    x_true, v_true = true_stage_motion(outcome.calibrations.stage, x_tel, v_tel)
    d = exp.target_position(np.interp(t_b, t_tel, x_true)) - np.asarray(exp.transducer_m)
    r = np.sqrt(np.sum(d * d, axis=-1))
    along = (d @ np.asarray(exp.stage_axis)) / r
    v_carriage = np.interp(t_b, t_tel, v_true)
    after = np.clip(np.searchsorted(t_tel, t_b, side="left"), 1, t_tel.size - 1)
    gap = t_tel[after] - t_tel[after - 1]
    inside = (t_b >= t_tel[0]) & (t_b <= t_tel[-1]) & (gap <= TELEMETRY_GAP_S)
    return {
        "range_m": np.where(inside, r, np.nan),
        "speed_mps": np.where(inside, -along * v_carriage, np.nan),
        "stage_x_m": np.where(inside, x, np.nan),
        "stage_v_mps": np.where(inside, v, np.nan),
    }


#: Scored estimates: the stage reported at least this fraction of the tow speed, so the
#: carriage is past its acceleration (a report inside the run-up blends into the interpolated
#: truth near the segment's ends and is not trusted).
SCORED_SPEED_FRACTION = 0.95


def in_scored_segment(outcome: RunOutcome, truth: dict[str, np.ndarray]) -> np.ndarray:
    """Where the ``truth`` (:func:`truth_at`) puts the carriage inside a tow pass's
    constant-speed segment: between ``tow.start_m`` and ``tow.end_m`` moving at the tow
    speed (at least :data:`SCORED_SPEED_FRACTION` of it, either direction), with a finite
    range. Bool, the truth's shape."""
    plan = outcome.experiment.tow
    lo, hi = sorted((plan.start_m, plan.end_m))
    x, v = truth["stage_x_m"], truth["stage_v_mps"]
    with np.errstate(invalid="ignore"):
        in_segment = (x >= lo) & (x <= hi)
        at_speed = np.abs(v) >= SCORED_SPEED_FRACTION * plan.speed_mps
    return np.asarray(in_segment & at_speed & np.isfinite(truth["range_m"]), dtype=bool)


def scored_mask(outcome: RunOutcome, truth: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """Which estimates are scored (shape ``(n_estimates,)``, bool): those whose bounce
    instant falls inside a tow pass's constant-speed segment as the stage telemetry saw it
    (:func:`in_scored_segment`), with a finite range estimate.

    Measured, not predicted: the segment's times are where the stage's own reports put the
    carriage, so a late ``ok`` or a stalled host or stage shifts nothing (the window predicted
    from the time GRBL accepted the move did, by up to the stall).
    """
    truth = telemetry_truth(outcome) if truth is None else truth
    if len(outcome.estimates) == 0:
        return np.zeros(0, dtype=bool)
    ranges = np.array([e.range_m for e in outcome.estimates])
    return np.asarray(in_scored_segment(outcome, truth) & np.isfinite(ranges), dtype=bool)


def expected_boundaries(outcome: RunOutcome) -> np.ndarray:
    """The hop boundaries the truth says should be detected (global hop indices, ascending,
    int64): every boundary of the schedule whose echo reached the receiver's input and whose
    bounce instant the telemetry puts inside a constant-speed segment
    (:func:`in_scored_segment`). From the truth and the schedule alone, not from the
    estimates: a boundary no estimate claims is still expected.

    Boundary ``k`` (the end of hop ``k``, where the tone changes) is transmitted at ``T``
    and bounces at ``T + R/c``, ``R`` the truth's range then (three fixed-point steps from
    ``R`` at ``T``, each shrinking the error by ``|dR/dt|/c``, 1e-3 at 1.5 m/s); its echo
    is received at ``T + 2R/c``, which must fall before the end of the captured input.
    """
    sch = outcome.experiment.schedule
    c = outcome.experiment.sound_speed_mps
    latency = outcome.latency_samples or 0
    t_end = (outcome.samples - latency) / outcome.fs_hz  # receiver time of the last sample
    period_s = float(sch.period_s)
    hop_s = period_s / sch.period_hops
    n = int(max(0.0, t_end - sch.t0_s) / hop_s) + sch.period_hops
    if n <= 0 or t_end <= 0:
        return np.zeros(0, dtype=np.int64)
    table = sch.hops(0, n + 1)
    tone = table.tone_index
    # A boundary is a change from one tone to another: none between two hops of one tone,
    # none into or out of a silent gap (tone index -1).
    switch = (tone[:-1] != tone[1:]) & (tone[:-1] >= 0) & (tone[1:] >= 0)
    t_tx = (table.start_s + table.duration_s)[:-1]
    keep = switch & (t_tx <= t_end)
    t_tx, k = t_tx[keep], table.index[:-1][keep]
    r = truth_at(outcome, t_tx)["range_m"]
    if not np.isfinite(r).any():
        return np.zeros(0, dtype=np.int64)
    # Where the truth is unknown at the transmit instant (a telemetry gap ending before the
    # bounce), start from the typical range: each step shrinks the error by |dR/dt|/c.
    r = np.where(np.isfinite(r), r, float(np.nanmedian(r)))
    for _ in range(3):
        step = truth_at(outcome, t_tx + r / c)["range_m"]
        r = np.where(np.isfinite(step), step, r)
    truth = truth_at(outcome, t_tx + r / c)
    ok = in_scored_segment(outcome, truth) & (t_tx + 2.0 * r / c <= t_end)
    return np.asarray(k[ok], dtype=np.int64)


@dataclass(frozen=True)
class RunScore:
    """Every estimate of a run against the telemetry truth; arrays of shape
    ``(n_estimates,)``.

    ``known``: the truth is known (the stage telemetry covers the bounce instant);
    ``scored``: inside a constant-speed segment (:func:`scored_mask`); ``wrong``: known and
    more than ``gate_m`` (:func:`detection_gate_m`) off in range, wherever it falls in the
    run (the ramps, the stop, between passes): no estimate is hidden from the count.
    """

    range_error_m: np.ndarray
    speed_error_mps: np.ndarray
    known: np.ndarray
    scored: np.ndarray
    wrong: np.ndarray
    gate_m: float = MAX_DETECTION_GATE_M

    @property
    def good_scored(self) -> np.ndarray:
        """Scored and inside the gate: the estimates of the gated RMSEs."""
        return np.asarray(self.scored & ~self.wrong, dtype=bool)

    def figures(self) -> dict[str, Any]:
        """Counts (all known, wrong, scored) and RMSEs (m, m/s), as ``summary.json`` gives
        them and the figures print them: RMSEs and biases over every scored estimate
        (``*_all_*``: every estimate with a known truth), whatever its error; the
        ``*_gated_*`` RMSEs over those inside the gate only."""
        good = self.good_scored
        n_known = int(self.known.sum())
        return {
            "estimates_with_truth": n_known,
            "wrong_estimates": int(self.wrong.sum()),
            "wrong_fraction": round(float(self.wrong.sum()) / n_known, 4) if n_known else None,
            "wrong_gate_m": self.gate_m,
            "scored_estimates": int(self.scored.sum()),
            "false_alarms": int((self.scored & self.wrong).sum()),
            "range_rmse_m": _rmse(self.range_error_m[self.scored]),
            "speed_rmse_mps": _rmse(self.speed_error_mps[self.scored]),
            "range_bias_m": _mean(self.range_error_m[self.scored]),
            "speed_bias_mps": _mean(self.speed_error_mps[self.scored]),
            "range_rmse_gated_m": _rmse(self.range_error_m[good]),
            "speed_rmse_gated_mps": _rmse(self.speed_error_mps[good]),
            "range_rmse_all_m": _rmse(self.range_error_m[self.known]),
            "speed_rmse_all_mps": _rmse(self.speed_error_mps[self.known]),
        }


def _rmse(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(x * x))) if x.size else None


def _mean(x: np.ndarray) -> float | None:
    return float(np.mean(x)) if x.size else None


def score_run(outcome: RunOutcome, truth: dict[str, np.ndarray] | None = None) -> RunScore:
    """:class:`RunScore` of ``outcome`` (``truth`` from :func:`telemetry_truth` if None)."""
    truth = telemetry_truth(outcome) if truth is None else truth
    r = np.array([e.range_m for e in outcome.estimates], dtype=float)
    v = np.array([e.speed_mps for e in outcome.estimates], dtype=float)
    err_r = r - truth["range_m"]
    err_v = v - truth["speed_mps"]
    known = np.isfinite(err_r)
    gate = detection_gate_m(outcome)
    with np.errstate(invalid="ignore"):
        wrong = known & (np.abs(err_r) > gate)
    return RunScore(err_r, err_v, known, scored_mask(outcome, truth), wrong, gate)


def detection_counts(outcome: RunOutcome, score: RunScore | None = None) -> tuple[int, int]:
    """``(expected, detected)`` hop boundaries: those :func:`expected_boundaries` gives, and
    how many of them at least one estimate of that hop index detected inside the gate."""
    score = score_run(outcome) if score is None else score
    expected = expected_boundaries(outcome)
    hops = np.array([e.hop_index for e in outcome.estimates], dtype=np.int64)
    hit = hops[score.known & ~score.wrong]
    return int(expected.size), int(np.isin(expected, hit).sum())


def summarize(outcome: RunOutcome) -> dict[str, Any]:
    """The run summary (also written as ``summary.json``).

    Counts every estimate whose truth is known: ``wrong_estimates`` over the whole run
    (more than ``wrong_gate_m`` off in range, :func:`detection_gate_m`; ``wrong_fraction``
    of ``estimates_with_truth``), and ``false_alarms``, the wrong ones inside the scored
    window. RMSEs and biases are over every scored estimate, whatever its error (``*_all_*``:
    over every estimate with a known truth); ``*_gated_*`` RMSEs over the scored ones inside
    the gate. The detection rate is ``detected_boundaries / expected_boundaries``
    (:func:`detection_counts`: expected from the truth and the schedule). ``tracks``: every
    confirmed track's count, span and RMSEs against the truth
    (:func:`hil.estimation.track_summary.track_figures`).
    """
    exp = outcome.experiment
    est = outcome.estimates
    truth = telemetry_truth(outcome)
    score = score_run(outcome, truth)
    r = np.array([e.range_m for e in est])
    t = np.array([e.t_s for e in est])
    expected, detected = detection_counts(outcome, score)
    cell = range_cell_m(exp.schedule.tones_hz, exp.sound_speed_mps)

    summary: dict[str, Any] = {
        "run": exp.name,
        "folder": str(outcome.folder),
        "simulated": exp.simulated,
        "receiver": exp.receiver,
        "receiver_options": {k: v for k, v in exp.receiver_options.items() if k != "on_map"},
        "waveform": f"{exp.preset}/{exp.waveform.family}",
        "fs_hz": outcome.fs_hz,
        "sound_speed_mps": exp.sound_speed_mps,
        # Where c came from: a required sound-speed calibration, or the experiment file.
        "sound_speed_from": outcome.calibrations.id_of("sound-speed") or "experiment file",
        "calibrations": list(outcome.calibrations.ids),
        "signal_s": round(outcome.signal_s, 4),
        "wall_s": round(outcome.wall_s, 2),
        "real_time_factor": round(outcome.signal_s / outcome.wall_s, 4) if outcome.wall_s else None,
        "estimates": len(est),
        **score.figures(),
        "update_period_s": float(np.median(np.diff(t))) if len(t) > 1 else None,
        "range_cell_m": round(cell, 6) if math.isfinite(cell) else None,
        "expected_boundaries": expected,
        "detected_boundaries": detected,
        "detection_rate": round(detected / expected, 4) if expected else None,
        "loopback_latency_samples": outcome.latency_samples,
        "dropped_samples": outcome.dropped_samples,
        "capture_backlog_max_s": round(outcome.capture_backlog_max_s, 3),
        "dac_underruns": outcome.dac_underruns,
        "adc_overruns": outcome.adc_overruns,
        # Clipping is never silent: STATUS reports with ADC_CLIPPING (each an alarm event),
        # the simulated board's exact count, and the level the simulation planned.
        "adc_clipping_alarms": sum(
            1 for _, _, _, text in outcome.events if ADC_CLIPPING_TEXT in text
        ),
        "adc_clipped_samples": outcome.adc_clipped_samples,
        "planned_adc_peak_fs": outcome.planned_adc_peak_fs,
        "events": len(outcome.events),
        # The receiver's word that an echo faster than its Doppler span was seen (refused,
        # not reported): the recording's note of it, once per side.
        "beyond_span_notices": [
            text for _, _, _, text in outcome.events if text.startswith(BEYOND_SPAN_TEXT)
        ],
        # Where the receiver refused clutter (diffuse reverberation, the band off): the
        # recording's notes of it, once per range (hil.estimation.gcas.clutter_seen).
        "clutter_notices": [
            text for _, _, _, text in outcome.events if text.startswith(CLUTTER_TEXT)
        ],
        "interrupted": outcome.interrupted,
        "error": outcome.error,
    }
    if outcome.exact_truth is not None and len(est):
        diff = truth["range_m"] - outcome.exact_truth["range_m"]
        fin = np.isfinite(diff)
        summary["telemetry_truth_error_max_m"] = (
            float(np.max(np.abs(diff[fin]))) if fin.any() else None
        )
        e_exact = r - outcome.exact_truth["range_m"]
        summary["range_rmse_vs_exact_m"] = _rmse(e_exact[score.scored])
        v = np.array([e.speed_mps for e in est], dtype=float)
        summary["speed_rmse_vs_exact_mps"] = _rmse(
            (v - outcome.exact_truth["speed_mps"])[score.scored]
        )
    # Per track (hil.estimation.track_summary): its span and its errors against the truth.
    summary["tracks"] = track_figures(est, truth["range_m"], truth["speed_mps"])
    return summary


def true_boundaries(
    outcome: RunOutcome, truth: dict[str, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The hop boundaries the truth says reached the receiver over the estimates' span:
    receive times (s, receiver time base) and codewords, shape ``(b,)`` each.

    A boundary transmitted at ``T`` (the end of its hop) arrives at ``T + 2R/c``, ``R`` the
    telemetry range at the bounce instant ``T + R/c`` (interpolated between the estimates'
    bounce instants; one fixed-point step, ``R`` changes by millimetres meanwhile).
    """
    truth = telemetry_truth(outcome) if truth is None else truth
    est = outcome.estimates
    r = truth["range_m"]
    ok = np.isfinite(r)
    if len(est) == 0 or ok.sum() < 2:
        return np.zeros(0), np.zeros(0, dtype=np.int64)
    hop = np.array([e.hop_index for e in est], dtype=np.int64)
    t_b = np.array([(e.t_s + e.t_tx_s) / 2.0 for e in est])[ok]
    order = np.argsort(t_b)
    t_b, r_ok = t_b[order], r[ok][order]
    sch = outcome.experiment.schedule
    k0, k1 = int(hop.min()), int(hop.max())
    table = sch.hops(k0, k1 - k0 + 1)
    t_end = sch.t0_s + table.start_s + table.duration_s
    c = outcome.experiment.sound_speed_mps
    rng = np.interp(t_end + np.interp(t_end, t_b, r_ok) / c, t_b, r_ok)
    inside = (t_end >= t_b[0]) & (t_end <= t_b[-1])
    codeword = np.arange(k0, k1 + 1) % sch.period_hops
    return (t_end + 2.0 * rng / c)[inside], codeword[inside]


def write_summary(outcome: RunOutcome, summary: dict[str, Any]) -> Path:
    """``summary.json`` and ``estimates.csv`` in the run folder."""
    path = outcome.folder / "summary.json"
    path.write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    truth = telemetry_truth(outcome)
    score = score_run(outcome, truth)
    scored, wrong = score.scored, score.wrong
    rows = ["t_s,range_m,speed_mps,hop_index,score,snr_db,true_range_m,true_speed_mps,scored,wrong"]
    for i, e in enumerate(outcome.estimates):
        rows.append(
            f"{e.t_s:.6f},{e.range_m:.5f},{e.speed_mps:.4f},{e.hop_index},{e.score:.3f},"
            f"{e.snr_db:.2f},{truth['range_m'][i]:.5f},{truth['speed_mps'][i]:.4f},"
            f"{int(scored[i])},{int(wrong[i])}"
        )
    (outcome.folder / "estimates.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path
