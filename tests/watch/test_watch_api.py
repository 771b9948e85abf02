"""The watch page's JSON, against recordings made with the recording writer: a finished one
and one still being written (its writer flushes between the reads)."""

from __future__ import annotations

import json
import math
import urllib.error
import urllib.request
from dataclasses import replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from hil.errors import ConfigError
from hil.recording.records import RunEvent, StageTelemetry
from hil.recording.writer import RunWriter
from hil.watch import WatchData, WatchServer
from hil.watch.server import page_html

FS = 100_000.0
ORIGIN = 1000


def _fill(rec: Any) -> None:
    """2 s of samples with a 100-sample gap (the writer records its event), 5 stage reports
    (the carriage at -2 m moving toward -x at 1.5 m/s: the target approaches), 5 estimates,
    a note and an alarm."""
    assert (rec.fs, rec.origin) == (FS, ORIGIN)
    writer, estimate = rec.writer, rec.estimate
    writer.append_samples(ORIGIN, np.zeros(100_000, np.int16))
    writer.append_samples(ORIGIN + 100_100, np.zeros(99_900, np.int16))
    for k in range(5):
        x = -2.0 - 0.3 * k
        writer.append_telemetry(StageTelemetry(0.2 * k, ORIGIN + 20_000 * k, x, -1.5, "Run"))
    writer.append_estimates([estimate(i) for i in range(5)])
    writer.append_event(RunEvent("note", ORIGIN, 0, "loopback latency 64 samples"))
    writer.append_event(RunEvent("alarm", ORIGIN + 150_000, 0, "watchdog: host silent"))
    writer.flush()


def test_state_of_a_recording(recorder: Any) -> None:
    _fill(recorder)
    data = WatchData.open(recorder.path)
    try:
        s = data.state()
    finally:
        data.close()
    assert s["file"] == "run.h5"
    assert s["experiment"] == "sim-towed-pass"
    assert s["receiver"] == "gcas"
    assert s["fs_hz"] == FS and s["n_codewords"] == 17
    assert s["board"] == {
        "samples": 199_900,
        "recorded_s": 1.999,
        "end_t_s": 2.0,
        "gaps": 1,
        "missing_samples": 100,
    }
    assert s["stage"] == {
        "state": "Run",
        "position_m": pytest.approx(-3.2),
        "velocity_mps": -1.5,
        "t_s": 0.8,
        "reports": 5,
    }
    assert [(e["kind"], e["severity"], e["t_s"], e["length"]) for e in s["events"]] == [
        ("gap", "warning", 1.0, 100),
        ("note", "note", 0.0, 0),
        ("alarm", "alarm", 1.5, 0),
    ]
    assert s["events"][0]["text"] == "samples 101000 .. 101099 missing"
    assert s["events"][2]["text"] == "watchdog: host silent"
    assert s["counts"] == {
        "estimates": 5,
        "events": 3,
        "alarms": 1,
        "warnings": 1,
        "notes": 1,
        "telemetry": 5,
    }
    json.dumps(s, allow_nan=False)


def test_truth_from_telemetry_and_the_recorded_geometry(recorder: Any) -> None:
    _fill(recorder)
    with_data = WatchData.open(recorder.path)
    try:
        t = with_data.truth()
    finally:
        with_data.close()
    # Target at stage_origin (11, 2, -1.2) + x; transducer at (0.5, 2, -1.2): range 10.5 + x.
    assert t["available"] is True
    assert t["t_s"] == pytest.approx([0.0, 0.2, 0.4, 0.6, 0.8])
    assert t["range_m"] == pytest.approx([8.5, 8.2, 7.9, 7.6, 7.3])
    assert t["speed_mps"] == pytest.approx([1.5] * 5)


