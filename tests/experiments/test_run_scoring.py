"""Scoring a tank run against the stage telemetry: which estimates count (the constant-speed
segments the telemetry saw, not the windows the driver predicted), gaps in the telemetry,
and the detection rate counted per pass. Synthetic runs with a known carriage motion."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from hil.estimation.base import Estimate
from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from hil.experiments.run_scoring import (
    MAX_DETECTION_GATE_M,
    TELEMETRY_GAP_S,
    detection_gate_m,
    expected_boundaries,
    range_cell_m,
    score_run,
    scored_mask,
    summarize,
    telemetry_truth,
    true_boundaries,
)
from hil.experiments.tank_run import TELEMETRY_MAX_REPLY_S, RunOutcome, Telemetry

EXP = parse_experiment(DEFAULT_EXPERIMENT)  # tow -2 m -> -5 m at 1.5 m/s, run-up 0.6 m
FS = 1000.0  # sample time = index / FS
ACCEL = 2.0  # m/s^2
SPEED = 1.5


def _pass_x(t: np.ndarray, t0: float, x0: float, x1: float) -> tuple[np.ndarray, np.ndarray]:
    """Trapezoidal move x0 -> x1 starting at t0: position (m) and signed velocity (m/s)."""
    d = np.sign(x1 - x0)
    ta = SPEED / ACCEL
    tc = (abs(x1 - x0) - SPEED * ta) / SPEED
    s = np.clip(t - t0, 0.0, 2 * ta + tc)
    acc = np.minimum(s, ta)
    cru = np.clip(s - ta, 0.0, tc)
    dec = np.clip(s - ta - tc, 0.0, ta)
    dist = 0.5 * ACCEL * acc**2 + SPEED * cru + SPEED * dec - 0.5 * ACCEL * dec**2
    speed = np.where(s < ta, ACCEL * s, np.where(s < ta + tc, SPEED, SPEED - ACCEL * dec))
    speed = np.where((t < t0) | (s >= 2 * ta + tc), 0.0, speed)
    return x0 + d * dist, d * speed


def _motion(t: np.ndarray, passes: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The carriage: at -1.4 m, first pass (-1.4 -> -5.6 m) at t = 1 s; a return pass
    (-5.6 -> -1.4 m) at t = 6 s when ``passes == 2``."""
    x, v = _pass_x(t, 1.0, -1.4, -5.6)
    if passes == 2:
        x2, v2 = _pass_x(t, 6.0, -5.6, -1.4)
        late = t >= 6.0
        x, v = np.where(late, x2, x), np.where(late, v2, v)
    return x, v


C = EXP.sound_speed_mps
HOP_S = 0.01  # the tank-audio schedule: boundary k (the end of hop k) leaves at (k + 1) hops


def _boundaries(ks: np.ndarray, passes: int) -> tuple[np.ndarray, np.ndarray]:
    """Boundaries ``ks`` of the schedule as the carriage meets them: transmit times (s) and
    the exact bounce instants (s), from ``t_b = T + R(t_b)/c`` solved to 1e-12 s."""
    t_tx = HOP_S * (ks + 1.0)
    t_b = t_tx.copy()
    for _ in range(6):  # |dR/dt|/c = 1e-3: each step gains three digits
        t_b = t_tx + EXP.range_at(_motion(t_b, passes)[0]) / C
    return t_tx, t_b


def _outcome(
    t_tel: np.ndarray, ks: np.ndarray, *, passes: int = 1, range_error_m: float = 0.0
) -> RunOutcome:
    """A run whose receiver detects boundaries ``ks`` (ascending), each at its true time with
    the true range (plus ``range_error_m``); telemetry reports at ``t_tel``."""
    x_tel, v_tel = _motion(t_tel, passes)
    t_tx, t_b = _boundaries(ks, passes)
    r_est = EXP.range_at(_motion(t_b, passes)[0])
    estimates = [
        Estimate(float(2 * b - tx), float(r + range_error_m), 1.5, int(k), 10.0, 20.0, 1.0,
                 float(tx), int(k) % 17, "x")
        for k, tx, b, r in zip(ks, t_tx, t_b, r_est, strict=True)
    ]  # fmt: skip
    telemetry = Telemetry(
        host_time_s=list(t_tel),
        sample_index=[int(round(t * FS)) for t in t_tel],
        position_m=list(x_tel),
        velocity_mps=list(v_tel),
        state=["RUN" if v else "IDLE" for v in v_tel],
    )
    return RunOutcome(
        folder=Path("unused"),
        experiment=EXP,
        fs_hz=FS,
        start_index=0,
        samples=int(12.0 * FS),  # 12 s of input: the receiver hears boundaries 0 .. 1198
        estimates=estimates,
        telemetry=telemetry,
        dropped_samples=0,
        dac_underruns=0,
        adc_overruns=0,
        events=[],
        wall_s=1.0,
        signal_s=12.0,
        # Deliberately wrong: a stall made the driver's prediction late. Scoring ignores it.
        windows=[(20.0, 22.0)],
    )


