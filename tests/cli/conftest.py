"""Shared by the CLI's bad-input tests: one refused command's line, and a short transmit."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.cli.main import main


def one_line_error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    """Run ``hil ARGV``; assert exit status 2 and one line on stderr, no traceback; return
    that line."""
    status = main(argv)
    err = capsys.readouterr().err
    assert status == 2, err
    assert "Traceback" not in err and err.count("\n") == 1, err
    return err.rstrip("\n")


@pytest.fixture
def schedule_and_wav(tmp_path: Path) -> tuple[Path, Path]:
    """A 50 ms transmit of ``att``'s default waveform: its schedule file and its WAV."""
    wav, schedule = tmp_path / "tx.wav", tmp_path / "tx.json"
    argv = ["waveform", "--duration", "0.05", "--out", str(wav), "--schedule", str(schedule)]
    assert main(argv) == 0
    return schedule, wav
