"""``hil waveform``: files, their agreement, diagnostics and bad input (exit status 2)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.io import wavfile

import hil.cli.waveform as waveform_cli
from hil.cli.main import main
from hil.signals.schedule_file import read_schedule_file

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _hop_samples(doc: dict, fs: float, n_total: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """For every hop of the file: its sample indices and the file formula's values.

    The documented rule: sample n belongs to the hop whose start_s <= n/fs < start_s +
    duration_s, boundaries compared with a tolerance of 1e-11 s (BOUNDARY_SNAP_S).
    """
    out = []
    tol = 1e-11
    for h in doc["hops"]:
        first = int(np.ceil((h["start_s"] - tol) * fs))
        end = int(np.ceil((h["start_s"] + h["duration_s"] - tol) * fs))
        n = np.arange(max(first, 0), min(end, n_total))
        t = n / fs - h["start_s"]
        val = (
            doc["amplitude"]
            * h["amplitude"]
            * np.cos(
                h["phase_rad"] + 2 * np.pi * (h["freq_hz"] * t + 0.5 * h["chirp_hz_per_s"] * t * t)
            )
        )
        out.append((n, val))
    return out


@pytest.mark.parametrize(
    ("family", "preset"),
    [
        ("random-cyclic", "att"),
        ("three-state", "att"),
        ("fmcw-tri", "tank-audio"),
        ("costas-lfm", "att"),
        ("lfm-pulse", "att"),
    ],
)
def test_wav_matches_schedule_file(tmp_path: Path, family: str, preset: str) -> None:
    wav, js = tmp_path / "x.wav", tmp_path / "x.json"
    status = main(
        [
            "waveform",
            "--preset",
            preset,
            "--family",
            family,
            "--duration",
            "0.5",
            "--out",
            str(wav),
            "--schedule",
            str(js),
        ]
    )
    assert status == 0
    fs, x = wavfile.read(wav)
    doc = json.loads(js.read_text())
    assert x.dtype == np.float32
    assert fs == int(doc["fs"])
    assert x.shape == (int(round(0.5 * doc["fs"])),)
    for key in ("fs", "family", "tones_hz", "code", "period_hops", "hops"):
        assert key in doc
    covered = np.zeros(x.shape[0], dtype=bool)
    for n, val in _hop_samples(doc, doc["fs"], x.shape[0]):
        np.testing.assert_allclose(x[n], val, atol=2e-7)
        covered[n] = True
    assert covered.all()  # the hops tile the WAV
    # The period definition rebuilds the same endless schedule.
    sch, _ = read_schedule_file(js)
    np.testing.assert_allclose(x, 0.9 * sch.evaluate(np.arange(x.shape[0]) / fs), atol=2e-7)


def test_issue_example_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = [
        "waveform",
        "--preset",
        "att",
        "--family",
        "random-cyclic",
        "--duration",
        "2",
        "--fs",
        "100000",
        "--out",
        str(tmp_path / "x.wav"),
        "--schedule",
        str(tmp_path / "x.json"),
        "--json",
    ]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["samples"] == 200_000
    assert summary["period_hops"] == 17
    assert summary["df_times_hop"] == pytest.approx(11.0)
    doc = json.loads((tmp_path / "x.json").read_text())
    assert len(doc["hops"]) == 200  # 2 s of 10 ms hops
    assert doc["code"] == summary_code(doc)


def summary_code(doc: dict) -> list[int]:
    return [h["tone_index"] for h in doc["hops"][: doc["period_hops"]]]


def test_long_wav_streams_in_blocks(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Force the streaming writer with a small block and compare to the one-shot writer.
    monkeypatch.setattr(waveform_cli, "_WRITE_BLOCK", 4096)
    assert main(["waveform", "--duration", "0.3", "--out", str(tmp_path / "s.wav")]) == 0
    monkeypatch.setattr(waveform_cli, "_WRITE_BLOCK", 1 << 20)
    assert main(["waveform", "--duration", "0.3", "--out", str(tmp_path / "o.wav")]) == 0
    fs1, a = wavfile.read(tmp_path / "s.wav")
    fs2, b = wavfile.read(tmp_path / "o.wav")
    assert fs1 == fs2 == 100_000 and a.dtype == np.float32
    np.testing.assert_array_equal(a, b)


@pytest.mark.slow
def test_plots_are_written(tmp_path: Path) -> None:
    out = tmp_path / "diag"
    assert main(["waveform", "--duration", "0.4", "--plot", str(out)]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "af_narrowband.png",
        "af_periodic.png",
        "af_wideband.png",
        "occupancy.png",
        "spectrogram.png",
    ]
    for p in out.iterdir():
        data = p.read_bytes()
        assert data.startswith(PNG_SIGNATURE) and len(data) > 10_000


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--family", "three-state", "--tones", "2"],
            "--tones (n_tones) = 2 is not allowed: must be exactly 3",
        ),
        (["--tones", "4", "--window", "2"], "only 12 distinct windows exist"),
        (["--fs", "50000"], "--fs (fs_hz) = 50000.0 is not allowed"),
        (["--fs", "50000"], "Nyquist"),
        (["--duration", "-1"], "--duration = -1.0 is not allowed: must be > 0 s"),
        (["--hop", "-0.01"], "--hop (hop_s) = -0.01 is not allowed: must be > 0 s"),
        (
            ["--preset", "pool"],
            "--preset (preset) = 'pool' is not allowed: must be one of att, tank-audio, tank-board",
        ),
        (["--family", "sonar"], "--family (family) = 'sonar' is not allowed"),
        (["--family", "three-state", "--order", "3"], "unambiguous range"),
        (["--amplitude", "2"], "--amplitude = 2.0 is not allowed: must be in (0, 1]"),
    ],
)
def test_bad_input_exits_2_with_one_clear_line(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["waveform", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_output_folders_are_created_or_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "new" / "deeper" / "x.wav"
    assert main(["waveform", "--duration", "0.05", "--out", str(out)]) == 0
    assert out.exists()
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    assert main(["waveform", "--duration", "0.05", "--out", str(blocker / "x.wav")]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"hil waveform: error: --out (its folder) = '{blocker}' is not allowed: must be a"
        " folder; it is a file: choose a folder\n"
    )


def test_console_script_exit_code(tmp_path: Path) -> None:
    # The installed entry point, as a user runs it: one line on stderr, status 2.
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "hil.cli.main",
            "waveform",
            "--family",
            "three-state",
            "--tones",
            "2",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2
    assert proc.stderr.startswith("hil waveform: error: --tones (n_tones) = 2")
    proc = subprocess.run(
        [sys.executable, "-m", "hil.cli.main", "waveform", "--bogus"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2 and "unrecognized arguments: --bogus" in proc.stderr


def test_schedule_file_errors(tmp_path: Path) -> None:
    from hil.errors import ConfigError

    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ConfigError, match="valid JSON"):
        read_schedule_file(bad)
    bad.write_text('{"format": "other"}')
    with pytest.raises(ConfigError, match="hil waveform --schedule"):
        read_schedule_file(bad)
    with pytest.raises(ConfigError, match="an existing schedule JSON file"):
        read_schedule_file(tmp_path / "missing.json")