T_TEL = np.round(np.arange(0.0, 12.0, 0.2), 6)  # 5 Hz reports
KS = np.arange(1190)  # every boundary whose echo is heard within the 12 s
T_EST = _boundaries(KS, 1)[1]  # their bounce instants (one pass)


def test_scored_segment_golden() -> None:
    # The carriage accelerates until t = 1.75 s (x = -1.9625 m) and cruises past -2 m at
    # 1.775 s and -5 m at 3.775 s. Interpolating the 1.6 s (accelerating, 1.2 m/s) and 1.8 s
    # reports puts the -2 m crossing at 1.77297 s with |v| = 1.46 > 0.95 * 1.5 there. The
    # boundary leaving at 1.77 s bounces 8.5 m / c = 5.73 ms later, inside; the one before
    # (1.7657 s) is not. The last, leaving at 3.77 s, bounces at 3.7737 s (5.5 m away). So the
    # scored estimates are boundaries 176 ... 376: 201 of them.
    out = _outcome(T_TEL, KS)
    scored = scored_mask(out)
    t = T_EST[scored]
    assert scored.sum() == 201
    assert np.flatnonzero(scored)[[0, -1]].tolist() == [176, 376]
    assert t[0] == pytest.approx(1.7757333, abs=1e-7) and t[-1] == pytest.approx(3.7737116)
    # Contiguous, and every scored estimate really is in the segment (within the 3 mm the
    # interpolation across the end of the run-up is off by) at the tow speed.
    assert np.all(np.diff(np.flatnonzero(scored)) == 1)
    x, v = _motion(t)
    assert np.all((x <= -2.0 + 3.5e-3) & (x >= -5.0)) and np.all(np.abs(v) == SPEED)


def test_scoring_does_not_use_the_predicted_window() -> None:
    # The outcome's predicted window (20-22 s) is far from the pass; the CI run that scored
    # 48 of 100 estimates had a window shifted by a stall.
    summary = summarize(_outcome(T_TEL, KS))
    assert summary["scored_estimates"] == 201
    assert (summary["expected_boundaries"], summary["detected_boundaries"]) == (201, 201)
    assert summary["detection_rate"] == 1.0 and summary["false_alarms"] == 0
    assert summary["range_rmse_m"] == pytest.approx(0.0, abs=0.02)


def test_truth_is_unknown_inside_a_telemetry_gap() -> None:
    # No reports between 2.0 and 3.2 s (a 1.2 s stall > TELEMETRY_GAP_S): the truth is NaN
    # there instead of a straight line through the missing motion.
    assert TELEMETRY_GAP_S < 1.2
    keep = (T_TEL <= 2.0) | (T_TEL >= 3.2)
    out = _outcome(T_TEL[keep], KS)
    truth = telemetry_truth(out)
    gap = (T_EST > 2.0) & (T_EST < 3.2)
    assert np.all(np.isnan(truth["range_m"][gap])) and np.all(np.isnan(truth["stage_x_m"][gap]))
    assert np.all(np.isfinite(truth["range_m"][~gap & (T_EST < 11.8)]))
    scored = scored_mask(out, truth)
    # Bounces at 1.7757 ... 1.9955 s (23) and 3.2043 ... 3.7737 s (58).
    assert scored.sum() == 23 + 58
    assert not np.any(scored & gap)
    # Nor is a boundary inside the gap expected: the truth there is unknown.
    np.testing.assert_array_equal(expected_boundaries(out), KS[scored])
    # Outside the telemetry: unknown as well.
    assert np.isnan(truth["range_m"][-1])


def test_detection_rate_is_counted_per_pass() -> None:
    # Two passes (out at 1 s, back at 6 s): the hops between them are not expected.
    out = _outcome(T_TEL, KS, passes=2)
    t_b = _boundaries(KS, 2)[1]
    scored = scored_mask(out)
    starts = np.flatnonzero(np.diff(scored.astype(int)) == 1) + 1
    np.testing.assert_allclose(t_b[starts], [1.7757333, 6.7737089])  # two runs of them
    summary = summarize(out)
    assert (summary["expected_boundaries"], summary["detection_rate"]) == (401, 1.0)
    # Half the boundaries of the second pass missed: (201 + 100) / (201 + 200).
    second = scored & (t_b > 6.0)
    assert second.sum() == 200
    drop = set(np.flatnonzero(second)[1::2].tolist())
    out.estimates = [e for i, e in enumerate(out.estimates) if i not in drop]
    summary = summarize(out)
    assert summary["scored_estimates"] == 301
    assert (summary["expected_boundaries"], summary["detected_boundaries"]) == (401, 301)
    assert summary["detection_rate"] == round(301 / 401, 4)


