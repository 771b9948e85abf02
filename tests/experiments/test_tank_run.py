"""The towed-target tank run: the experiment file, preflight refusals, the built-in
simulated run end to end (short), replay equals live, and kill -9 leaves a readable file."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from firmware_protocol.messages import Status
from hil.cli.main import main
from hil.devices.audio.daq import AudioDaqStatus
from hil.errors import ConfigError
from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from hil.experiments.live.board_state import xrun_counts, xruns_since
from hil.experiments.live.latency import measure_latency
from hil.experiments.tank_run import run_experiment
from tests.experiments.conftest import CliRun, near_home

# A shorter pass than the built-in run keeps the suite quick.
SHORT = DEFAULT_EXPERIMENT.replace("end_m = -5.0", "end_m = -3.5").replace(
    'name = "sim-towed-pass"', 'name = "short-pass"'
)


#: SHORT slowed to 0.5 m/s and started 0.1 m from home (its run-up from -0.1 m) for the tests
#: that stop the run mid-pass: positioning the carriage 1.4 m out to the run-up's start costs
#: about 3.5 s of wall time at time_scale 0.4 before the recording begins, and the pass they
#: interrupt is 2.8 m long (5.6 s of tow, 14 s of wall time).
STOPPED_MID_PASS = SHORT.replace("speed_mps = 1.5", "speed_mps = 0.5").replace(
    "start_m = -2.0", "start_m = -0.7"
)


def _edit(old: str, new: str) -> str:
    assert old in DEFAULT_EXPERIMENT, old
    return DEFAULT_EXPERIMENT.replace(old, new)


def test_default_experiment_golden() -> None:
    exp = parse_experiment(DEFAULT_EXPERIMENT)
    assert exp.simulated
    # Fresh water at 20 °C (Marczak 1997): 1482.38 m/s.
    assert exp.sound_speed_mps == pytest.approx(1482.38, abs=0.01)
    assert exp.schedule.period_hops == 17 and exp.waveform.fs_hz == 192_000.0
    # Stage x = -2 m puts the target at tank x = 9 m: 8.5 m from the transducer.
    np.testing.assert_allclose(exp.range_at(np.array([-2.0, -5.0])), [8.5, 5.5])
    # Derived from the tank and the tow (hil.experiments.experiment.tank_receiver_options).
    assert exp.receiver_options == {
        "background": "simulated",
        "reverb_speed_mps": 0.0,
        "range_readout": "first-arrival",
    }


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        (
            _edit("[tow]", "[tow]\nsped_mps = 1.0"),
            "tow.sped_mps = 1.0 is not allowed: must be one of the keys",
        ),
        (_edit("[run]", "[runs]"), "runs = "),
        (_edit("speed_mps = 1.5", "speed_mps = -1.5"), "tow.speed_mps = -1.5"),
        (_edit("start_m = -2.0", "start_m = -0.3"), "tow.start_m - tow.run_up_m = 0.3"),
        (_edit("end_m = -5.0", "end_m = -11.0"), "inside the tank"),
        (_edit("max_speed_mps = 3.0", "max_speed_mps = 1.0"), "receiver.max_speed_mps = 1.0"),
        (_edit('board = "sim://board"\n', ""), "devices.board = None"),
        (
            _edit("water_temperature_c = 20.0", "water_temperature_c = 120.0"),
            "tank.water_temperature_c = 120.0",
        ),
        (_edit('family = "random-cyclic"', 'family = "chirp"'), "waveform.family = 'chirp'"),
        (_edit("max_range_m = 12.0", "max_range_m = 500.0"), "receiver.max_range_m = 500.0"),
        ("[run\n", "valid TOML"),
    ],
)
def test_bad_experiment_files_are_refused_naming_the_field(text: str, fragment: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_experiment(text)
    assert fragment in str(info.value)


def test_missing_calibration_is_refused_before_anything_runs(tmp_path: Path) -> None:
    text = _edit("required = []", 'required = ["latency"]').replace(
        'store = "calibration"', f'store = "{tmp_path / "cal"}"'
    )
    exp = parse_experiment(text)
    with pytest.raises(ConfigError) as info:
        run_experiment(exp, folder=tmp_path / "run")
    assert "calibration 'latency'" in str(info.value)
    assert "hil calibrate latency --store" in str(info.value)
    assert not (tmp_path / "run" / "run.h5").exists()


def _store_calibrations(store: Path, latency_rate_hz: float = 192_000.0) -> dict[str, str]:
    from hil.experiments.calibration.latency import LatencyResult
    from hil.experiments.calibration.sound_speed import SoundSpeedResult
    from hil.experiments.calibration.stage import StageResult
    from hil.experiments.calibration.store import CalibrationStore

    cal = CalibrationStore(store)
    latency = LatencyResult((64, 64, 65), latency_rate_hz, 64, 64.3, 0.5, 1, 40.0, 0.5)
    c = SoundSpeedResult(1490.0, 0.3, "time-of-flight")
    stage = StageResult(1.002, 1e-4, 0.001, 5e-5, -3.0, -1, 1490.0)
    return {
        kind: cal.save(kind, result, {"device": "test"}).id
        for kind, result in (("latency", latency), ("sound-speed", c), ("stage", stage))
    }


def test_required_calibrations_are_loaded_and_applied(tmp_path: Path) -> None:
    from hil.experiments.run_calibrations import load_run_calibrations

    ids = _store_calibrations(tmp_path / "cal")
    text = _edit("required = []", 'required = ["sound-speed", "stage", "latency"]').replace(
        'store = "calibration"', f'store = "{tmp_path / "cal"}"'
    )
    exp = parse_experiment(text)
    cals = load_run_calibrations(exp, 192_000.0)
    assert cals.ids == (ids["sound-speed"], ids["stage"], ids["latency"])
    assert cals.id_of("latency") == ids["latency"] and cals.id_of("level") is None
    assert cals.sound_speed_mps == 1490.0 and cals.latency_samples == 64
    assert cals.stage is not None and (cals.stage.scale, cals.stage.backlash_m) == (1.002, 0.001)
    applied = cals.apply(exp)
    assert applied.sound_speed_mps == 1490.0 and applied.waveform.sound_speed_mps == 1490.0
    assert exp.sound_speed_mps == pytest.approx(1482.38, abs=0.01)
    # A c so low that the receiver's range is beyond the unambiguous one: named, with the id.
    slow = dataclasses.replace(cals, sound_speed_mps=100.0)
    with pytest.raises(ConfigError) as info:
        slow.apply(exp)
    assert str(info.value).startswith("receiver.max_range_m = 12.0 is not allowed: must be <=")
    assert f"at the calibrated sound speed 100.0 m/s (calibration {ids['sound-speed']})" in str(
        info.value
    )
    # Kinds the file does not list are not used, though the store holds them.
    only_stage = parse_experiment(text.replace('"sound-speed", "stage", "latency"', '"stage"'))
    cals = load_run_calibrations(only_stage, 192_000.0)
    assert (cals.sound_speed_mps, cals.latency_samples) == (None, None)
    assert cals.apply(only_stage) is only_stage


def test_a_latency_calibration_at_another_rate_is_refused_before_anything_runs(
    tmp_path: Path,
) -> None:
    _store_calibrations(tmp_path / "cal", latency_rate_hz=48_000.0)
    text = _edit("required = []", 'required = ["latency"]').replace(
        'store = "calibration"', f'store = "{tmp_path / "cal"}"'
    )
    with pytest.raises(ConfigError) as info:
        run_experiment(parse_experiment(text), folder=tmp_path / "run")
    message = str(info.value)
    assert "calibration 'latency' = 'measured at 48000 Hz' is not allowed" in message
    assert "must be the run's rate, 192000 Hz" in message and "hil calibrate latency" in message
    assert not (tmp_path / "run" / "run.h5").exists()


def _child_commands() -> list[str]:
    """Command lines of this process's live children (Linux /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(") ", 1)[1].split()
            if int(fields[1]) == os.getpid() and fields[0] != "Z":
                found.append((stat.parent / "cmdline").read_text().replace("\0", " "))
        except (OSError, IndexError, ValueError):
            continue  # it ended while we looked
    return found


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_a_refusal_in_a_simulated_run_leaves_no_simulated_tank_running(tmp_path: Path) -> None:
    # The simulated tank's process starts first; the receiver then refuses its options.
    text = _edit(
        'options = { background = "simulated" }',
        'options = { background = "simulated", reverb_speed_mps = -5.0 }',
    )
    with pytest.raises(ConfigError, match=r"reverb_speed_mps = -5\.0 is not allowed"):
        run_experiment(parse_experiment(text), folder=tmp_path / "run")
    assert not [c for c in _child_commands() if "hil.experiments.sim_tank" in c]