def test_truth_boundaries_arrive_two_ranges_late(recorder: Any) -> None:
    # A standing carriage: every boundary (hop end T) arrives at T + 2R/c with R = 8.5 m.
    recorder.writer.append_telemetry(StageTelemetry(0.0, ORIGIN, -2.0, 0.0, "Idle"))
    recorder.writer.append_telemetry(StageTelemetry(1.0, ORIGIN + 100_000, -2.0, 0.0, "Idle"))
    recorder.writer.flush()
    data = WatchData.open(recorder.path)
    try:
        m = data.codeword_map()
        c = data.sound_speed_mps
    finally:
        data.close()
    assert 1400 < c < 1550
    assert m["map"] is None and m["png"] is None and m["n_codewords"] == 17
    # Hops of 10 ms from t = 0 within [0, 1] s: ends at 10 ms .. 1 s (the last one inside).
    t_end = 0.01 * np.arange(1, 101)
    assert m["boundary_t_s"] == pytest.approx(t_end + 2 * 8.5 / c)
    assert m["boundary_codeword"] == list(np.arange(0, 100) % 17)


def test_no_truth_without_an_experiment_file(tmp_path: Path, recorder: Any) -> None:
    from hil.recording.reader import RunRecording

    with RunRecording.open(recorder.path) as rec:
        doc = rec.schedule_document()
    path = tmp_path / "bare.h5"
    with RunWriter.create(path, fs_hz=FS, n_channels=1, dtype="int16", schedule_document=doc):
        pass
    data = WatchData.open(path)
    try:
        assert data.truth() == {
            "available": False,
            "reason": "the recording holds no experiment file (no tank geometry)",
            "t_s": [],
            "range_m": [],
            "speed_mps": [],
        }
        assert data.state()["stage"] is None
    finally:
        data.close()


def test_estimates_since_while_the_recording_grows(recorder: Any) -> None:
    recorder.writer.append_estimates([recorder.estimate(i) for i in range(3)])
    recorder.writer.flush()
    data = WatchData.open(recorder.path)
    try:
        first = data.estimates(0)
        assert first["total"] == 3 and first["since"] == 0
        assert first["t_s"] == pytest.approx([0.5, 0.51, 0.52])
        assert first["codeword"] == [0, 1, 2]
        # Appended but not flushed: not visible yet.
        recorder.writer.append_estimates(
            [recorder.estimate(3), recorder.estimate(4, range_m=math.nan)]
        )
        assert data.estimates(3)["total"] == 3
        recorder.writer.flush()
        more = data.estimates(3)
        assert more["total"] == 5 and more["since"] == 3
        assert more["t_s"] == pytest.approx([0.53, 0.54])
        assert more["range_m"] == [8.5, None]  # NaN as JSON null
        assert data.estimates(5)["t_s"] == []
        assert data.state()["counts"]["estimates"] == 5
        with pytest.raises(ConfigError, match=r"since = -1 is not allowed: must be >= 0"):
            data.estimates(-1)
    finally:
        data.close()


def _get(url: str) -> tuple[int, Any]:
    try:
        with urllib.request.urlopen(url, timeout=30) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as err:
        return err.code, err.read()


def test_http_routes(recorder: Any) -> None:
    _fill(recorder)
    server = WatchServer(WatchData.open(recorder.path)).start()
    try:
        assert server.url.startswith("http://127.0.0.1:")
        status, body = _get(server.url)
        assert status == 200 and body == page_html() and b"<title>hil watch</title>" in body
        status, body = _get(server.url + "api/state")
        assert status == 200 and json.loads(body)["counts"]["alarms"] == 1
        status, body = _get(server.url + "api/estimates?since=4")
        assert status == 200 and json.loads(body)["t_s"] == pytest.approx([0.54])
        status, body = _get(server.url + "api/truth")
        assert status == 200 and json.loads(body)["available"] is True
        status, body = _get(server.url + "api/map")
        assert status == 200 and json.loads(body)["n_codewords"] == 17
        status, body = _get(server.url + "api/estimates?since=abc")
        assert status == 400
        assert json.loads(body) == {
            "error": "since = 'abc' is not allowed: must be an integer >= 0 (an estimate row "
            "number)"
        }
        status, body = _get(server.url + "nothing")
        assert status == 404 and json.loads(body) == {"error": "no such page: /nothing"}
        status, _ = _get(server.url + "files/time_codeword_map.png")
        assert status == 404  # none saved beside this recording
    finally:
        server.close()