def test_expected_boundaries_come_from_the_truth_not_the_estimates() -> None:
    # The receiver stops detecting 0.5 s before the end of the pass and misses every other
    # boundary before: the 201 boundaries of the pass are still expected (counting from the
    # estimates' own hop indices expected only the 151 their span covers).
    out = _outcome(T_TEL, KS)
    ks = np.array([k for k in KS if k < 326 and k % 2 == 0])
    out.estimates = [e for e in out.estimates if e.hop_index in set(ks.tolist())]
    np.testing.assert_array_equal(expected_boundaries(out), np.arange(176, 377))
    summary = summarize(out)
    assert (summary["expected_boundaries"], summary["detected_boundaries"]) == (201, 75)
    assert summary["detection_rate"] == round(75 / 201, 4)
    # No estimate at all: still 201 expected, none detected.
    out.estimates = []
    summary = summarize(out)
    assert (summary["expected_boundaries"], summary["detection_rate"]) == (201, 0.0)


def test_a_boundary_whose_echo_was_not_captured_is_not_expected() -> None:
    # The input ends at 3.0 s: boundary k leaves at 0.01 (k + 1) s and comes back 2R/c
    # later (9.0 ms at 6.67 m), so the last heard is 298 (leaving at 2.99 s, back at
    # 2.99900 s); 299 leaves at 3.00 s.
    out = _outcome(T_TEL, KS)
    out.samples = int(3.0 * FS)
    expected = expected_boundaries(out)
    assert (int(expected[0]), int(expected[-1])) == (176, 298)
    # The loopback latency (10 ms here) shortens the receiver's input by as much: 297 is
    # back at 2.98900 s, before 2.99 s.
    out.latency_samples = 10
    assert int(expected_boundaries(out)[-1]) == 297


def test_no_boundary_is_expected_where_the_tone_does_not_change() -> None:
    # Hops 16 and 0 of each period given the same tone: the end of hop 16 (k = 16 mod 17)
    # switches nothing, so no echo marks it. The pass's 201 boundaries 176 ... 376 hold 12
    # of those (186, 203, ..., 373).
    code = EXP.schedule.code.copy()
    code[16] = code[0]
    out = _outcome(T_TEL, KS)
    out.experiment = dataclasses.replace(EXP, schedule=dataclasses.replace(EXP.schedule, code=code))
    expected = expected_boundaries(out)
    assert expected.size == 201 - 12 and not np.any(expected % 17 == 16)


def test_false_alarms_are_scored_estimates_outside_the_gate() -> None:
    # The tank-audio tones span 57-63 kHz: one range resolution cell c / 2B = 0.1235 m, so
    # that is the gate (under 0.5 m).
    assert range_cell_m(EXP.schedule.tones_hz, C) == pytest.approx(C / 12e3, rel=1e-12)
    out = _outcome(T_TEL, KS, range_error_m=0.2)  # inside 0.5 m, outside one cell
    assert detection_gate_m(out) == pytest.approx(0.12353163, abs=1e-8)
    summary = summarize(out)
    assert summary["wrong_gate_m"] == detection_gate_m(out)
    assert summary["range_cell_m"] == round(C / 12e3, 6)
    assert summary["scored_estimates"] == 201 and summary["false_alarms"] == 201
    assert summary["detection_rate"] == 0.0 and summary["detected_boundaries"] == 0
    # Every scored estimate is in the RMSE and the bias, whatever its error; the gated RMSE
    # has none left (to the 0.26 mm the interpolated telemetry truth is off by).
    assert summary["range_rmse_m"] == pytest.approx(0.2, abs=3e-4)
    assert summary["range_bias_m"] == pytest.approx(0.2, abs=3e-4)
    assert summary["range_rmse_gated_m"] is None and summary["speed_rmse_gated_mps"] is None
    assert summary["range_rmse_all_m"] == pytest.approx(0.2, abs=1e-3)
    # Inside the cell: detected, not wrong.
    summary = summarize(_outcome(T_TEL, KS, range_error_m=0.1))
    assert summary["false_alarms"] == 0 and summary["detection_rate"] == 1.0
    assert summary["range_rmse_gated_m"] == summary["range_rmse_m"]
    assert summary["range_rmse_m"] == pytest.approx(0.1, abs=3e-4)