def test_mixed_simulated_and_real_devices_are_refused(tmp_path: Path) -> None:
    exp = parse_experiment(_edit('stage = "sim://stage"', 'stage = "serial:///dev/ttyUSB9"'))
    with pytest.raises(ConfigError, match="both simulated"):
        run_experiment(exp, folder=tmp_path / "run")


def test_every_board_annotation_becomes_a_recordable_event() -> None:
    from hil.acquisition import Annotation, AnnotationKind
    from hil.experiments.live.board_state import run_event
    from hil.recording.schema import EVENT_KINDS

    for kind in AnnotationKind:
        ev = run_event(Annotation(7, kind, 3, "detail"))  # RunEvent refuses unknown kinds
        assert ev.kind in EVENT_KINDS and ev.text == f"{kind.value}: detail"
        assert (ev.sample_index, ev.length) == (7, 3)
    underrun = run_event(Annotation(0, AnnotationKind.DAC_UNDERRUN))
    assert underrun.kind == "underrun"


def _board_status(underruns: int, overruns: int) -> Status:
    return Status(
        sample_index=48_000,
        dac_buffer_level=4096,
        adc_buffer_level=0,
        dac_underruns=underruns,
        adc_overruns=overruns,
        temperature_cdeg=2150,
    )


def test_xrun_counts_read_the_board_and_the_audio_interface() -> None:
    # The board's Status names them dac_underruns/adc_overruns, the audio interface's
    # status underruns/overruns: a run over either reports its own counts (not always 0).
    assert xrun_counts(_board_status(7, 3)) == (7, 3)
    assert xrun_counts(AudioDaqStatus(frames=4096, overruns=2, underruns=5)) == (5, 2)
    assert xrun_counts(None) == (0, 0)


