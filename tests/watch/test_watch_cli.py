"""``hil watch`` on the command line: help, and one-line errors (exit 2) for bad files."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from hil.cli.main import main

ROOT = Path(__file__).resolve().parents[2]


def test_help_says_defaults_and_units(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["watch", "--help"])
    assert stop.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "usage: hil watch [-h] [--port PORT] [--host HOST] [--open] [--map] RUN" in text
    assert "0 picks a free one (default: 0)" in text
    assert "(default: 127.0.0.1)" in text
    assert "(m, m/s vs receive time in s)" in text
    assert "polls every 0.5 s" in text
    assert "about half a core for a tank-audio run, so off by default" in text


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
            "recording written by hil; it does not start with the HDF5 signature (900 bytes)",
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
        f"hil watch: error: RUN (recording) = {str(path)!r} is not allowed: must be a complete "
        "hil run recording; it lacks the attribute fs_hz, "
    )


def _default_sigint() -> None:
    """In the child before exec: SIGINT raises KeyboardInterrupt again, as in a terminal
    (a suite started as a background job hands its children SIGINT ignored, and Python
    keeps an inherited ignore)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.slow
def test_the_command_serves_a_recording_until_interrupted(recorder: Any) -> None:
    recorder.writer.append_estimates([recorder.estimate(i) for i in range(4)])
    recorder.writer.flush()
    # PYTHONFAULTHANDLER: a server that does not stop is asked for its threads' stacks.
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONFAULTHANDLER": "1"}
    cmd = [sys.executable, "-m", "hil.cli.main", "watch", str(recorder.path), "--port", "0"]
    with subprocess.Popen(
        cmd,
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_default_sigint,
    ) as proc:
        try:
            assert proc.stdout is not None and proc.stderr is not None
            line = proc.stdout.readline()
            match = re.fullmatch(
                r"watching (.+) at (http://127\.0\.0\.1:\d+/)  \(Ctrl-C to stop\)\n", line
            )
            assert match is not None, line
            assert match.group(1) == str(recorder.path)
            with urllib.request.urlopen(match.group(2) + "api/state", timeout=60) as r:
                assert json.loads(r.read())["counts"]["estimates"] == 4
            proc.send_signal(signal.SIGINT)
            try:
                code = proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.send_signal(signal.SIGABRT)  # the fault handler prints every stack
                _, err = proc.communicate(timeout=30)
                pytest.fail(f"hil watch still ran 60 s after SIGINT; its threads:\n{err}")
            assert code == 0
            assert proc.stderr.read() == "stopped\n"
        finally:
            if proc.poll() is None:
                proc.kill()
