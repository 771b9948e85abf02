"""``hil estimate``: estimates from a WAV, CSV/JSON output, the map, and bad input."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.io import wavfile

from hil.cli.main import main
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule_file import schedule_document, write_schedule_file
from sim_devices.acoustics.delay import TwoWayPath
from sim_devices.acoustics.echo import AnalyticEcho
from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed

ROOT = Path(__file__).resolve().parents[2]
FS = 100_000.0
R0, V = 40.0, 9.0  # m, m/s closing


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """0.8 s of a closing target's echo plus white noise, as WAV + schedule."""
    folder = tmp_path_factory.mktemp("estimate")
    spec = get_preset("att").spec("random-cyclic")
    sch = check_design(spec)
    sonar = Fixed([0.0, 0.0, 0.0])
    path = TwoWayPath(sonar, ConstantVelocity([R0, 0.0, 0.0], [-V, 0.0, 0.0]), sonar, 1500.0)
    n = int(0.8 * FS)
    x = AnalyticEcho(sch, path, FS).block(0, n)
    x = x + np.random.default_rng(7).normal(0.0, 0.5, n)
    x = 0.5 * x / np.max(np.abs(x))
    wavfile.write(folder / "rx.wav", int(FS), x.astype(np.float32))
    wavfile.write(folder / "stereo.wav", int(FS), np.stack([x, x], axis=1).astype(np.float32))
    wavfile.write(folder / "rx48k.wav", 48_000, x[:48_000].astype(np.float32))
    bad = x.astype(np.float32).copy()
    bad[12_345] = np.nan
    wavfile.write(folder / "nan.wav", int(FS), bad)
    doc = schedule_document(sch, FS, 0.8, sound_speed_mps=1500.0, spec=spec.to_dict())
    write_schedule_file(folder / "x.json", doc)
    return folder