def test_serves_the_saved_map_beside_the_recording(recorder: Any) -> None:
    _fill(recorder)
    path = recorder.path
    png = b"\x89PNG\r\n\x1a\nnot really"
    (path.parent / "time_codeword_map.png").write_bytes(png)
    server = WatchServer(WatchData.open(path)).start()
    try:
        _, body = _get(server.url + "api/map")
        assert json.loads(body)["png"] == "/files/time_codeword_map.png"
        assert _get(server.url + "files/time_codeword_map.png") == (200, png)
    finally:
        server.close()


def test_the_page_fetches_nothing_from_outside() -> None:
    html = page_html().decode()
    assert "http://" not in html and "https://" not in html and "src=" not in html


def test_truth_times_from_the_least_delayed_sync_pair(recorder: Any) -> None:
    # SYNC pairs late by 30, 2 and 50 ms after board sample 0 at host time 10 s: the
    # least-delayed one puts sample 0 at 10.002 s. The reports' recorded indices (from a
    # live fit) are ignored once pairs exist: a report at host time h is at board sample
    # (h - 10.002) * fs.
    w = recorder.writer
    for index, late in ((100_000, 0.030), (200_000, 0.002), (300_000, 0.050)):
        w.append_sync(index, 10.0 + index / FS + late)
    for host_t, x in ((11.0, -2.0), (12.0, -3.0)):
        w.append_telemetry(StageTelemetry(host_t, 0, x, -1.0, "Run"))
    w.flush()
    data = WatchData.open(recorder.path)
    try:
        t = data.truth()
    finally:
        data.close()
    # Host 11 s: board sample 99 800, receiver time (99 800 - ORIGIN) / FS = 0.988 s.
    assert t["t_s"] == pytest.approx([0.988, 1.988])
    assert t["range_m"] == pytest.approx([8.5, 7.5])
    assert t["speed_mps"] == pytest.approx([1.0, 1.0])


def test_an_unreadable_recording_is_a_503_naming_the_file(recorder: Any) -> None:
    _fill(recorder)
    data = WatchData.open(recorder.path)
    server = WatchServer(data).start()
    try:
        data.close()  # the file handle is gone, as when a disk is lost under a running server
        status, body = _get(server.url + "api/state")
        assert status == 503
        error = json.loads(body)["error"]
        assert error.startswith(f"{recorder.path} cannot be read: ")
        status, body = _get(server.url)
        assert status == 200  # the page itself still loads and shows the error banner
    finally:
        server.shutdown()
        server.server_close()


def test_estimates_carry_their_track_ids(recorder: Any) -> None:
    ids = [-1, -1, 0, 0, 1]
    recorder.writer.append_estimates(
        [replace(recorder.estimate(i), track_id=k) for i, k in enumerate(ids)]
    )
    recorder.writer.flush()
    data = WatchData.open(recorder.path)
    try:
        assert data.estimates(0)["track_id"] == ids
        assert data.estimates(3)["track_id"] == [0, 1]
    finally:
        data.close()


def test_a_recording_without_track_ids_shows_none(recorder: Any, tmp_path: Path) -> None:
    recorder.writer.append_estimates([recorder.estimate(i) for i in range(3)])
    recorder.writer.close()
    with h5py.File(recorder.path, "r+") as f:  # as written before track ids were kept
        del f["estimates/track_id"]
        columns = [str(c) for c in f["estimates"].attrs["columns"] if str(c) != "track_id"]
        f["estimates"].attrs["columns"] = columns
    data = WatchData.open(recorder.path)
    try:
        got = data.estimates(0)
    finally:
        data.close()
    assert got["track_id"] == [-1, -1, -1] and len(got["t_s"]) == 3
