"""A new user's bad inputs, each run as the user runs it (``hil`` with its argv), refused in
one line that names the field as written, the value, the allowed range and what to do, with
exit status 2 and no traceback: out-of-range numbers that used to exhaust memory, an empty
background file, and a scene sweep's receiver options named where the file gives them."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil.cli.main import main

from .conftest import one_line_error


@pytest.mark.parametrize("value", ["0", "340", "20000", "1e12", "nan"])
def test_estimate_takes_a_sound_speed_of_water_only(
    value: str, schedule_and_wav: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    # 1e12 m/s used to allocate 26 GiB and 20000 m/s to fail inside the search.
    schedule, wav = schedule_and_wav
    capsys.readouterr()
    argv = ["estimate", "--schedule", str(schedule), "--input", str(wav)]
    assert one_line_error(capsys, [*argv, "--sound-speed", value]) == (
        f"hil estimate: error: --sound-speed = {float(value)!r} is not allowed: must be a sound"
        " speed of water, 1300 .. 1700 m/s; e.g. --sound-speed 1500"
    )


def test_estimate_refuses_a_schedule_written_for_another_sound_speed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    wav, schedule = tmp_path / "tx.wav", tmp_path / "tx.json"
    argv = ["waveform", "--duration", "0.05", "--out", str(wav), "--schedule", str(schedule)]
    assert main(argv) == 0
    text = schedule.read_text().replace('"sound_speed_mps": 1500.0', '"sound_speed_mps": 1e9')
    assert '"sound_speed_mps": 1e9' in text
    schedule.write_text(text)
    capsys.readouterr()
    err = one_line_error(capsys, ["estimate", "--schedule", str(schedule), "--input", str(wav)])
    assert err == (
        "hil estimate: error: schedule.sound_speed_mps = 1000000000.0 is not allowed: must be"
        " a sound speed of water, 1300 .. 1700 m/s; give --sound-speed"
    )


def test_waveform_takes_a_sound_speed_of_water_only(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["waveform", "--out", str(tmp_path / "w.wav"), "--sound-speed", "340"]
    assert one_line_error(capsys, argv) == (
        "hil waveform: error: --sound-speed = 340.0 is not allowed: must be a sound speed of"
        " water, 1300 .. 1700 m/s; e.g. --sound-speed 1500"
    )


@pytest.mark.parametrize(
    ("options", "option", "field", "value"),
    [
        (["--hop", "1e9"], "--hop", "hop_s", 1e9),
        (["--family", "fmcw-saw", "--sweep", "1e9"], "--sweep", "sweep_s", 1e9),
        (["--family", "cw-pulse", "--pulse", "1e4", "--pri", "2e4"], "--pulse", "pulse_s", 1e4),
    ],
)
def test_waveform_refuses_a_hop_too_long_to_hold(
    options: list[str],
    option: str,
    field: str,
    value: float,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # A 1e9 s hop used to ask for 728 TiB of tone table.
    argv = ["waveform", "--duration", "0.05", "--out", str(tmp_path / "w.wav"), *options]
    assert one_line_error(capsys, argv) == (
        f"hil waveform: error: {option} ({field}) = {value!r} is not allowed: must be <= 167.772"
        " s (16777216 samples at 100000 Hz, the longest hop held in memory); shorten it (more"
        " hops in a period give the same unambiguous range)"
    )


def test_waveform_suggests_only_hops_it_accepts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["waveform", "--out", str(tmp_path / "w.wav"), "--tones", "100000"]
    err = one_line_error(capsys, argv)
    assert err.endswith("try --hop 22.7273, or change the bandwidth"), err


@pytest.mark.parametrize(
    ("options", "named"),
    [
        (["--family", "costas", "--costas-prime", "4"], "--costas-prime (prime) = 4 is not"),
        (["--m-hops", "0"], "--m-hops (M) = 0 is not"),
        (["--candidates", "100000000"], "--candidates (candidates) = 100000000 is not"),
        (["--sweep", "nan"], "--sweep (sweep_s) = nan is not"),
        (["--family", "three-state", "--m-hops", "5"], "--m-hops (m_hops) = 5 is not"),
        (["--family", "fmcw-saw", "--tones", "5"], "--tones (n_tones) = 5 is not"),
    ],
)
def test_waveform_names_the_option_of_a_design_error(
    options: list[str], named: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    err = one_line_error(capsys, ["waveform", "--out", str(tmp_path / "w.wav"), *options])
    assert err.startswith(f"hil waveform: error: {named} allowed: must be "), err


def test_estimate_refuses_an_empty_background_file(
    schedule_and_wav: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # An empty .npy used to end in numpy's EOFError traceback.
    schedule, wav = schedule_and_wav
    empty = tmp_path / "bg.npy"
    empty.write_bytes(b"")
    capsys.readouterr()
    argv = ["estimate", "--schedule", str(schedule), "--input", str(wav)]
    err = one_line_error(
        capsys, [*argv, "--receiver", "gcas-bg", "--option", f"background={empty}"]
    )
    assert err == (
        f"hil estimate: error: receiver.options.background = '{empty}' is not allowed: must be"
        " a .npy file of one code period; it is empty; capture one: hil docs tank-run,"
        " 'Empty-tank background'"
    )


def test_estimate_refuses_a_background_that_is_not_a_npy_file(
    schedule_and_wav: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    # A WAV given as the background passed on numpy's "pickled data ... allow_pickle" text.
    schedule, wav = schedule_and_wav
    capsys.readouterr()
    argv = ["estimate", "--schedule", str(schedule), "--input", str(wav)]
    err = one_line_error(capsys, [*argv, "--receiver", "gcas-bg", "--option", f"background={wav}"])
    # The WAV's first six bytes: "RIFF" and the low half of its chunk size.
    assert err.startswith(
        f"hil estimate: error: receiver.options.background = '{wav}' is not allowed: must be"
        " a .npy file of one code period; it is not a NumPy .npy file (it starts with b'RIFF"
    ), err
    assert err.endswith("'); capture one: hil docs tank-run, 'Empty-tank background'"), err


@pytest.mark.parametrize("receiver", ["gcas", "mfbank", "jifs"])
def test_estimate_refuses_a_doppler_grid_past_its_largest(
    receiver: str, schedule_and_wav: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    # 10^8 hypotheses ended in an allocation's traceback: 3 GiB in GCAS, 12.7 GiB in the
    # matched-filter bank; every receiver with a Doppler grid checks it in one place.
    schedule, wav = schedule_and_wav
    capsys.readouterr()
    argv = ["estimate", "--schedule", str(schedule), "--input", str(wav), "--receiver", receiver]
    err = one_line_error(capsys, [*argv, "--option", "n_doppler=100000000"])
    assert err == (
        "hil estimate: error: n_doppler = 100000000 is not allowed: must be an integer in"
        " 1 .. 4096; hypotheses closer than the Doppler resolution add nothing: leave it out"
        " for the receiver's default"
    )


def _scene_sweep(tmp_path: Path, fixed: str, grid: str = "") -> Path:
    path = tmp_path / "scene.toml"
    path.write_text(
        '[sweep]\nname = "x"\ntrial = "scene"\nseed = 1\n'
        f'[grid]\nscene = ["still"]\n{grid}\n[fixed]\n{fixed}\n'
    )
    return path


@pytest.mark.parametrize(
    ("fixed", "grid", "message"),
    [
        (
            'receiver = "gcas-bg"\nreceiver_options = {background = "bg.npy"}',
            "",
            "fixed.receiver_options.background = 'bg.npy' is not allowed: must be left out: a"
            " scene captures gcas-bg's background from its own empty water; remove it (hil"
            " estimate and tank runs take a captured one)",
        ),
        (
            'receiver = "gcas-bg"\nreceiver_options = {refine = "yes"}',
            "",
            "fixed.receiver_options.refine = 'yes' is not allowed: must be true or false (a"
            " gcas-bg option); e.g. refine=true",
        ),
        (
            'receiver = "gcas"\nreceiver_options = {n_doppler = -4}',
            "",
            "fixed.receiver_options.n_doppler = -4 is not allowed: must be an integer in"
            " 1 .. 4096; hypotheses closer than the Doppler resolution add nothing: leave it"
            " out for the receiver's default",
        ),
        (
            'receiver = "gcas-bg"\nreceiver_options = {reverb_speed_mps = inf}',
            "",
            "fixed.receiver_options.reverb_speed_mps = inf is not allowed: must be a JSON value:"
            " a finite number, a string, a list or a table of them; give a finite number",
        ),
        (
            'receiver = "gcas"',
            "m_hops = [2.5]",
            "grid.m_hops = 2.5 is not allowed: must be an integer number of hops; at grid point"
            " {'scene': 'still', 'm_hops': 2.5}; e.g. m_hops = 10",
        ),
    ],
)
def test_a_scene_sweep_names_the_receiver_option_where_the_file_gives_it(
    fixed: str, grid: str, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # These were blamed on "the trial's default", told to set an option in [fixed] that
    # [fixed] refuses, silently ignored (background) or shown truncated (m_hops = 2).
    sweep = _scene_sweep(tmp_path, fixed, grid)
    argv = ["sweep", str(sweep), "--out", str(tmp_path / "out"), "--serial", "--quiet"]
    assert one_line_error(capsys, argv) == f"hil sweep: error: {message}"
    assert not (tmp_path / "out" / "results.jsonl").exists()


def test_a_scene_sweep_names_an_unknown_receiver_option(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sweep = _scene_sweep(tmp_path, 'receiver = "gcas-mti"\nreceiver_options = {bogus = 1}')
    argv = ["sweep", str(sweep), "--out", str(tmp_path / "out"), "--serial", "--quiet"]
    err = one_line_error(capsys, argv)
    assert err.startswith(
        "hil sweep: error: fixed.receiver_options.bogus = 1 is not allowed: must be an option"
        " of the gcas receiver: attenuation_db, cancel, "
    ), err
    assert err.endswith(", search; check its spelling, or choose the receiver it belongs to")


@pytest.mark.parametrize(
    ("receiver", "message"),
    [
        ("gcas", "receiver.options.bogus = 2 is not allowed: must be an option of the gcas"),
        ("stft", "receiver.options.bogus = 2 is not allowed: must be an option of the stft"
         " receiver: min_frames, n_s, ns_reading, segment, step; check its spelling, or choose"
         " the receiver it belongs to"),
    ],
)  # fmt: skip
def test_estimate_names_an_unknown_receiver_option_and_its_value(
    receiver: str,
    message: str,
    schedule_and_wav: tuple[Path, Path],
    capsys: pytest.CaptureFixture[str],
) -> None:
    # Was "gcas option = ['bogus']" and "extra = ['bogus']": no option, no value.
    schedule, wav = schedule_and_wav
    capsys.readouterr()
    argv = ["estimate", "--schedule", str(schedule), "--input", str(wav), "--receiver", receiver]
    err = one_line_error(capsys, [*argv, "--option", "bogus=2"])
    assert err.startswith(f"hil estimate: error: {message}"), err


def _experiment(tmp_path: Path, capsys: pytest.CaptureFixture[str], options: str) -> Path:
    assert main(["tank-run", "--print-default"]) == 0
    text = capsys.readouterr().out
    line = 'options = { background = "simulated" }'
    assert line in text
    path = tmp_path / "experiment.toml"
    path.write_text(text.replace(line, f"options = {options}"))
    return path


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (
            "{ background = 3 }",
            "receiver.options.background = 3 is not allowed: must be the path of an empty-tank"
            " background (.npy), a string; write it in quotes; capture one: hil docs tank-run,"
            " 'Empty-tank background'",
        ),
        (
            '{ background = "simulated", refine = "yes" }',
            "receiver.options.refine = 'yes' is not allowed: must be true or false (a gcas-bg"
            " option); e.g. refine=true",
        ),
        (
            '{ background = "simulated", still_periods = 4 }',
            "receiver.options.still_periods = 4 is not allowed: must be an option of the gcas-bg"
            " receiver: attenuation_db, background, cancel, ",
        ),
    ],
)
def test_a_tank_run_names_a_bad_gcas_bg_option(
    options: str, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # These were found only once the run folder was claimed and the simulated background
    # captured (background = 3 as a TypeError traceback, refine named without its table).
    experiment = _experiment(tmp_path, capsys, options)
    argv = ["tank-run", str(experiment), "--virtual-time", "--no-live"]
    err = one_line_error(capsys, [*argv, "--out", str(tmp_path / "run")])
    assert err.startswith(f"hil tank-run: error: {message}"), err
    assert not (tmp_path / "run").exists()


def test_a_tank_sweep_refuses_its_experiments_receiver_option_before_any_trial(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Every trial used to fail on it (exit 1), after the sweep had started.
    experiment = _experiment(tmp_path, capsys, '{ background = "simulated", refine = "yes" }')
    sweep = tmp_path / "tank.toml"
    sweep.write_text(
        '[sweep]\nname = "x"\ntrial = "tank_run"\nseed = 1\n[grid]\ntow_speed_mps = [1.0]\n'
        f'[fixed]\nexperiment = "{experiment}"\n'
    )
    out = tmp_path / "out"
    err = one_line_error(capsys, ["sweep", str(sweep), "--out", str(out), "--serial", "--quiet"])
    assert err == (
        "hil sweep: error: receiver.options.refine = 'yes' is not allowed: must be true or false"
        " (a gcas-bg option); at grid point {'tow_speed_mps': 1.0}; in the experiment"
        f" {experiment} with this point's parameters; e.g. refine=true"
    )
    assert not (out / "results.jsonl").exists()


@pytest.mark.parametrize(
    ("argv", "field"),
    [
        (["simulate", "{d}"], "scenario"),
        (["tank-run", "{d}"], "experiment"),
        (["estimate", "--schedule", "{d}", "--input", "x.wav"], "schedule"),
    ],
)
def test_a_folder_given_for_a_text_file_is_named(
    argv: list[str], field: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Was "error: Is a directory: PATH", naming neither the field nor what to do.
    folder = tmp_path / "a-folder"
    folder.mkdir()
    err = one_line_error(capsys, [a.replace("{d}", str(folder)) for a in argv])
    assert err == (
        f"hil {argv[0]}: error: {field} = '{folder}' is not allowed: must be a file, not a"
        f" folder; give the {field} file in it"
    )


def test_simulate_refuses_a_run_longer_than_a_wav_holds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Was a struct.error traceback from the WAV header, after the folder was claimed.
    out = tmp_path / "sim"
    argv = ["simulate", "att", "--duration", "1e9", "--quiet", "--out", str(out)]
    assert one_line_error(capsys, argv) == (
        "hil simulate: error: --duration = 1000000000.0 is not allowed: must be <= 2684.35 s"
        " (received.wav of 4 float32 channels at 100000 Hz stays within a WAV's 4 GiB);"
        " simulate a shorter run, or fewer output channels (output.channels)"
    )
    assert not out.exists()


def test_simulate_refuses_a_run_its_disk_has_no_room_for(tmp_path: Path) -> None:
    # A real limit: the process's file-size limit (ulimit -f) at 1 MB, under which writes
    # past it fail as on a full disk; 2 s of att's four float32 channels at 100 kHz is
    # 3.2 MB. Nothing is claimed or written; without the limit the same run is written.
    import resource

    def one_megabyte() -> None:
        _default_sigint()
        resource.setrlimit(resource.RLIMIT_FSIZE, (1_000_000, 1_000_000))

    out = tmp_path / "runs" / "sim"
    argv = [sys.executable, "-m", "hil.cli.main", "simulate", "att", "--duration", "2",
            "--quiet", "--out", str(out)]  # fmt: skip
    done = subprocess.run(argv, capture_output=True, text=True, preexec_fn=one_megabyte)
    assert done.returncode == 2, done.stderr
    assert done.stderr == (
        f"hil simulate: error: --out = '{out}' is not allowed: must be a folder with room for"
        " received.wav (0.0032 GB; 0.001 GB left there: the file-size limit (ulimit -f));"
        " free some space (or raise the limit), write --out elsewhere, or simulate a shorter"
        " run\n"
    )
    assert not out.exists()
    done = subprocess.run(argv, capture_output=True, text=True, preexec_fn=_default_sigint)
    assert done.returncode == 0, done.stderr
    assert (out / "received.wav").stat().st_size > 3_200_000


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (
            ["response", "--duration", "1e9"],
            "--duration (duration_s) = 1000000000.0 is not allowed: must be a finite duration"
            " <= 60 s; a sweep of a few seconds measures the response; repeat the calibration"
            " to average",
        ),
        (
            ["response", "--taps", "100000000"],
            "--taps (equaliser_taps) = 100000000 is not allowed: must be an integer in [16,"
            " 65536]; a transducer's response needs a few thousand taps at most",
        ),
        (
            ["response", "--regularisation", "nan"],
            "--regularisation (regularisation_db) = nan is not allowed: must be a finite number"
            " of dB re peak |H|^2; e.g. -40 (deeper: a sharper, noisier inverse)",
        ),
        (
            ["level", "--adc-full-scale", "0"],
            "--adc-full-scale (adc_full_scale_v) = 0.0 is not allowed: must be a voltage > 0 V",
        ),
        (
            ["level", "--input-gain", "inf"],
            "--input-gain (input_gain_db) = inf is not allowed: must be a finite gain, dB",
        ),
    ],
)
def test_calibrate_refuses_a_setting_out_of_range(
    options: list[str],
    message: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The first two ran out of memory (a 349 TiB sweep; the OOM killer), the others were
    # accepted (a full scale of 0 V stood for "not given").
    monkeypatch.setenv("HIL_CALIBRATION_DIR", str(tmp_path / "store"))
    assert one_line_error(capsys, ["calibrate", *options]) == f"hil calibrate: error: {message}"
    assert not (tmp_path / "store" / "simulated" / options[0]).exists()


def test_sweep_refuses_more_pool_workers_than_the_machine_holds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # --workers 100000 used to start spawning a hundred thousand Pythons.
    cores = os.cpu_count() or 1
    out = tmp_path / "out"
    argv = ["sweep", "scenes", "--quick", "--quiet", "--out", str(out), "--workers", "100000"]
    assert one_line_error(capsys, argv) == (
        f"hil sweep: error: --workers = 100000 is not allowed: must be an integer in"
        f" 1..{4 * cores} (4 per core, {cores} cores); one per core is the default; for more,"
        " run on a Dask cluster (--scheduler)"
    )
    assert not (out / "results.jsonl").exists()


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # a background suite hands it ignored


@pytest.mark.slow
def test_simulate_says_its_folder_holds_a_partial_simulation_after_ctrl_c(tmp_path: Path) -> None:
    # Was only "interrupted (Ctrl-C)", leaving a received.wav whose header claims the whole run.
    out = tmp_path / "sim"
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil.cli.main", "simulate", "att", "--duration", "600",
         "--quiet", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint,
    )  # fmt: skip
    wav = out / "received.wav"
    deadline = time.monotonic() + 120.0
    while not (wav.exists() and wav.stat().st_size > 1_000_000):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert err.splitlines()[-2:] == [
        f"hil simulate: {out} holds a partial simulation, cut short at the interruption"
        " (received.wav): simulate again into a new folder",
        "hil simulate: interrupted (Ctrl-C)",
    ], err


@pytest.mark.parametrize("impl", ["python", "c"])
def test_sim_serve_board_names_its_gain_option(
    impl: str, capsys: pytest.CaptureFixture[str]
) -> None:
    err = one_line_error(capsys, ["sim-serve", "board", "--impl", impl, "--gain", "nan"])
    expected = "hil sim-serve: error: --gain = nan is not allowed: must be a finite number"
    assert err.startswith(expected), err


@pytest.mark.parametrize(
    ("argv", "option", "owner"),
    [
        (["stage", "--jack"], "--jack = True", "tank"),
        (["board", "--tank"], "--tank = True", "stage"),
        (["stage", "--delay", "5"], "--delay = 5", "board"),
        (["tank", "--gain", "2"], "--gain = 2.0", "board"),
        (["board", "--period", "256"], "--period = 256", "tank"),
        (["stage", "--experiment", "x.toml"], "--experiment = 'x.toml'", "tank"),
    ],
)
def test_sim_serve_refuses_another_device_s_option(
    argv: list[str], option: str, owner: str, capsys: pytest.CaptureFixture[str]
) -> None:
    # Each was ignored: sim-serve stage --jack served stock GRBL on a pty.
    err = one_line_error(capsys, ["sim-serve", *argv])
    assert err == (
        f"hil sim-serve: error: {option} is not allowed: must be an option of sim-serve"
        f" {owner}; sim-serve {argv[0]} does not read it: drop it"
    )


def test_sim_serve_s_device_options_hold_the_parser_s_defaults() -> None:
    import argparse

    from hil.cli import sim_serve

    parser = argparse.ArgumentParser()
    sim_serve.register(parser.add_subparsers())
    args = parser.parse_args(["sim-serve", "board"])
    for options in sim_serve._DEVICE_OPTIONS.values():
        for dest, default in options.items():
            assert getattr(args, dest) == default, dest