def test_json_lines_track_the_target(recording: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = [
        "estimate",
        "--schedule",
        str(recording / "x.json"),
        "--input",
        str(recording / "rx.wav"),
        "--json",
    ]
    assert main(args) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(rows) >= 40  # 10 ms hops over 0.8 s, after the first M hops
    for row in rows:
        for key in ("t_s", "range_m", "speed_mps", "hop_index", "score"):
            assert key in row
        bounce = (row["t_s"] + row["t_tx_s"]) / 2
        assert row["range_m"] == pytest.approx(R0 - V * bounce, abs=0.1)
        assert row["speed_mps"] == pytest.approx(V, abs=0.3)
    hops = [r["hop_index"] for r in rows]
    assert np.all(np.diff(hops) == 1)
    # One target, every hop: one track, confirmed on its 3rd estimate (3 of 5).
    assert [r["track_id"] for r in rows] == [-1, -1] + [0] * (len(rows) - 2)


def test_json_lines_are_json_dumps_strict_with_nan_as_null(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Each line is strict JSON of the estimate's fields as json.dumps writes it (a
    # non-finite float as null).
    base = ["estimate", "--schedule", str(recording / "x.json"), "--input",
            str(recording / "rx.wav"), "--json"]  # fmt: skip
    assert main(base) == 0
    lines = capsys.readouterr().out.splitlines()
    rows = [json.loads(line) for line in lines]
    assert len(rows) > 10
    for line, row in zip(lines, rows, strict=True):
        assert line == json.dumps(row, allow_nan=False)


def test_plain_listing_counts_and_lists_the_tracks(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["estimate", "--schedule", str(recording / "x.json"), "--input",
            str(recording / "rx.wav")]  # fmt: skip
    assert main([*base, "--json"]) == 0
    out, err = capsys.readouterr()
    rows = [json.loads(line) for line in out.splitlines()]
    on0 = [r for r in rows if r["track_id"] == 0]
    # What GCAS refused instead of reporting: on stderr beside JSON (stdout holds estimates
    # only), after the table without it; here the target's ghosts and Doppler sidelobes,
    # which the every-echo search makes candidates (measured 93 in 0.8 s).
    (refused,) = err.splitlines()
    assert re.fullmatch(
        r"refused: \d+ not one echo of the schedule \(ghosts, sidelobes, noise\)", refused
    )
    assert main(base) == 0
    lines = capsys.readouterr().out.splitlines()[1 + len(rows) :]  # after the table
    assert lines[0] == f"{len(rows)} estimates from {recording / 'rx.wav'} (gcas)"
    assert lines[1].startswith(
        f"track 0: {len(rows) - 2} estimates, t {on0[0]['t_s']:.3f}–{on0[-1]['t_s']:.3f} s, "
        f"range {on0[0]['range_m']:.3f} → {on0[-1]['range_m']:.3f} m, speed 9.0"
    )
    assert lines[2:] == ["2 estimates on no confirmed track", refused]
    # A tracker setting is a receiver option: two of five confirm on the 2nd estimate.
    assert main([*base, "--json", "--option", "track_confirm_hits=2"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["track_id"] for r in rows] == [-1] + [0] * (len(rows) - 1)


def test_json_lines_carry_each_estimates_bound(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["estimate", "--schedule", str(recording / "x.json"), "--input",
            str(recording / "rx.wav"), "--json"]  # fmt: skip
    assert main(base) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    bounds = np.array([r["crlb_range_m"] for r in rows])
    # 0.5-scaled echo at about -3 dB per-sample SNR: bounds of about a millimetre.
    assert len(rows) >= 40 and np.all((bounds > 1e-4) & (bounds < 5e-3))
    assert all(0 < r["crlb_speed_mps"] < 0.01 for r in rows)
    assert main([*base, "--option", "refine=false"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert rows and all(r["crlb_range_m"] is None and r["crlb_speed_mps"] is None for r in rows)


@pytest.mark.slow
def test_csv_output_and_map(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "est.csv"
    png = tmp_path / "map.png"
    args = [
        "estimate",
        "--schedule",
        str(recording / "x.json"),
        "--input",
        str(recording / "rx.wav"),
        "--csv",
        str(out),
        "--map",
        str(png),
    ]
    assert main(args) == 0
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) >= 40 and float(rows[5]["speed_mps"]) == pytest.approx(V, abs=0.3)
    assert [r["track_id"] for r in rows[:3]] == ["-1", "-1", "0"]
    assert png.read_bytes().startswith(b"\x89PNG")


def test_stereo_input_needs_a_channel(recording: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = [
        "estimate",
        "--schedule",
        str(recording / "x.json"),
        "--input",
        str(recording / "stereo.wav"),
    ]
    assert main(base) == 2
    assert (
        "--channel = None is not allowed: must be one of 0..1: the input has 2 channels"
        in capsys.readouterr().err
    )
    assert main([*base, "--channel", "5"]) == 2
    assert "--channel = 5" in capsys.readouterr().err
    assert main([*base, "--channel", "1", "--json"]) == 0
    assert len(capsys.readouterr().out.splitlines()) >= 40


@pytest.mark.parametrize(
    ("wav", "extra", "message"),
    [
        ("rx48k.wav", [], "the schedule's sample rate 100000 Hz"),
        ("nan.wav", [], "sample 12345 (t = 0.123450 s) is nan"),
        ("rx.wav", ["--M", "200"], "--m-hops (m_hops) = 200 is not allowed"),
        ("rx.wav", ["--receiver", "sonar9000"], "--receiver (receiver) = 'sonar9000'"),
        ("missing.wav", [], "an existing WAV file"),
        ("rx.wav", ["--option", "novalue"], "KEY=VALUE"),
        (
            "rx.wav",
            ["--option", "track_confirm_hits=0"],
            "track_confirm_hits = 0 is not allowed: must be an integer >= 1; "
            "e.g. track_confirm_hits=3",
        ),
        (
            "rx.wav",
            ["--option", "track_gate=3"],
            "track_gate = 3 is not allowed: must be a tracker setting: track_accel_mps2, ",
        ),
    ],
)
def test_bad_input_exits_2(
    recording: Path, wav: str, extra: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    args = [
        "estimate",
        "--schedule",
        str(recording / "x.json"),
        "--input",
        str(recording / wav),
        *extra,
    ]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert "Traceback" not in err


def test_the_tracks_doc_listing_runs_as_written(
    recording: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    text = (ROOT / "docs" / "tracks.md").read_text(encoding="utf-8")
    block = text.split("```\n$ ", 1)[1].split("```", 1)[0].splitlines()
    command, expected = block[0].split(), block[1:]
    assert command[0] == "hil"
    monkeypatch.chdir(recording)
    assert main(command[1:]) == 0
    out = capsys.readouterr().out.splitlines()
    # "…" in the listing stands for the table's rows, one per estimate.
    skip = expected.index("…")
    n_rows = len(out) - len(expected) + 1
    assert out[:skip] == expected[:skip] and out[skip + n_rows :] == expected[skip + 1 :]
    assert n_rows == int(expected[skip + 1].split()[0])


def test_without_json_or_csv_the_estimates_are_printed_as_a_table(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """As the help says: one line per estimate, time, range, speed and SNR, then the count."""
    from hil.cli.estimate import table_header, table_row

    base = ["estimate", "--schedule", str(recording / "x.json"), "--input"]
    assert main([*base, str(recording / "rx.wav"), "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert main([*base, str(recording / "rx.wav")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "     t (s)  range (m)  speed (m/s)  SNR (dB)" == table_header()
    assert lines[1 : 1 + len(rows)] == [
        table_row({k: float("nan") if v is None else v for k, v in r.items()}) for r in rows
    ]
    assert lines[1 + len(rows)] == f"{len(rows)} estimates from {recording / 'rx.wav'} (gcas)"
    _, r, v, _ = (float(x) for x in lines[1].split())
    assert r == pytest.approx(rows[0]["range_m"], abs=5e-4) and v == pytest.approx(V, abs=0.3)


@pytest.fixture(scope="module")
def too_fast(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """0.6 s of a target closing at 35 m/s (faster than the default ±30 m/s span) from 50 m,
    0 dB per-sample SNR, as WAV + schedule."""
    folder = tmp_path_factory.mktemp("too-fast")
    spec = get_preset("att").spec("random-cyclic")
    sch = check_design(spec)
    sonar = Fixed([0.0, 0.0, 0.0])
    path = TwoWayPath(sonar, ConstantVelocity([50.0, 0.0, 0.0], [-35.0, 0.0, 0.0]), sonar, 1500.0)
    n = int(0.6 * FS)
    x = AnalyticEcho(sch, path, FS).block(0, n)
    x = x + np.random.default_rng(4).normal(0.0, np.sqrt(0.5), n)
    wavfile.write(folder / "rx.wav", int(FS), (0.2 * x).astype(np.float32))
    doc = schedule_document(sch, FS, 0.6, sound_speed_mps=1500.0, spec=spec.to_dict())
    write_schedule_file(folder / "x.json", doc)
    return folder


def test_an_echo_beyond_the_span_is_said_once_and_not_estimated(
    too_fast: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["estimate", "--schedule", str(too_fast / "x.json"), "--input",
            str(too_fast / "rx.wav")]  # fmt: skip
    assert main([*base, "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    notices = [r for r in rows if "notice" in r]
    # Said once, on the closing side, at one of the first boundaries after M hops; the fit
    # beyond the span found the echo's speed (a measurement for the notice, not reported).
    assert len(notices) == 1
    seen = notices[0]
    assert seen["notice"] == "beyond_span" and seen["side"] == "closing"
    assert seen["max_speed_mps"] == 30.0 and seen["hop_index"] <= 12
    assert seen["speed_mps"] == pytest.approx(35.0, abs=0.5)
    estimates = [r for r in rows if "notice" not in r]
    # No estimate of it: at most 0.05 wrong per hop over 60 hops (measured: none).
    assert len(estimates) <= 3
    assert main(base) == 0
    out = capsys.readouterr().out
    notes = [line for line in out.splitlines() if line.startswith("note: ")]
    assert notes == [
        "note: an echo beyond the ±30 m/s Doppler span was seen (closing) at "
        f"t = {seen['t_s']:.4f} s (hop {seen['hop_index']}); it is refused, not reported: "
        "raise --max-speed to measure it"
    ]


@pytest.fixture(scope="module")
def near_water(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """2 s of a target at rest at 40 m (0 dB) in dense volume reverberation from 1 m
    (0.3 scatterers per m³, 0 dB SRR), as WAV + schedule."""
    from tests.estimation_gcas.test_scenes import MOTION_S, _motion_input

    folder = tmp_path_factory.mktemp("near-water")
    spec = get_preset("att").spec("random-cyclic")
    x, _ = _motion_input("still", 0.0, 0.0, 4, min_range_m=1.0, density_per_m3=0.3)
    wavfile.write(folder / "rx.wav", int(FS), (0.5 * x / np.max(np.abs(x))).astype(np.float32))
    doc = schedule_document(check_design(spec), FS, MOTION_S, sound_speed_mps=1500.0,
                            spec=spec.to_dict())  # fmt: skip
    write_schedule_file(folder / "x.json", doc)
    return folder


@pytest.mark.slow
def test_clutter_is_labelled_as_clutter_and_not_reported(
    near_water: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The band off (a still target): the near water's diffuse reverberation is refused as
    # clutter and said, a notice per range more than 1 m from those said before; no estimate
    # there. Measured: notices at 2.63 and 1.14 m, 43 clutter refusals, no estimate nearer
    # than 5 m.
    base = ["estimate", "--schedule", str(near_water / "x.json"), "--input",
            str(near_water / "rx.wav"), "--max-speed", "30", "--max-range", "100",
            "--option", "reverb_speed_mps=0"]  # fmt: skip
    assert main([*base, "--json"]) == 0
    captured = capsys.readouterr()
    rows = [json.loads(line) for line in captured.out.splitlines()]
    clutter = [r for r in rows if r.get("notice") == "clutter"]
    estimates = [r for r in rows if "notice" not in r]
    assert 2 <= len(clutter) <= 8
    assert all(1.0 <= r["range_m"] <= 6.0 for r in clutter)
    ranges = sorted(r["range_m"] for r in clutter)
    assert min(np.diff(ranges)) > 1.0
    assert not [e for e in estimates if e["range_m"] < 5.0]
    assert any(abs(e["range_m"] - 40.0) < 0.5 for e in estimates)
    counted = re.search(r"(\d+) diffuse reverberation \(clutter\)", captured.err)
    assert counted is not None and int(counted.group(1)) >= len(clutter)
    assert main(base) == 0
    notes = [line for line in capsys.readouterr().out.splitlines() if line.startswith("note: ")]
    assert notes == [
        f"note: diffuse reverberation (clutter) at {r['range_m']:.2f} m at t = {r['t_s']:.4f} s "
        f"(hop {r['hop_index']}): counted as clutter, not reported as a target"
        for r in clutter
    ]


def _write_24_bit(path: Path, x: np.ndarray, fs: int) -> None:
    """A mono 24-bit PCM WAV (a format scipy.io.wavfile cannot write) of ``x`` in [-1, 1]."""
    q = np.clip(np.round(x * 2**23), -(2**23), 2**23 - 1).astype("<i4")
    stored = q.view(np.uint8).reshape(-1, 4)[:, :3].tobytes()
    fmt = b"fmt " + (16).to_bytes(4, "little") + np.array(
        [1, 1], dtype="<u2").tobytes() + np.array([fs, 3 * fs], dtype="<u4").tobytes() + np.array(
        [3, 24], dtype="<u2").tobytes()  # fmt: skip
    data = b"data" + len(stored).to_bytes(4, "little") + stored
    body = b"WAVE" + fmt + data
    path.write_bytes(b"RIFF" + len(body).to_bytes(4, "little") + body)


def test_a_24_bit_input_gives_the_float_inputs_estimates_and_its_clipping_is_warned(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """24-bit samples are read (scaled by 2**-23, left-justified as scipy reads them), and a
    sample at either full scale (+0x7fffff, -0x7fffff or -0x800000) counts as clipped."""
    _, x = wavfile.read(recording / "rx.wav")
    y = x.astype(np.float64)
    y[[1000, 2000, 3000]] = [1.0, -1.0, -2.0]  # stored as +0x7fffff, -0x800000, -0x800000
    y[4000] = -(2**23 - 1) / 2**23
    _write_24_bit(tmp_path / "rx24.wav", y, int(FS))
    base = ["estimate", "--schedule", str(recording / "x.json"), "--json", "--input"]
    assert main([*base, str(recording / "rx.wav")]) == 0
    floats = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert main([*base, str(tmp_path / "rx24.wav")]) == 0
    out, err = capsys.readouterr()
    ints = [json.loads(line) for line in out.splitlines()]
    assert [r["hop_index"] for r in ints] == [r["hop_index"] for r in floats]
    # 24-bit quantisation (6e-8 of full scale) moves a range by far less than a millimetre.
    assert max(abs(a["range_m"] - b["range_m"]) for a, b in zip(ints, floats, strict=True)) < 1e-3
    assert f"{tmp_path / 'rx24.wav'} is clipped: 4 samples at the integer format's full " in err
    assert "the first at t = 0.010000 s" in err


@pytest.mark.slow
def test_estimate_imports_no_module_it_does_not_use(recording: Path) -> None:
    """The start-up of hil estimate (issue 27): no HDF5 library where no HDF5 is written, no
    matplotlib without --map, no scipy at all (not scipy.io for the WAV, scipy.signal for the
    filters, scipy.special for the CFAR threshold, scipy.linalg for numba's BLAS check nor
    scipy's base for numba's version check), no cffi nor yaml for numba, no simulator
    (checked in a fresh interpreter)."""
    import subprocess
    import sys

    code = (
        "import json, sys\n"
        "from hil.cli.main import main\n"
        f"status = main(['estimate', '--schedule', {str(recording / 'x.json')!r}, "
        f"'--input', {str(recording / 'rx.wav')!r}, '--json'])\n"
        "sys.stdout = sys.__stdout__\n"
        "print(json.dumps([status, sorted(sys.modules)]))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, check=True)  # fmt: skip
    status, modules = json.loads(proc.stdout.splitlines()[-1])
    assert status == 0 and "hil.estimation.gcas.receiver" in modules
    loaded = set(modules)
    avoided = {"h5py", "matplotlib", "scipy", "cffi", "pycparser", "yaml", "sim_devices"}
    assert sorted(m for m in loaded if m.split(".")[0] in avoided) == []


@pytest.mark.slow
def test_a_target_10_db_weaker_at_the_same_speed_is_found_unless_cancel_is_off(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # As the docs say: GCAS searches again with the echoes it measured taken out, and
    # `--option cancel=false` searches once. 50 m and 30 m closing at 9 m/s, the second
    # 10 dB weaker, 1 s at 0 dB per-sample SNR on the first. Measured: 90 estimates of each
    # with it (within 0.3 m and 0.3 m/s), 90 and 0 without.
    spec = get_preset("att").spec("random-cyclic")
    sch = check_design(spec)
    sonar = Fixed([0.0, 0.0, 0.0])
    n = int(1.0 * FS)
    x = np.zeros(n)
    for r0, amp in ((50.0, 1.0), (30.0, 10 ** (-10 / 20))):
        path = TwoWayPath(sonar, ConstantVelocity([r0, 0.0, 0.0], [-V, 0.0, 0.0]), sonar, 1500.0)
        x += AnalyticEcho(sch, path, FS, amplitude=amp).block(0, n)
    x += np.random.default_rng(8).normal(0.0, np.sqrt(0.5), n)
    wavfile.write(tmp_path / "rx.wav", int(FS), (0.2 * x / np.max(np.abs(x))).astype(np.float32))
    write_schedule_file(
        tmp_path / "x.json",
        schedule_document(sch, FS, 1.0, sound_speed_mps=1500.0, spec=spec.to_dict()),
    )
    base = ["estimate", "--schedule", str(tmp_path / "x.json"), "--input",
            str(tmp_path / "rx.wav"), "--json"]  # fmt: skip

    def counts(*extra: str) -> tuple[int, int]:
        assert main([*base, *extra]) == 0
        rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
        rows = [r for r in rows if "notice" not in r]

        def near(r0: float) -> int:
            return sum(
                abs(r["range_m"] - (r0 - V * r["t_s"])) < 0.3 and abs(r["speed_mps"] - V) < 0.3
                for r in rows
            )

        return near(50.0), near(30.0)

    strong, weak = counts()
    assert strong >= 80 and weak >= 75
    strong_once, weak_once = counts("--option", "cancel=false")
    assert strong_once >= 80 and weak_once <= 5


def test_gcas_still_estimates_from_the_command_line(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # No still water here: gcas-still reads the lone target as gcas does; the background is
    # subtracted from 0.68 s (4 code periods) on.
    args = ["estimate", "--schedule", str(recording / "x.json"), "--input",
            str(recording / "rx.wav"), "--receiver", "gcas-still", "--json"]  # fmt: skip
    assert main(args) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(rows) >= 40
    for row in rows:
        bounce = (row["t_s"] + row["t_tx_s"]) / 2
        assert row["range_m"] == pytest.approx(R0 - V * bounce, abs=0.1)
        assert row["speed_mps"] == pytest.approx(V, abs=0.3)
    assert main([*args[:-1], "--option", "still_periods=0"]) == 2
    assert "still_periods = 0" in capsys.readouterr().err
