"""SWMR: a reader in another process sees the recording up to the writer's last flush while
it is written, the time-based flush makes data visible without an explicit flush, and a
writer killed with SIGKILL leaves a readable file up to its last flush."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil.recording import RunEvent, RunRecording, RunWriter

CHILD = Path(__file__).with_name("recording_child.py")
FS = 100_000.0


def _child(mode: str, path: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, str(CHILD), mode, str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _read_in_other_process(path: Path) -> dict[str, Any]:
    proc = _child("read", path)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    result: dict[str, Any] = json.loads(out)
    return result


def _values(first: int, n: int) -> np.ndarray:
    v = (np.arange(first, first + n) % 30000).astype(np.int16)
    return np.stack([v, -v], axis=1)


class FakeClock:
    """A clock the test moves by hand (s)."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.mark.slow
def test_reader_sees_data_up_to_the_last_flush(
    tmp_path: Path, schedule_doc: dict[str, Any]
) -> None:
    path = tmp_path / "live.h5"
    clock = FakeClock()
    writer = RunWriter.create(
        path,
        fs_hz=FS,
        n_channels=2,
        dtype="int16",
        schedule_document=schedule_doc,
        chunk_frames=1024,
        clock=clock,
    )
    with writer:
        writer.append_samples(0, _values(0, 3000))
        writer.append_sync(0, 10.0)
        writer.append_event(RunEvent("note", 0, 0, "start"))
        writer.flush()
        seen = _read_in_other_process(path)
        assert seen == {
            "n_samples": 3000,
            "segments": [0],
            "values_ok": True,
            "events": 1,
            "sync": 1,
            "estimates": 0,
        }

        # Appended but not flushed (the clock has not moved a second): not yet visible.
        clock.now = 0.5
        writer.append_samples(3500, _values(3500, 2000))
        writer.append_event(RunEvent("alarm", 4000, 0, "door"))
        assert writer.flush_count == 1
        seen = _read_in_other_process(path)
        assert (seen["n_samples"], seen["segments"], seen["events"]) == (3000, [0], 1)

        # One second after the last flush the next append flushes by itself.
        clock.now = 1.0
        writer.append_sync(5000, 10.05)
        assert writer.flush_count == 2
        seen = _read_in_other_process(path)
        assert seen == {
            "n_samples": 5000,
            "segments": [0, 3500],
            "values_ok": True,
            "events": 3,  # start, the gap 3000..3499, the alarm
            "sync": 2,
            "estimates": 0,
        }


def test_sigkill_leaves_a_recording_readable_up_to_the_last_flush(tmp_path: Path) -> None:
    path = tmp_path / "killed.h5"
    proc = _child("write", path)
    reported: list[tuple[int, int, int]] = []
    try:
        assert proc.stdout is not None
        while len(reported) < 4:
            line = proc.stdout.readline()
            if not line:
                pytest.fail(f"writer ended early: {proc.stderr.read() if proc.stderr else ''}")
            _, *counts = line.split()
            reported.append((int(counts[0]), int(counts[1]), int(counts[2])))
        # The writer keeps appending (and flushing) while the signal arrives.
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    rows, events, estimates = reported[-1]
    with RunRecording.open(path) as rec:
        n = rec.n_samples
        assert n >= rows and n % 2000 == 0
        blocks = rec.samples()
        for b in blocks:
            np.testing.assert_array_equal(b.data, _values(b.first_index, len(b.data)))
        # A 100-sample gap after every 5th block of 2000.
        seg = rec.segments()
        assert seg.sample_index.tolist() == [i * 10_100 for i in range(len(seg))]
        assert rec.gaps() == [(10_000 + i * 10_100, 100) for i in range(len(seg) - 1)]
        assert len(rec.events()) >= events
        est = rec.estimates("fake")
        assert len(est) >= estimates
        assert [e.hop_index for e in est] == list(range(len(est)))
        kinds = [e.kind for e in rec.events()]
        assert kinds.count("gap") == len(seg) - 1
