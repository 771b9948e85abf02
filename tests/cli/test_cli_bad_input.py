"""Every bad input of issue 22 is refused with one line naming the field, the value and the
fix (exit status 2, no traceback), or warned about in one line when the run can go on."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.io import wavfile

from hil.cli.main import main
from hil.experiments.experiment import DEFAULT_EXPERIMENT

from .conftest import one_line_error

GARBAGE = bytes(np.random.default_rng(22).integers(0, 256, 3000, dtype=np.uint8))


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated att recording (2 s) with its schedule, plus a schedule of another seed."""
    out = tmp_path_factory.mktemp("sim")
    assert main(["simulate", "att", "--out", str(out), "--duration", "2", "--quiet"]) == 0
    assert main(["waveform", "--preset", "att", "--seed", "2", "--duration", "1",
                 "--schedule", str(out / "other-seed.json")]) == 0  # fmt: skip
    fs, x = wavfile.read(out / "received.wav")
    wavfile.write(out / "received0.wav", fs, x[:, 0])
    return out


@pytest.mark.parametrize(
    ("argv", "what"),
    [
        (["tank-run", "{f}"], "experiment"),
        (["simulate", "{f}", "--out", "{d}"], "scenario"),
        (["sweep", "{f}", "--out", "{d}"], "sweep"),
    ],
)
def test_binary_garbage_as_a_toml_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], what: str
) -> None:
    path = tmp_path / "garbage.toml"
    path.write_bytes(GARBAGE)
    line = one_line_error(capsys, [a.format(f=path, d=tmp_path / "o") for a in argv])
    assert f"{what} = '{path}' is not allowed: must be a UTF-8 text file; byte " in line
    assert "not text: is it the right file?" in line