def test_the_run_counts_only_the_xruns_after_its_start() -> None:
    # A board counts since power-up: 5 underruns and 2 overruns came before this run.
    before = xrun_counts(_board_status(5, 2))
    assert xruns_since(before, _board_status(7, 2)) == (2, 0)
    assert xruns_since(before, _board_status(5, 2)) == (0, 0)
    # A counter that went down restarted (power-cycled board, driver reconnected).
    assert xruns_since(xrun_counts(_board_status(9, 4)), _board_status(2, 4)) == (2, 0)
    # No status yet at the start (audio: counted from the stream's start).
    assert xruns_since((0, 0), AudioDaqStatus(frames=1, overruns=1, underruns=0)) == (0, 1)
    assert xruns_since((0, 0), None) == (0, 0)


def test_measure_latency_golden() -> None:
    x = np.random.default_rng(3).normal(size=5000)
    assert measure_latency(np.concatenate([np.zeros(64), x])[:5000], x) == 64
    assert measure_latency(x, x) == 0


@pytest.mark.parametrize(
    ("fraction", "expected"), [(0.0, 64), (0.15, 64), (0.45, 64), (0.55, 65), (0.7, 65), (0.9, 65)]
)
def test_loopback_latency_between_two_samples_rounds_to_a_neighbour(
    fraction: float, expected: int
) -> None:
    # The built-in run's four tones 2 kHz apart: the raw cross-correlation's carrier peaks
    # repeat every 0.5 ms, and a delay between two samples put a neighbouring one (about 96
    # samples off) on top. The envelope's peak is the nearest sample to the delay.
    from hil.experiments.live.latency import measure_loopback
    from hil.signals.synthesis import BlockSynthesizer

    exp = parse_experiment(DEFAULT_EXPERIMENT)
    n = 9600  # the run's 50 ms probe at 192 kHz
    sent = BlockSynthesizer(exp.schedule, exp.waveform.fs_hz, amplitude=0.5).render(0, n)
    f = np.fft.rfftfreq(2 * n)
    padded = np.concatenate([sent, np.zeros(n)])  # silence after: the shift wraps nothing in
    delayed = np.fft.irfft(np.fft.rfft(padded) * np.exp(-2j * np.pi * f * (64 + fraction)))
    lag, rho = measure_loopback(0.3 * delayed[:n], sent)
    assert lag == expected and rho > 0.99


def test_sample_zero_time_survives_a_stall_where_most_syncs_are_late() -> None:
    from hil.experiments.live.board_state import sample_zero_time_s

    fs = 192_000.0
    # The SYNC pairs recorded by a CI run whose simulated board stalled for 4.3 s of clock
    # time, then caught up in a burst: every pair after the stall is late by 6-7 s.
    ci = [(2593430, 3.4508), (2616505, 3.5614), (2640036, 3.6247), (2663412, 3.7669),
          (2688194, 4.0276), (2723066, 8.3419), (2763225, 8.4109), (2880314, 8.4596),
          (3038893, 8.4947)]  # fmt: skip
    burst = [(2_900_000 + 20_000 * k, 8.5 + 0.005 * k) for k in range(8)]
    pairs = ci + burst
    offsets = np.array([t - i / fs for i, t in pairs])
    truth = 3.6247 - 2640036 / fs  # the least-delayed pair, before the stall
    assert offsets.min() == pytest.approx(truth)
    # The former rule (least delay within 1 s below the median) dropped the true pairs here:
    # the run then ended its capture 2 s of signal early and mapped the telemetry 2 s off.
    assert np.median(offsets) > truth + 1.0
    assert sample_zero_time_s(pairs, fs) == pytest.approx(truth, abs=1e-9)
    # A single early pair followed only by late ones (a stall from the start that never
    # drains) is still the one that counts.
    lone = [ci[2], *burst]
    assert sample_zero_time_s(lone, fs) == pytest.approx(truth, abs=1e-9)
    assert sample_zero_time_s([], fs) is None