def test_the_gate_is_half_a_metre_when_the_cell_is_wider() -> None:
    # Tones 300 Hz apart (900 Hz in all): a cell of c / 1800 Hz = 0.82 m, so the gate is 0.5 m.
    narrow = dataclasses.replace(
        EXP.schedule, tones_hz=np.array([57000.0, 57300.0, 57600.0, 57900.0])
    )
    out = _outcome(T_TEL, KS, range_error_m=0.3)
    out.experiment = dataclasses.replace(EXP, schedule=narrow)
    assert range_cell_m(narrow.tones_hz, C) == pytest.approx(C / 1800.0, rel=1e-12)
    assert detection_gate_m(out) == MAX_DETECTION_GATE_M == 0.5
    summary = summarize(out)
    assert summary["false_alarms"] == 0 and summary["detection_rate"] == 1.0
    # One tone resolves no range by bandwidth: the cell is infinite, the gate 0.5 m.
    assert range_cell_m(np.array([57000.0]), C) == math.inf


def test_no_estimates_or_no_telemetry() -> None:
    out = _outcome(T_TEL, KS)
    out.estimates = []
    assert scored_mask(out).shape == (0,)
    out = _outcome(T_TEL[:1], KS)
    truth = telemetry_truth(out)
    assert set(truth) == {"range_m", "speed_mps", "stage_x_m", "stage_v_mps"}
    assert not scored_mask(out, truth).any()


def test_reports_answered_late_are_left_out_of_the_truth() -> None:
    clean = telemetry_truth(_outcome(T_TEL, KS))
    out = _outcome(T_TEL, KS)
    tel = out.telemetry
    k = int(np.searchsorted(T_TEL, 2.4))  # mid-pass
    # That report came back 0.3 s after its query (a stalled stage): its position is the
    # carriage's 0.3 s later than its date says.
    tel.position_m[k] -= SPEED * 0.3
    tel.reply_s = [0.0] * len(T_TEL)
    tel.reply_s[k] = 0.3
    truth = telemetry_truth(out)
    np.testing.assert_allclose(truth["range_m"], clean["range_m"], atol=1e-12)
    # Kept, it would have pulled the truth by up to 0.45 m.
    tel.reply_s[k] = TELEMETRY_MAX_REPLY_S
    assert np.nanmax(np.abs(telemetry_truth(out)["stage_x_m"] - clean["stage_x_m"])) > 0.4


def test_a_stage_calibration_corrects_the_truth_not_the_scoring() -> None:
    # Scale 1.002 about -3 m, backlash 1 mm: the carriage is where the calibration says,
    # so the truth's range follows it, and its speed is 1.002 times the reported one. The
    # scored segment stays in the tow plan's commanded coordinates.
    from hil.experiments.calibration.apply import StagePositionCorrection
    from hil.experiments.run_calibrations import RunCalibrations

    plain = _outcome(T_TEL, KS)
    corr = StagePositionCorrection(scale=1.002, backlash_m=0.001, reference_m=-3.0)
    calibrated = _outcome(T_TEL, KS)
    calibrated.calibrations = RunCalibrations(ids=("stage-x",), stage=corr, kinds=("stage",))
    a, b = telemetry_truth(plain), telemetry_truth(calibrated)
    np.testing.assert_array_equal(scored_mask(plain), scored_mask(calibrated))
    np.testing.assert_array_equal(a["stage_x_m"], b["stage_x_m"])
    scored = scored_mask(plain)
    # Moving -x: half the backlash adds +0.5 mm and the scale moves -2 m by +2 mm, -5 m by
    # -4 mm, so the carriage is 2.5 mm short of -2 m and 3.5 mm past -5 m (on the axis
    # through the transducer: the range changes by as much).
    x = a["stage_x_m"][scored]
    x_true = -3.0 + 1.002 * (x + 3.0) + 0.0005
    np.testing.assert_allclose(b["range_m"][scored], EXP.range_at(x_true), rtol=0, atol=1e-12)
    np.testing.assert_allclose(b["speed_mps"][scored], 1.002 * a["speed_mps"][scored], rtol=1e-12)
    dr = (b["range_m"] - a["range_m"])[scored]  # the target nears as the carriage goes -x
    assert dr.max() == pytest.approx(0.0025, abs=1e-5)
    assert dr.min() == pytest.approx(-0.0035, abs=1e-5)


