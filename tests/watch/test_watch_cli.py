"""``hil watch`` on the command line: help, and one-line errors (exit 2) for bad files."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.cli.main import main


def test_help_says_defaults_and_units(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["watch", "--help"])
    assert stop.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "usage: hil watch [-h] [--port PORT] [--host HOST] [--open] RUN" in text
    assert "0 picks a free one (default: 0)" in text
    assert "(default: 127.0.0.1)" in text
    assert "(m, m/s vs receive time in s)" in text
    assert "polls every 0.5 s" in text


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (
            None,
            "hil watch: error: RUN (recording) = '{p}' is not allowed: must be an existing "
            "run recording (.h5)",
        ),
        (
            b"\x00\xffgarbage" * 100,
            "hil watch: error: RUN (recording) = '{p}' is not allowed: must be an HDF5 run "
            "recording written by hil; it is not readable as HDF5",
        ),
    ],
    ids=["missing", "garbage"],
)
def test_bad_recordings_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes | None, message: str
) -> None:
    path = tmp_path / "run.h5"
    if content is not None:
        path.write_bytes(content)
    assert main(["watch", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(message.format(p=path))


def test_a_port_out_of_range(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["watch", str(tmp_path / "run.h5"), "--port", "70000"]) == 2
    assert capsys.readouterr().err == (
        "hil watch: error: --port (port) = 70000 is not allowed: must be 0..65535 "
        "(0: a free port)\n"
    )


def test_a_damaged_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import h5py

    path = tmp_path / "run.h5"
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "cas-hil-run"
        f.attrs["format_version"] = 2
    assert main(["watch", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(
        f"hil watch: error: RUN (recording) = {str(path)!r} is not allowed: must be a readable "
        "hil run recording; it is damaged or incomplete ("
    )