def test_the_run_keeps_every_sync_pair_beyond_the_fits_window() -> None:
    from hil.acquisition.clock_fit import SampleClockFit
    from hil.experiments.live.board_state import collect_sync_pairs

    # The board's fit keeps its latest 256 pairs; the run collects as they come.
    fit = SampleClockFit(100_000.0, max_pairs=256)
    run_pairs: list[tuple[int, float]] = []
    for k in range(1000):
        fit.add(1000 * k, 5.0 + k / 100 + (0.0 if k == 3 else 0.002))
        if k % 7 == 0:
            collect_sync_pairs(fit, run_pairs)
    collect_sync_pairs(fit, run_pairs)
    assert [p[0] for p in run_pairs] == [1000 * k for k in range(1000)]
    collect_sync_pairs(fit, run_pairs)  # nothing new: nothing added
    assert len(run_pairs) == 1000
    from hil.experiments.live.board_state import sample_zero_time_s

    # The least-delayed pair (k = 3) left the fit's window long ago; the run still has it.
    assert sample_zero_time_s(run_pairs, 100_000.0) == pytest.approx(5.0)
    assert len(fit.pair_list()) == 256
    assert sample_zero_time_s(fit.pair_list(), 100_000.0) == pytest.approx(5.002)
    collect_sync_pairs(None, run_pairs)  # no fit (no board, or not configured): nothing to add
    assert len(run_pairs) == 1000


#: Summary keys a recording cannot give back (docs/tank-run.md, "After a crash").
NOT_RECORDED = frozenset(
    {"folder", "wall_s", "real_time_factor", "capture_backlog_max_s", "adc_clipped_samples",
     "planned_adc_peak_fs", "telemetry_truth_error_max_m", "range_rmse_vs_exact_m",
     "speed_rmse_vs_exact_mps"}
)  # fmt: skip


@pytest.mark.slow
def test_simulated_run_end_to_end_and_replay_equals_live(
    cli_virtual_run: CliRun, capsys: pytest.CaptureFixture[str]
) -> None:
    from hil.recording.reader import RunRecording
    from hil.recording.replay import compare_estimates, replay

    # ``hil tank-run SHORT --out FOLDER --no-live --json --virtual-time`` (the conftest's run,
    # shared with test_run_log: its log options change nothing of the run).
    assert cli_virtual_run.status == 0
    folder, summary = cli_virtual_run.folder, cli_virtual_run.summary
    tmp_path = cli_virtual_run.scratch  # where hil report writes its rebuilt summary
    for name in ("run.h5", "summary.json", "estimates.csv", "range_speed.png", "errors.png",
                 "time_codeword_map.png"):  # fmt: skip
        assert (folder / name).exists(), name
    assert summary["error"] == "" and not summary["interrupted"]
    assert summary["dropped_samples"] == 0
    # On virtual time the capture loop waits for each receiver decision (one 10 ms block
    # behind at most) and the board's DAC never runs dry.
    assert summary["capture_backlog_max_s"] <= 0.02, summary["capture_backlog_max_s"]
    assert summary["dac_underruns"] == 0 and summary["adc_overruns"] == 0
    assert summary["loopback_latency_samples"] == 64  # the simulated converters
    assert summary["scored_estimates"] >= 50
    # The towed target is tracked: the first-arrival readout ranges the direct path despite
    # the surface/bottom images ~0.2 ms behind it (the peak readout: +0.45 m); the speed is
    # still biased by the images (-0.07 m/s in the default run).
    assert summary["receiver_options"]["range_readout"] == "first-arrival"
    assert summary["speed_rmse_mps"] < 0.1
    assert abs(summary["range_bias_m"]) < 0.06 and summary["range_rmse_m"] < 0.08
    assert summary["telemetry_truth_error_max_m"] < 0.1
    assert summary["false_alarms"] <= 2
    assert summary["wrong_fraction"] <= 0.05
    assert summary["estimates_with_truth"] >= summary["scored_estimates"]
    assert summary["detection_rate"] > 0.9
    # Replay with the live settings reproduces the live estimates exactly.
    rec = RunRecording.open(folder / "run.h5")
    # Every board annotation is in the recording, after the loopback-latency note.
    events = rec.events()
    assert events[0].kind == "note" and len(events) == summary["events"] + 1
    live = rec.estimates()
    assert len(live) == summary["estimates"]
    assert events[-1].text == "stop: completed" and events[-1].kind == "note"
    again = replay(rec)
    agreement, words = compare_estimates(live, again)
    assert agreement == "equal", words
    rec.close()
    # hil report rebuilds the same summary from the recording (into another folder): what a
    # recording holds is what the run scored with; the wall time is not recorded.
    assert main(["report", str(folder / "run.h5"), "--out", str(tmp_path / "re"), "--json"]) == 0
    rebuilt = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    same = sorted(set(summary) - NOT_RECORDED - {"figures"})
    assert {k: rebuilt[k] for k in same} == {k: summary[k] for k in same}
    assert rebuilt["wall_s"] == 0.0 and rebuilt["real_time_factor"] is None
    # The GCAS map, replayed: the same figure set as live.
    assert sorted(Path(f).name for f in rebuilt["figures"]) == sorted(
        Path(f).name for f in summary["figures"]
    )