def test_wrong_estimates_outside_the_scored_window_are_counted() -> None:
    # Ghosts during the ramps and after the stop (2 m off) fall outside the scored window:
    # they count as wrong over the run, not as false alarms of the scored window.
    out = _outcome(T_TEL, KS)
    scored = scored_mask(out)
    ghosts = np.flatnonzero(~scored & (T_EST > 1.0) & (T_EST < 6.0))
    for i in ghosts.tolist():
        e = out.estimates[i]
        out.estimates[i] = Estimate(
            e.t_s, e.range_m + 2.0, e.speed_mps, e.hop_index, e.score, e.snr_db, e.alpha,
            e.t_tx_s, e.codeword, e.receiver,
        )  # fmt: skip
    summary = summarize(out)
    known = int(np.isfinite(telemetry_truth(out)["range_m"]).sum())
    assert summary["estimates_with_truth"] == known
    assert summary["wrong_estimates"] == ghosts.size > 100
    assert summary["wrong_fraction"] == pytest.approx(round(ghosts.size / known, 4))
    assert summary["false_alarms"] == 0 and summary["scored_estimates"] == 201
    assert summary["range_rmse_m"] < 1e-3  # the interpolated telemetry truth: 0.26 mm
    assert summary["wrong_gate_m"] == pytest.approx(C / 12e3, rel=1e-12)  # one range cell
    # Over the whole run every estimate with a truth counts, the ghosts with their 2 m.
    assert summary["range_rmse_all_m"] == pytest.approx(
        2.0 * math.sqrt(ghosts.size / known), rel=1e-3
    )
    score = score_run(out)
    assert np.array_equal(np.flatnonzero(score.wrong), ghosts)
    assert not (score.good_scored & score.wrong).any()


def test_true_boundaries_golden() -> None:
    # The target held at 7 m: every boundary arrives 2·7/c after its hop ends, with the hop's
    # codeword (hop index mod the 17-hop period).
    out = _outcome(T_TEL, KS)
    n = len(out.estimates)
    truth = {k: np.full(n, v) for k, v in (("range_m", 7.0), ("speed_mps", 0.0))}
    t_rx, word = true_boundaries(out, truth)
    sch = EXP.schedule
    hops = np.array([e.hop_index for e in out.estimates])
    k = np.arange(hops.min(), hops.max() + 1)
    table = sch.hops(int(k[0]), k.size)
    t_end = sch.t0_s + table.start_s + table.duration_s
    t_b = np.array([(e.t_s + e.t_tx_s) / 2 for e in out.estimates])
    inside = (t_end >= t_b.min()) & (t_end <= t_b.max())
    np.testing.assert_allclose(t_rx, t_end[inside] + 2 * 7.0 / EXP.sound_speed_mps, atol=1e-12)
    assert word.tolist() == (k[inside] % 17).tolist()
    out.estimates = []
    assert true_boundaries(out)[0].size == 0


def test_the_summary_lists_the_receivers_notices_of_an_echo_beyond_the_span() -> None:
    from hil.estimation.gcas.beyond_span import CLOSING, BeyondSpan

    said = BeyondSpan(0.1085, 3, CLOSING, 3.0, 3.6).text()
    events = [("note", 108, 0, said), ("alarm", 12_000, 0, "stop: completed")]
    summary = summarize(dataclasses.replace(_outcome(T_TEL, KS), events=events))
    assert summary["beyond_span_notices"] == [said] and summary["events"] == 2
    assert said == (
        "an echo beyond the ±3 m/s Doppler span was seen (closing) at t = 0.1085 s (hop 3); "
        "it is refused, not reported: raise --max-speed to measure it"
    )
    assert summarize(_outcome(T_TEL, KS))["beyond_span_notices"] == []


def test_the_summary_lists_the_receivers_notices_of_clutter() -> None:
    from hil.estimation.gcas.beyond_span import CLOSING, BeyondSpan
    from hil.estimation.gcas.clutter_seen import ClutterSeen

    near = ClutterSeen(0.1135, 10, 2.634, 0.02).text()
    far = ClutterSeen(0.2415, 23, 1.14, -0.01).text()
    beyond = BeyondSpan(0.1085, 3, CLOSING, 3.0, 3.6).text()
    events = [("note", 108, 0, beyond), ("note", 113, 0, near), ("note", 241, 0, far)]
    summary = summarize(dataclasses.replace(_outcome(T_TEL, KS), events=events))
    assert summary["clutter_notices"] == [near, far]
    assert summary["beyond_span_notices"] == [beyond] and summary["events"] == 3
    assert summarize(_outcome(T_TEL, KS))["clutter_notices"] == []