@pytest.mark.slow
def test_binary_garbage_as_a_schedule(
    sim_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "garbage.json"
    path.write_bytes(GARBAGE)
    line = one_line_error(capsys, ["estimate", "--input", str(sim_run / "received0.wav"),
                           "--schedule", str(path)])  # fmt: skip
    assert f"schedule = '{path}' is not allowed: must be a UTF-8 text file" in line


def test_schedule_with_text_for_fs(
    sim_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doc = json.loads((sim_run / "schedule.json").read_text())
    doc["fs"] = "fast"
    path = tmp_path / "fast.json"
    path.write_text(json.dumps(doc))
    line = one_line_error(capsys, ["estimate", "--input", str(sim_run / "received0.wav"),
                           "--schedule", str(path)])  # fmt: skip
    assert line == (
        "hil estimate: error: schedule.fs = 'fast' is not allowed: must be a number > 0 (Hz); "
        f"{path} is damaged: write it again with `hil waveform --schedule FILE`"
    )


def test_schedule_with_a_garbage_period(
    sim_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doc = json.loads((sim_run / "schedule.json").read_text())
    doc["period"]["code"] = "garbage"
    path = tmp_path / "period.json"
    path.write_text(json.dumps(doc))
    line = one_line_error(capsys, ["estimate", "--input", str(sim_run / "received0.wav"),
                           "--schedule", str(path)])  # fmt: skip
    assert line.startswith("hil estimate: error: schedule.code = 'garbage' is not allowed")


def test_receiver_option_of_the_wrong_type(
    sim_run: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    wav, schedule = str(sim_run / "received0.wav"), str(sim_run / "schedule.json")
    line = one_line_error(capsys, ["estimate", "--input", wav, "--schedule", schedule,
                           "--option", "n_doppler=abc"])  # fmt: skip
    assert line == (
        "hil estimate: error: receiver.options.n_doppler = 'abc' is not allowed: must be an"
        " integer (a gcas option); e.g. n_doppler=64"
    )


def _experiment(tmp_path: Path, old: str, new: str) -> Path:
    assert old in DEFAULT_EXPERIMENT
    path = tmp_path / "experiment.toml"
    path.write_text(DEFAULT_EXPERIMENT.replace(old, new))
    return path


def test_receiver_option_text_for_a_speed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _experiment(
        tmp_path,
        'options = { background = "simulated" }',
        'options = { background = "simulated", reverb_speed_mps = "fast" }',
    )
    line = one_line_error(capsys, ["tank-run", str(path)])
    assert line == (
        "hil tank-run: error: receiver.options.reverb_speed_mps = 'fast' is not allowed: must "
        "be 'auto' or a speed >= 0 m/s; give a number such as 0.8, 0 to turn the band off, "
        "or 'auto'"
    )


def test_quoted_false_is_not_read_as_true(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _experiment(tmp_path, "reverberation = true", 'reverberation = "false"')
    line = one_line_error(capsys, ["tank-run", str(path)])
    assert line == (
        "hil tank-run: error: simulation.reverberation = 'false' is not allowed: must be true "
        "or false (a TOML boolean, unquoted); write reverberation = false"
    )


def test_quoted_false_in_a_scenario(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "s.toml"
    path.write_text('preset = "att"\nduration_s = 0.1\n[output]\nplots = "false"\n')
    line = one_line_error(capsys, ["simulate", str(path), "--out", str(tmp_path / "o")])
    assert "output.plots = 'false' is not allowed: must be true or false" in line
    assert line.endswith("write plots = false")


def test_misspelt_simulated_device(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _experiment(tmp_path, 'board = "sim://board"', 'board = "sim://bord"')
    line = one_line_error(capsys, ["tank-run", str(path)])
    assert line == (
        "hil tank-run: error: devices.board = 'sim://bord' is not allowed: must be sim://board "
        "(a simulated board); did you mean sim://board?"
    )


def test_wav_over_the_size_limit_is_refused_before_writing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "big.wav"
    line = one_line_error(capsys, ["waveform", "--duration", "100000", "--out", str(out)])
    assert line == (
        "hil waveform: error: --duration = 100000.0 is not allowed: must be a WAV of at most "
        "--max-size 4 GB; 100000 s at 100000 Hz is 40 GB of float32 WAV; shorten --duration "
        "or raise --max-size (above 4 GiB the file is RF64)"
    )
    assert not out.exists()


def test_code_shorter_than_the_window_blames_the_code_length(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = one_line_error(
        capsys, ["waveform", "--code-length", "2", "--out", str(tmp_path / "a.wav")]
    )
    assert line == (
        "hil waveform: error: --code-length (code_length) = 2 is not allowed: must be >= the "
        "window W = 3 (a code holds its windows); lengthen the code to >= 3 or shorten the "
        "window (--window)"
    )


def test_calibration_band_given_high_first(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = one_line_error(capsys, ["calibrate", "response", "--band", "16000", "4000",
                           "--store", str(tmp_path)])  # fmt: skip
    assert line == (
        "hil calibrate: error: --band (band_hz) = '16000 4000' is not allowed: must be LOW "
        "HIGH in Hz with 0 < LOW < HIGH < Nyquist (24000 Hz); give the lower edge first, "
        "e.g. --band 4000 16000"
    )


#: The schedule and clipping checks read the input whatever the receiver: the cheapest one
#: (STFT, about a third of GCAS's CPU on this input) keeps these tests to the checks.
CHEAP_RECEIVER = ["--receiver", "stft"]


def _warnings(capsys: pytest.CaptureFixture[str], argv: list[str]) -> list[str]:
    """The warnings ``hil`` printed for ``argv`` (an ``estimate`` on the cheap receiver)."""
    status = main([*argv, *CHEAP_RECEIVER])
    err = capsys.readouterr().err
    assert status == 0, err
    return [line for line in err.splitlines() if line.startswith("hil: WARNING: ")]


@pytest.mark.slow
def test_schedule_of_another_seed_is_said(
    sim_run: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    wav = sim_run / "received0.wav"
    other = sim_run / "other-seed.json"
    (line,) = _warnings(capsys, ["estimate", "--input", str(wav), "--schedule", str(other)])
    assert f"{wav} does not follow the hop code of {other}" in line
    assert "is the schedule from another seed or run? Estimates would be wrong" in line
    own = sim_run / "schedule.json"
    assert _warnings(capsys, ["estimate", "--input", str(wav), "--schedule", str(own)]) == []


@pytest.mark.slow
def test_clipped_int16_input_is_warned(
    sim_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fs, x = wavfile.read(sim_run / "received0.wav")
    y = np.clip(x / np.abs(x).max() * 1.5, -1.0, 1.0)
    clipped = tmp_path / "clipped.wav"
    wavfile.write(clipped, fs, np.round(y * 32767).astype(np.int16))
    n_clipped = int(np.count_nonzero(np.abs(np.round(y * 32767)) >= 32767))
    (line,) = _warnings(capsys, ["estimate", "--input", str(clipped),
                                 "--schedule", str(sim_run / "schedule.json")])  # fmt: skip
    assert line.startswith(
        f"hil: WARNING: {clipped} is clipped: {n_clipped} samples at the integer format's full "
        "scale, the first at t = "
    )
    assert line.endswith("lower the input gain and record again (estimates there are unreliable)")
    unclipped = tmp_path / "fine.wav"
    wavfile.write(unclipped, fs, np.round(x / np.abs(x).max() * 0.5 * 32767).astype(np.int16))
    assert _warnings(capsys, ["estimate", "--input", str(unclipped),
                              "--schedule", str(sim_run / "schedule.json")]) == []  # fmt: skip