def _default_sigint() -> None:
    """In the child before exec: SIGINT raises KeyboardInterrupt again, as in a terminal (a
    suite started as a background job hands its children SIGINT ignored, and Python keeps
    an inherited ignore)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.slow
def test_the_default_demo_runs_on_ptys_in_real_time(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The real-time smoke test: the simulated devices on ptys in a child process, driven as
    hardware is. Limits are generous: on a machine busy with other work the capture may lag
    seconds behind (the board's ring holds 8 s) and the simulated board may underrun."""
    exp_file = tmp_path / "short.toml"
    exp_file.write_text(near_home(SHORT))
    folder = tmp_path / "run"
    assert main(["tank-run", str(exp_file), "--out", str(folder), "--no-live", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["error"] == "" and not summary["interrupted"]
    assert summary["dropped_samples"] == 0
    assert summary["capture_backlog_max_s"] < 6.0
    assert summary["loopback_latency_samples"] == 64
    assert summary["scored_estimates"] >= 50 and summary["detection_rate"] > 0.8
    assert abs(summary["range_bias_m"]) < 0.1 and summary["range_rmse_m"] < 0.15
    assert summary["wrong_fraction"] <= 0.1
    # In real time too, hil report of the recording gives every scoring key of the live
    # summary: the recording keeps each stage report with its reply time (the late ones are
    # left out of both truths) and the SYNC pairs that map them.
    assert main(["report", str(folder / "run.h5"), "--out", str(tmp_path / "re"), "--json",
                 "--no-map"]) == 0  # fmt: skip
    rebuilt = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    # Not the xrun counts: live they are the simulated board's own, rebuilt the recorded xrun
    # events, which also hold each time a host that fell behind skipped DAC samples.
    same = sorted(set(summary) - NOT_RECORDED - {"figures", "dac_underruns", "adc_overruns"})
    assert {k: rebuilt[k] for k in same} == {k: summary[k] for k in same}
    # One time base: the recording's telemetry sample indices are the SYNC mapping the
    # summary used (live, each report got the clock fit of its moment, up to 0.6 s off).
    from hil.experiments.live.board_state import sample_zero_time_s
    from hil.recording.reader import RunRecording

    with RunRecording.open(folder / "run.h5") as rec:
        tel, pairs, fs = rec.table("telemetry"), rec.sync_pairs(), rec.fs_hz
    zero = sample_zero_time_s(
        list(zip(pairs.sample_index.tolist(), pairs.host_time_s.tolist(), strict=True)), fs
    )
    assert zero is not None and tel["sample_index"].size > 10
    np.testing.assert_array_equal(
        tel["sample_index"], np.round((tel["host_time_s"] - zero) * fs).astype(np.int64)
    )


@pytest.mark.slow
def test_kill_9_during_a_run_leaves_a_recording_hil_report_rebuilds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run killed with SIGKILL mid-pass leaves a recording that reads and that ``hil
    report`` turns into the summary and figures the run never wrote. What is checked is the
    recording's writer (SWMR, flushed as it goes), the same on either clock: the run is on
    virtual time (the simulated tank in the run's own process), without the seconds of wall
    time of a real-time pass. The real-time tank's own process is checked under a signal by
    the Ctrl-C case below, and killed mid-run by
    test_the_built_in_tank_lost_mid_run_stops_the_run_naming_it."""
    from hil.recording.reader import RunRecording

    exp_file = tmp_path / "short.toml"
    exp_file.write_text(STOPPED_MID_PASS)
    folder = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil.cli.main", "tank-run", str(exp_file), "--out", str(folder),
         "--no-live", "--virtual-time"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    h5 = folder / "run.h5"
    _wait_while_running(proc, lambda: h5.exists() and h5.stat().st_size > 200_000, "200 kB")
    grown = h5.stat().st_size
    _wait_while_running(proc, lambda: h5.stat().st_size > grown, "one more flush")
    os.killpg(proc.pid, signal.SIGKILL)  # the run's process group, as kill -9 of a session
    proc.wait(timeout=10)
    rec = RunRecording.open(h5)
    blocks = rec.samples()
    assert blocks and sum(b.data.shape[0] for b in blocks) > 10_000
    assert rec.schedule().period_hops == 17
    assert rec.telemetry()
    estimates = len(rec.estimates())
    rec.close()
    # The summary and figures it never wrote, rebuilt from the recording alone.
    assert not (folder / "summary.json").exists()
    assert main(["report", str(h5), "--json"]) == 1  # the run did not stop on its own
    from hil.experiments.run_from_recording import KILLED

    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["error"] == KILLED and summary["interrupted"] is True
    assert summary["estimates"] == estimates and summary["rebuilt_from"] == str(h5)
    assert summary["loopback_latency_samples"] == 64
    assert json.loads((folder / "summary.json").read_text()) == summary
    for name in ("estimates.csv", "range_speed.png", "errors.png", "time_codeword_map.png"):
        assert (folder / name).exists(), name


def _wait_while_running(proc: subprocess.Popen[Any], ready: Callable[[], bool], what: str) -> None:
    """Poll ``ready`` until it holds; fails if the run ends first. The 15 minutes guard
    against a hung run only: no test here relies on how fast the machine is."""
    guard = time.monotonic() + 900
    while not ready():
        assert proc.poll() is None, f"the run ended (status {proc.returncode}) before {what}"
        assert time.monotonic() < guard, f"no {what} within 15 minutes: the run hangs"
        time.sleep(0.1)


def _carriage_moving(h5: Path) -> bool:
    """Whether the live recording's stage telemetry already shows the carriage moving."""
    from hil.recording.reader import RunRecording

    if not h5.exists():
        return False
    try:
        with RunRecording.open(h5) as rec:
            return any(abs(t.velocity_mps) > 0.05 for t in rec.telemetry())
    except (OSError, KeyError, ConfigError):
        # Not yet a complete recording (the file is being created: not yet readable, or its
        # groups not yet written). Once it is in SWMR mode every column reads while the run
        # writes it (docs/recording-format.md). Poll again.
        return False


def _stopped_as_interrupted(
    code: int, out: str, h5: Path, how: str, said: str
) -> tuple[dict[str, Any], Any]:
    """Check a run interrupted by ``how`` (its exit ``code``, the stdout ``out`` of ``hil
    tank-run --json``, its recording ``h5``; ``said`` shown on a failure): exit 130, a summary
    that says it was interrupted and how, the recording readable and ending with the stop's
    event. The summary and the recording's instrument entry."""
    import h5py

    from hil.recording.instrument import read_entry
    from hil.recording.reader import RunRecording

    assert code == 130, said  # interrupted: the run stopped before its end
    summary = json.loads(out.strip().splitlines()[-1])
    assert (summary["interrupted"], summary["error"]) == (True, f"interrupted ({how})"), said
    with RunRecording.open(h5) as rec:
        assert sum(b.data.shape[0] for b in rec.samples()) > 10_000
        stop = rec.events()[-1]
    assert (stop.kind, stop.text) == ("alarm", f"stop: interrupted ({how})")
    with h5py.File(h5, "r") as f:
        entry = read_entry(f)
    assert entry is not None
    return summary, entry


@pytest.mark.slow
def test_ctrl_c_stops_cleanly_in_real_time_and_keeps_the_recording(tmp_path: Path) -> None:
    """SIGINT (a terminal's Ctrl-C) to the run's process group mid-pass: transmission
    stopped, stage held, files closed, a summary written that says the run was interrupted
    and how, the recording readable and ending with the stop's event. In real time over ptys,
    the simulated tank in its own process in the run's process group: real time is what
    shows that the tank's process outlives the signal the whole group gets (it ignores SIGINT,
    SIGTERM and SIGHUP alike, one rule in ``hil.experiments.sim_tank._serve``) and that the
    stage, held, ends short of the pass's end. SIGTERM and SIGHUP: the next test, on virtual
    time."""
    exp_file = tmp_path / "slow.toml"
    # A slow tow (0.5 m/s: a 2.8 m pass takes 14 s of wall time at time_scale 0.4) leaves
    # the interrupt seconds of the pass to land in, even when the telemetry that shows the
    # carriage moving is read seconds late on a loaded machine (CI once saw a 1.5 m/s pass,
    # 4.5 s of wall time, all but over before the interrupt arrived).
    exp_file.write_text(STOPPED_MID_PASS)
    folder = tmp_path / "run"
    log = tmp_path / "stderr.txt"  # shown if the run did not stop as it should
    with log.open("w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "hil.cli.main", "tank-run", str(exp_file), "--out",
             str(folder), "--no-live", "--json"],
            stdout=subprocess.PIPE, stderr=err, text=True, start_new_session=True,
            preexec_fn=_default_sigint,
        )  # fmt: skip
    h5 = folder / "run.h5"
    try:
        # Interrupt while the carriage is on its pass, as the recording's telemetry shows (a
        # fixed delay after the capture starts may land after the pass on a loaded machine,
        # or before the recording exists while a loaded machine builds the receiver).
        _wait_while_running(proc, lambda: _carriage_moving(h5), "the carriage on its pass")
        os.killpg(proc.pid, signal.SIGINT)  # as a terminal does: the whole process group
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:  # the test failed first: leave nothing running
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    said = f"stdout: {out}\nstderr: {log.read_text()}"
    _, entry = _stopped_as_interrupted(proc.returncode, out, h5, "Ctrl-C", said)
    assert entry["instrument"]["board"]["link"].startswith("/dev/pts/"), entry  # over ptys
    # The stage was held: the simulated carriage (its true trajectory, written by the
    # simulated tank at stop) is at rest at the end and stopped short of the end of the pass
    # (end_m - run_down_m = -4.1 m).
    traj = np.load(folder / "sim_stage_trajectory.npz")
    t, x = traj["t"], traj["x"]
    late = t >= t[-1] - 0.2
    assert np.ptp(x[late]) < 1e-3
    assert x[-1] > -4.1 + 0.05


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=lambda s: s.name)
def test_sigterm_and_sighup_stop_cleanly_on_virtual_time_and_keep_the_recording(
    tmp_path: Path,
    sig: signal.Signals,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """SIGTERM (kill, a service manager) or SIGHUP (the terminal closed) mid-pass: what the
    Ctrl-C test above checks, for the run's own handling of the signal (``StopSignals``: a
    RunInterrupted named after the signal, the safe stop, the summary and the recording's
    stop event), the same on either clock. ``hil tank-run --virtual-time`` in this process
    (no tank process: the signal reaches only the run's), the signal raised in its main
    thread as the recorded stage telemetry first shows the carriage moving: mid-pass at a
    known instant, however loaded the machine."""
    from hil.recording.records import StageTelemetry
    from hil.recording.writer import RunWriter

    exp_file = tmp_path / "slow.toml"
    exp_file.write_text(STOPPED_MID_PASS)
    folder = tmp_path / "run"
    append_telemetry = RunWriter.append_telemetry
    raised: list[StageTelemetry] = []

    def signal_once_moving(writer: RunWriter, record: StageTelemetry) -> None:
        append_telemetry(writer, record)
        if not raised and abs(record.velocity_mps) > 0.05:
            raised.append(record)
            signal.raise_signal(sig)  # its handler runs here, in the run's main thread

    monkeypatch.setattr(RunWriter, "append_telemetry", signal_once_moving)
    code = main(["tank-run", str(exp_file), "--out", str(folder), "--no-live", "--json",
                 "--virtual-time"])  # fmt: skip
    out, err = capsys.readouterr()
    assert len(raised) == 1, (out, err)
    how = sig.name
    summary, entry = _stopped_as_interrupted(
        code, out, folder / "run.h5", how, f"stdout: {out}\nstderr: {err}"
    )
    # On virtual time: the in-process devices (no tank process, so no trajectory file). The
    # hold on a stop is the same safe stop for every signal, checked above in real time and
    # on virtual time by test_tank_run_virtual's unplugged board (the in-process carriage).
    assert entry["instrument"]["board"]["link"] == "sim://board (in process, virtual time)"
    # Stopped mid-pass: the pass (2.8 m at 0.5 m/s, 5.6 s) was not over.
    assert summary["signal_s"] < 5.6


@pytest.mark.slow
def test_the_receiver_is_built_before_anything_moves_or_transmits(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Building the receiver loads (on a fresh install: compiles) its kernels, tens of seconds:
    with the board already streaming that overflowed the capture ring. It comes first."""
    import hil.experiments.tank_run as tank_run
    from hil.devices.grbl import GrblStage

    order: list[str] = []
    make = tank_run.build_receiver

    def recording_make(*args: object, **kwargs: object) -> object:
        order.append("receiver")
        return make(*args, **kwargs)  # type: ignore[arg-type]

    def stop_at_stage(self: GrblStage) -> GrblStage:
        order.append("stage")
        raise RuntimeError("the test stops the run at the stage")

    monkeypatch.setattr(tank_run, "build_receiver", recording_make)
    monkeypatch.setattr(GrblStage, "open", stop_at_stage)
    exp_file = tmp_path / "short.toml"
    exp_file.write_text(SHORT)
    # On virtual time: the order is the same as on ptys (run_experiment builds the receiver
    # before it opens any device) without starting the simulated tank's process.
    argv = ["tank-run", str(exp_file), "--out", str(tmp_path / "run"), "--no-live", "--json"]
    code = main([*argv, "--virtual-time"])
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code != 0
    assert "the test stops the run at the stage" in summary["error"]
    assert order == ["receiver", "stage"]


def test_a_board_stopped_by_its_watchdog_ends_the_run_with_the_reason() -> None:
    """The board stops streaming when its watchdog expires; the run must stop at once with
    that reason, not wait for samples until run.max_duration_s."""
    from hil.devices.board import Board
    from hil.devices.clock import VirtualClock
    from hil.experiments.live.board_state import board_stopped
    from sim_devices.board import BoardPort, LoopbackWorld, MemoryBoardLink, SimulatedBoard

    clock = VirtualClock()
    sim = SimulatedBoard(clock=clock, world=LoopbackWorld(5))
    link = MemoryBoardLink(BoardPort(sim), timeout=0.0)
    with Board(link, virtual_time=clock, keepalive_ms=60000) as board:
        board.configure()
        first = board.start()
        assert board.wait_for_samples(first + 100, timeout_s=1.0)
        assert board_stopped(board) is None
        sim.faults.expire_watchdog()
        assert clock.wait_until(lambda: board_stopped(board) is not None, timeout_s=1.0)
        why = board_stopped(board)
    assert why is not None
    assert why.startswith("the board stopped streaming at sample ")
    assert "board watchdog expired: transmission stopped" in why
    assert "the host sent it nothing for its watchdog timeout" in why


@pytest.mark.slow
def test_the_built_in_tank_lost_mid_run_stops_the_run_naming_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The simulated tank's process killed under the run, mid-pass (as the run's 30th
    estimate comes, an event of the run rather than a size of its file polled): the run
    stops, naming it (not a bare ``OSError: [Errno 5]`` from whichever pty noticed first)."""
    from hil.estimation.base import Estimate
    from hil.experiments import sim_tank
    from hil.experiments.tank_run import LiveView
    from hil.recording.reader import RunRecording

    started: list[sim_tank.SimulatedTankProcess] = []
    original = sim_tank.SimulatedTankProcess.__init__

    def keep(self: sim_tank.SimulatedTankProcess, *args: object) -> None:
        original(self, *args)  # type: ignore[arg-type]
        started.append(self)

    monkeypatch.setattr(sim_tank.SimulatedTankProcess, "__init__", keep)
    folder = tmp_path / "run"
    h5 = folder / "run.h5"
    seen: list[Estimate] = []

    def kill_at_30(estimates: list[Estimate]) -> None:
        if len(seen) < 30 <= len(seen) + len(estimates):
            os.kill(started[0].pid, signal.SIGKILL)
        seen.extend(estimates)

    # The short pass near home: 1.5 m at 1.5 m/s, its 30th estimate 0.3 s into the capture.
    outcome = run_experiment(
        parse_experiment(near_home(SHORT)),
        folder=folder,
        view=LiveView(enabled=False),
        on_estimates=kill_at_30,
    )
    assert len(seen) >= 30 and not outcome.interrupted
    pid = started[0].pid
    assert outcome.error == (
        f"DeviceLostError: the built-in simulated tank (process {pid}) lost: its process exited"
        " with code -9; check that nothing killed it (its errors are printed above)"
    )
    with RunRecording.open(h5) as rec:
        assert rec.events()[-1].text == f"stop: error: {outcome.error}"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_the_cli_refuses_an_existing_run_folder_before_starting_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    (earlier / "run.h5").write_bytes(b"an earlier run")
    assert main(["tank-run", "--out", str(earlier), "--no-live"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"hil tank-run: error: --out = '{earlier}' is not allowed: must be")
    assert "never overwritten" in err
    assert (earlier / "run.h5").read_bytes() == b"an earlier run"
    assert sorted(p.name for p in earlier.iterdir()) == ["run.h5"]
    assert not [c for c in _child_commands() if "hil.experiments.sim_tank" in c]


def test_hil_report_refuses_what_is_not_a_run_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "none.h5"
    assert main(["report", str(missing)]) == 2
    assert "RUN (recording) = " in capsys.readouterr().err
    cut = tmp_path / "cut.h5"
    cut.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(40))
    assert main(["report", str(cut)]) == 2
    err = capsys.readouterr().err
    assert "is not allowed: must be an HDF5 run recording written by hil" in err
