"""A new user's bad inputs the first tour left: calibration options that were silently
ignored (a thermometer's uncertainty with time of flight, a stage URL on the simulated
bench), Ctrl-C while a sweep writes its report, and the commands it did not try (replay,
report, docs; estimate's --option of a common setting). Each is run as the user runs it
(``hil`` with its argv) and refused in one line naming the option, the value, the allowed
range and what to do."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from hil.cli.main import main

from .conftest import empty_recording, one_line_error


def test_sound_speed_by_time_of_flight_refuses_a_temperature_uncertainty(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # It was accepted and ignored: time of flight reads c's uncertainty off its fit.
    argv = ["calibrate", "sound-speed", "--method", "tof", "--store", str(tmp_path)]
    err = one_line_error(capsys, [*argv, "--temperature-uncertainty", "0.3"])
    assert err == (
        "hil calibrate: error: --temperature-uncertainty = 0.3 is not allowed: must be left"
        " out with --method tof, whose c takes its uncertainty from the fit of the echo's time"
        " of flight (the temperature only cross-checks c); drop it, or use --method temperature"
        " --temperature °C"
    )
    assert not any(tmp_path.rglob("*.json"))


def test_sound_speed_by_temperature_uses_the_temperature_uncertainty(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["calibrate", "sound-speed", "--temperature", "20", "--store", str(tmp_path)]
    assert main([*argv, "--temperature-uncertainty", "0.3"]) == 0
    wide = capsys.readouterr().out.splitlines()[0]
    assert main(argv) == 0
    default = capsys.readouterr().out.splitlines()[0]
    # dc/dT at 20 °C is 3.07 m/s per °C (Marczak): 0.3 °C -> 0.921 m/s, 0.1 °C -> 0.307 m/s.
    assert wide.startswith("sound speed: 1482.380 m/s +- 0.921 m/s"), wide
    assert default.startswith("sound speed: 1482.380 m/s +- 0.307 m/s"), default


@pytest.mark.parametrize(
    ("option", "value", "shown"),
    [("--stage", "/dev/ttyUSB0", "'/dev/ttyUSB0'"), ("--device", "sim://audio", "'sim://audio'"),
     ("--latency", "5", "5"), ("--positions=-0.3,-0.2", None, "[-0.3, -0.2]"),
     ("--speed", "0.02", "0.02"), ("--pings", "8", "8"), ("--gate-ms", "1 4", "[1.0, 4.0]")],
)  # fmt: skip
def test_sound_speed_by_temperature_refuses_the_options_of_a_measurement(
    option: str, value: str | None, shown: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # They were accepted and ignored: a thermometer's c ranges no echo, so neither the stage's
    # positions and speed nor the echo's gate and pings are used.
    argv = ["calibrate", "sound-speed", "--temperature", "20", "--store", str(tmp_path)]
    given = [option] if value is None else [option, *value.split()]
    name = option.split("=")[0]
    assert one_line_error(capsys, [*argv, *given]) == (
        f"hil calibrate: error: {name} = {shown} is not allowed: must be left out with"
        " --method temperature (nothing is measured); drop it, or use --method tof to measure"
        " c by time of flight"
    )


@pytest.mark.parametrize(
    ("url", "allowed"),
    [
        ("bogus://x", "must be a device path or one of serial://, loop://, socket://,"),
        ("sim://audio", "must be a stage URL (a serial port or transport URL, or sim://stage);"),
        ("sim://stagex", "must be sim://stage (a simulated stage); did you mean sim://stage?"),
        ("", "must be a non-empty transport URL or device path"),
    ],
)
@pytest.mark.parametrize("kind", [["stage"], ["sound-speed", "--method", "tof"]])
def test_calibrating_on_the_simulated_bench_checks_the_stage_url(
    url: str, allowed: str, kind: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A bogus --stage was ignored on the simulated bench; it is checked as the tank run
    # checks devices.stage (hil.devices.table).
    argv = ["calibrate", *kind, "--stage", url, "--store", str(tmp_path)]
    err = one_line_error(capsys, argv)
    assert err.startswith(f"hil calibrate: error: --stage = {url!r} is not allowed: {allowed}"), err


def test_the_simulated_bench_refuses_a_real_stage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["calibrate", "stage", "--stage", "/dev/ttyUSB0", "--store", str(tmp_path)]
    assert one_line_error(capsys, argv) == (
        "hil calibrate: error: --stage = '/dev/ttyUSB0' is not allowed: must be sim://stage or"
        " left out on the simulated bench; give --device (the audio interface) to calibrate"
        " with a real stage"
    )


_TRIALS = '''\
import signal
from pathlib import Path


def one(params, seed):
    return {"x": float(params["x"])}


def report(spec, records, out_dir):
    """Ctrl-C after the first half of the first report; the whole report on a resume."""
    path = Path(out_dir) / "report.md"
    first = not path.exists()
    path.write_text("# partial\\n" if first else f"# {len(records)} trials\\n")
    if first:
        signal.raise_signal(signal.SIGINT)
    return [path]


one.write_report = report
'''


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # a background suite hands it ignored


def test_ctrl_c_while_a_sweep_writes_its_report_says_it_may_be_partial(tmp_path: Path) -> None:
    # Was only "interrupted (Ctrl-C)": the report left half written looked finished.
    (tmp_path / "trials.py").write_text(_TRIALS)
    sweep = tmp_path / "s.toml"
    sweep.write_text(
        '[sweep]\nname = "t"\ntrial = "trials.py:one"\ntrials_per_point = 2\nseed = 1\n'
        "[grid]\nx = [1.0, 2.0]\n"
    )
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "hil.cli.main", "sweep", str(sweep), "--out", str(out)]
    first = subprocess.run(
        [*argv, "--serial", "--quiet"], capture_output=True, text=True, timeout=300,
        preexec_fn=_default_sigint,
    )  # fmt: skip
    assert first.returncode == 130, first.stderr
    assert first.stderr.splitlines() == [
        f"hil sweep: interrupted (Ctrl-C) while writing the report: all 4 trials are saved in"
        f" {out / 'results.jsonl'}, but the report in {out} may be partial; rebuild it with:"
        f" hil sweep {sweep} --out {out} --resume"
    ]
    assert (out / "report.md").read_text() == "# partial\n"
    again = subprocess.run(
        [*argv, "--serial", "--quiet", "--resume"], capture_output=True, text=True, timeout=300,
        preexec_fn=_default_sigint,
    )  # fmt: skip
    assert again.returncode == 0, again.stderr
    assert "ran 0 (4 already done)" in again.stdout
    assert (out / "report.md").read_text() == "# 4 trials\n"


# -- the commands the first tour did not try: replay, report, docs, estimate's --option ---


@pytest.mark.parametrize(
    ("value", "shown"), [("1e12", "1000000000000.0"), ("20000", "20000.0"), ("fast", "'fast'")]
)
def test_replay_takes_a_sound_speed_of_water_only(
    value: str, shown: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # 1e12 m/s used to end in numpy's 130 GiB allocation error; 20000 m/s in no estimates.
    run = empty_recording(tmp_path / "run.h5")
    argv = ["replay", str(run), "--option", f"sound_speed_mps={value}"]
    assert one_line_error(capsys, argv) == (
        f"hil replay: error: --option sound_speed_mps = {shown} is not allowed: must be a sound"
        " speed of water, 1300 .. 1700 m/s; e.g. --option sound_speed_mps=1500"
    )


def test_replay_names_the_staged_receiver_of_an_unknown_option(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # It named "the gcas receiver" and left the stage's options (background, ...) out.
    run = empty_recording(tmp_path / "run.h5", "gcas-bg", background="simulated")
    err = one_line_error(capsys, ["replay", str(run), "--option", "backgroud=x.npy"])
    assert err.startswith(
        "hil replay: error: receiver.options.backgroud = 'x.npy' is not allowed: must be an"
        " option of the gcas-bg receiver: attenuation_db, background, cancel, "
    ), err


@pytest.mark.parametrize(
    ("option", "flag"),
    [("sound_speed_mps=1e12", "--sound-speed"), ("m_hops=5", "--m-hops"),
     ("max_range_m=5", "--max-range"), ("max_speed_mps=2", "--max-speed")],
)  # fmt: skip
def test_estimate_sets_the_common_settings_with_their_own_options_only(
    option: str, flag: str, schedule_and_wav: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    # --option sound_speed_mps=1e12 overrode the checked --sound-speed (a 26 GiB allocation);
    # --option m_hops=5 overrode --m-hops unseen.
    schedule, wav = schedule_and_wav
    capsys.readouterr()
    argv = ["estimate", "--schedule", str(schedule), "--input", str(wav), "--option", option]
    key = option.partition("=")[0]
    err = one_line_error(capsys, argv)
    assert err.startswith(f"hil estimate: error: --option {key} = "), err
    assert err.endswith(
        f" is not allowed: must be a receiver-specific option; hil estimate sets it with {flag}:"
        " use that instead"
    ), err


def test_estimate_names_the_staged_receiver_of_an_unknown_option(
    schedule_and_wav: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    schedule, wav = schedule_and_wav
    capsys.readouterr()
    argv = ["estimate", "--schedule", str(schedule), "--input", str(wav)]
    err = one_line_error(capsys, [*argv, "--receiver", "gcas-still", "--option", "stil=4"])
    assert err.startswith(
        "hil estimate: error: receiver.options.stil = 4 is not allowed: must be an option of"
        " the gcas-still receiver: "
    ), err
    assert "still_periods" in err, err


def test_report_refuses_an_exact_truth_that_is_a_folder_or_not_text(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A folder said only "Is a directory"; a binary file ended in a UnicodeDecodeError.
    run = empty_recording(tmp_path / "run.h5")
    argv = ["report", str(run), "--no-map", "--out", str(tmp_path / "out"), "--exact-truth"]
    folder = tmp_path / "truth"
    folder.mkdir()
    assert one_line_error(capsys, [*argv, str(folder)]) == (
        f"hil report: error: --exact-truth = '{folder}' is not allowed: must be a file, not a"
        " folder; give the --exact-truth file in it"
    )
    binary = tmp_path / "truth.csv"
    binary.write_bytes(b"time_s,range_m,closing_speed_mps\n\xa0\x00\x01")
    assert one_line_error(capsys, [*argv, str(binary)]) == (
        f"hil report: error: --exact-truth = '{binary}' is not allowed: must be a UTF-8 text"
        " file; byte 33 is 0xa0, not text: is it the right file?"
    )


@pytest.mark.parametrize("topic", ["TANK-RUN", "Tank-Run.md", "docs/tank-run.md"])
def test_docs_finds_a_topic_in_any_case(topic: str, capsys: pytest.CaptureFixture[str]) -> None:
    # TANK-RUN was refused, without a suggestion.
    assert main(["docs", topic, "--path"]) == 0
    assert Path(capsys.readouterr().out.strip()).name == "tank-run.md"
