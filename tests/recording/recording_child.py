"""A separate process for the SWMR and kill tests (run as a script, never imported by them).

``python recording_child.py write PATH``: records continuously (2 channels int16, sample
value = board index mod 30000 on channel 0 and its negative on channel 1, a 100-sample gap
after every 5th block, one note event and one estimate per block), flushing after every 3rd
block and printing ``flushed ROWS EVENTS ESTIMATES`` after each flush, until killed (or 60 s).

``python recording_child.py read PATH``: opens the recording and prints one JSON object with
what it sees and whether every sample holds the value its board index implies.

``python recording_child.py strings PATH``: records string-bearing rows only (per batch two
telemetry rows, one event, one estimate; row ``i`` of each table as :func:`string_rows`
makes it), flushing after every batch; prints ``flushed 1`` after the first flush, and
after stdin is closed (or 15 s) closes the recording and prints ``done BATCHES``.
"""

from __future__ import annotations

import json
import sys
import threading
import time

import numpy as np

from hil.estimation.base import Estimate
from hil.recording import EVENT_KINDS, RunEvent, RunRecording, RunWriter, StageTelemetry
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule_file import schedule_document

FS = 100_000.0
BLOCK = 2000
GAP = 100


def expected_values(first_index: int, n: int) -> np.ndarray:
    """The samples the writer stores for board indices ``first_index ..``, shape (n, 2)."""
    v = (np.arange(first_index, first_index + n) % 30000).astype(np.int16)
    return np.stack([v, -v], axis=1)


def write(path: str) -> None:
    sch = check_design(get_preset("att").spec("random-cyclic"))
    doc = schedule_document(sch, FS, 0.0, sound_speed_mps=1500.0)
    writer = RunWriter.create(
        path, fs_hz=FS, n_channels=2, dtype="int16", schedule_document=doc, chunk_frames=4096
    )
    index, rows, events, estimates = 0, 0, 0, 0
    stop = time.monotonic() + 60.0
    block = 0
    while time.monotonic() < stop:
        writer.append_samples(index, expected_values(index, BLOCK))
        rows += BLOCK
        writer.append_event(RunEvent("note", index, 0, f"block {block}"))
        writer.append_estimates(
            [Estimate(index / FS, 1.0, 0.0, block, 1.0, 0.0, 1.0, 0.0, 0, "fake")]
        )
        events += 1
        estimates += 1
        index += BLOCK
        block += 1
        if block % 5 == 0:
            index += GAP
            events += 1  # the writer's gap event, recorded with the next block
        if block % 3 == 0:
            writer.flush()
            gap_pending = 1 if block % 5 == 0 else 0
            print(f"flushed {rows} {events - gap_pending} {estimates}", flush=True)


def read(path: str) -> None:
    with RunRecording.open(path) as rec:
        blocks = rec.samples()
        ok = all(
            np.array_equal(b.data, expected_values(b.first_index, len(b.data))) for b in blocks
        )
        seg = rec.segments()
        print(
            json.dumps(
                {
                    "n_samples": rec.n_samples,
                    "segments": seg.sample_index.tolist(),
                    "values_ok": ok,
                    "events": len(rec.events()),
                    "sync": len(rec.sync_pairs()),
                    "estimates": len(rec.estimates()),
                }
            ),
            flush=True,
        )


STATES = ("Run", "Hold:0", "ümlaut–dash", "停止中", "Jog")
RECEIVERS = ("gcas", "ümlaut–dash", "停止中")


def string_rows(i: int) -> tuple[StageTelemetry, RunEvent, Estimate]:
    """Row ``i`` of the telemetry, events and estimates tables of the ``strings`` mode
    (every 7th event text is 600 bytes long, so the writer cuts it)."""
    text = "€" * 200 + f" {i}" if i % 7 == 3 else f"event {i}: ümlaut–dash 停止中 𝄞"
    return (
        StageTelemetry(i * 0.1, i * 1000, i * 0.01, 0.5, STATES[i % len(STATES)]),
        RunEvent(EVENT_KINDS[i % len(EVENT_KINDS)], i * 1000, i, text),
        Estimate(i / FS, float(i), 0.0, i, 1.0, 0.0, 1.0, 0.0, i % 4, RECEIVERS[i % 3]),
    )


def strings(path: str) -> None:
    sch = check_design(get_preset("att").spec("random-cyclic"))
    doc = schedule_document(sch, FS, 0.0, sound_speed_mps=1500.0)
    stop = threading.Event()

    def wait_for_eof() -> None:
        sys.stdin.read()
        stop.set()

    threading.Thread(target=wait_for_eof, daemon=True).start()
    deadline = time.monotonic() + 15.0
    batches = 0
    with RunWriter.create(
        path, fs_hz=FS, n_channels=1, dtype="int16", schedule_document=doc
    ) as writer:
        while not stop.is_set() and time.monotonic() < deadline:
            for i in (2 * batches, 2 * batches + 1):
                writer.append_telemetry(string_rows(i)[0])
            _, event, estimate = string_rows(batches)
            writer.append_event(event)
            writer.append_estimates([estimate])
            writer.flush()
            batches += 1
            if batches == 1:
                print("flushed 1", flush=True)
            time.sleep(0.001)
    print(f"done {batches}", flush=True)


if __name__ == "__main__":
    {"write": write, "read": read, "strings": strings}[sys.argv[1]](sys.argv[2])
