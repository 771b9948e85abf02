"""--log-level and --log-file: the command's warnings go to stderr and the file at the chosen
level; bad values are usage errors."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from scipy.io import wavfile

from hil.cli.main import main


@pytest.fixture(scope="module")
def clipped(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A clipped int16 WAV of the att waveform (warned about) and its schedule."""
    out = tmp_path_factory.mktemp("clip")
    wav, schedule = out / "x.wav", out / "x.json"
    assert main(["waveform", "--duration", "0.5", "--out", str(wav),
                 "--schedule", str(schedule)]) == 0  # fmt: skip
    fs, x = wavfile.read(wav)
    wavfile.write(wav, fs, np.round(np.clip(x * 2.0, -1, 1) * 32767).astype(np.int16))
    return wav, schedule


def test_warning_goes_to_stderr_and_the_log_file(
    clipped: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    wav, schedule = clipped
    log = tmp_path / "hil.log"
    argv = ["--log-file", str(log), "estimate", "--input", str(wav), "--schedule", str(schedule)]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert f"hil: WARNING: {wav} is clipped: " in err
    (line,) = log.read_text().splitlines()
    assert f"WARNING hil.cli.estimate: {wav} is clipped: " in line


def test_level_error_silences_warnings(
    clipped: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    wav, schedule = clipped
    log = tmp_path / "hil.log"
    argv = ["--log-level", "ERROR", "--log-file", str(log),
            "estimate", "--input", str(wav), "--schedule", str(schedule)]  # fmt: skip
    assert main(argv) == 0
    assert "WARNING" not in capsys.readouterr().err
    assert log.read_text() == ""
    assert not [h for h in logging.getLogger("hil").handlers if h.level]  # closed at the end


def test_bad_log_options_are_usage_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["--log-level", "loud", "devices"])
    assert stop.value.code == 2
    assert "argument --log-level: invalid choice: 'loud'" in capsys.readouterr().err
    missing = tmp_path / "no" / "such" / "hil.log"
    assert main(["--log-file", str(missing), "devices", "serial"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"hil devices: error: No such file or directory: {missing}"
    )
