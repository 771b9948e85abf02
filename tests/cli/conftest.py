"""Shared by the CLI's bad-input tests: one refused command's line, a short transmit, and a
recording without samples."""

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


def empty_recording(path: Path, receiver: str = "gcas", **settings: object) -> Path:
    """A run recording at ``path`` that holds no samples: the ATT random-cyclic schedule at
    100 kHz and a live ``receiver`` with ``m_hops`` 10, ``max_speed_mps`` 30 and
    ``settings``."""
    from hil.recording.records import ReceiverSetup
    from hil.recording.writer import RunWriter
    from hil.signals.presets import check_design, get_preset
    from hil.signals.schedule_file import schedule_document

    doc = schedule_document(
        check_design(get_preset("att").spec("random-cyclic")), 100e3, 0.0, sound_speed_mps=1500.0
    )
    setup = ReceiverSetup(receiver, {"m_hops": 10, "max_speed_mps": 30.0, **settings})
    with RunWriter.create(
        path, fs_hz=100e3, n_channels=1, dtype="int16", schedule_document=doc, receiver=setup
    ):
        pass
    return path
