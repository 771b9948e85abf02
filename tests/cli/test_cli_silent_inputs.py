"""Inputs that used to be accepted silently are refused in one line naming the option, the
value and the range (exit status 2)."""

from __future__ import annotations

import wave
from pathlib import Path

import pytest

from .conftest import one_line_error


def _wav(path: Path, samples: int, fs: int = 100_000) -> Path:
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(fs)
        w.writeframes(b"\0\0" * samples)
    return path


@pytest.mark.parametrize("samples", [0, 10])
def test_estimate_refuses_an_empty_or_too_short_wav(
    samples: int,
    schedule_and_wav: tuple[Path, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    schedule, _ = schedule_and_wav
    short = _wav(tmp_path / "short.wav", samples)
    capsys.readouterr()
    err = one_line_error(capsys, ["estimate", "--schedule", str(schedule), "--input", str(short)])
    assert err == (
        f"hil estimate: error: --input = '{short}' is not allowed: must be at least one hop of"
        f" signal (0.01 s = 1000 samples at 100000 Hz); it holds {samples} sample"
        f"{'s' * (samples != 1)}; record a longer input"
    )


@pytest.mark.parametrize(
    ("option", "value", "allowed"),
    [
        ("--max-speed", "nan", "a finite speed >= 0 m/s"),
        ("--max-speed", "-1", "a finite speed >= 0 m/s"),
        ("--max-range", "inf", "a finite range > 0 m"),
    ],
)
def test_estimate_refuses_a_speed_or_range_that_is_not_a_finite_number_in_range(
    option: str,
    value: str,
    allowed: str,
    schedule_and_wav: tuple[Path, Path],
    capsys: pytest.CaptureFixture[str],
) -> None:
    schedule, wav = schedule_and_wav
    capsys.readouterr()
    argv = ["estimate", "--schedule", str(schedule), "--input", str(wav), option, value]
    err = one_line_error(capsys, argv)
    assert err == (
        f"hil estimate: error: {option} = {float(value)!r} is not allowed: must be {allowed};"
        " give a number such as the default"
    )


def test_stage_refuses_an_empty_url_from_the_option_or_the_environment(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    allowed = "a stage URL such as sim://stage, /dev/ttyUSB0 or serial:///dev/ttyACM0"
    assert one_line_error(capsys, ["stage", "status", "--url", ""]) == (
        f"hil stage: error: --url = '' is not allowed: must be {allowed}; give the stage's"
        " URL, or leave --url out for sim://stage"
    )
    monkeypatch.setenv("HIL_STAGE_URL", " ")
    assert one_line_error(capsys, ["stage", "status"]) == (
        f"hil stage: error: HIL_STAGE_URL = ' ' is not allowed: must be {allowed}; set it to"
        " the stage's URL, or unset it for sim://stage"
    )


@pytest.mark.parametrize("blocksize", ["0", "-5"])
def test_calibrate_refuses_a_block_size_below_one_frame(
    blocksize: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["calibrate", "latency", "--blocksize", blocksize, "--store", str(tmp_path)]
    assert one_line_error(capsys, argv) == (
        f"hil calibrate: error: --blocksize = {blocksize} is not allowed: must be an integer"
        " >= 1 frames; e.g. 256"
    )
    assert not any(tmp_path.iterdir())  # refused before anything ran or was stored
