"""Format version 2: the table string columns are fixed-length UTF-8, so they round-trip any
text that fits, cut a long event text on a character boundary, refuse a name that does not
fit, read while the writer runs (SWMR), and version-1 files (variable-length strings) still
read."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.recording import (
    EVENT_KINDS,
    RunEvent,
    RunRecording,
    RunWriter,
    StageTelemetry,
    schema,
)
from hil.recording.tables import append_rows, create_table, fit_text, read_table

CHILD = Path(__file__).with_name("recording_child.py")
FS = 100_000.0

NON_ASCII = ("Hold:0", "ümlaut–dash", "停止中", "𝄞 clef", "")


def _writer(path: Path, doc: dict[str, Any]) -> RunWriter:
    return RunWriter.create(path, fs_hz=FS, n_channels=1, dtype="int16", schedule_document=doc)


def _estimate(i: int, receiver: str) -> Estimate:
    return Estimate(i / FS, float(i), 0.5, i, 1.0, 20.0, 1.0, 0.0, i % 4, receiver)


def _memory_file(name: str) -> h5py.File:
    return h5py.File(name, "w", driver="core", backing_store=False, libver="latest")


# ---------------------------------------------------------------------------- layout


def test_string_columns_are_fixed_length_utf8_of_the_schema_lengths(
    tmp_path: Path, schedule_doc: dict[str, Any]
) -> None:
    path = tmp_path / "run.h5"
    _writer(path, schedule_doc).close()
    want = {
        "telemetry/state": 16,
        "events/kind": 16,
        "events/text": 512,
        "estimates/receiver": 32,
    }
    with h5py.File(path, "r") as f:
        assert f.attrs["format_version"] == schema.FORMAT_VERSION == 2
        for name, length in want.items():
            info = h5py.check_string_dtype(f[name].dtype)
            assert (info.encoding, info.length) == ("utf-8", length), name
        # The scalar strings are written before SWMR starts and stay variable-length.
        for name in (schema.SCHEDULE_DOCUMENT, schema.EXPERIMENT_TOML):
            assert h5py.check_string_dtype(f[name].dtype).length is None
    assert (
        schema.TELEMETRY_STATE_BYTES,
        schema.EVENT_KIND_BYTES,
        schema.EVENT_TEXT_BYTES,
        schema.ESTIMATE_RECEIVER_BYTES,
    ) == (16, 16, 512, 32)


# ---------------------------------------------------------------------------- round trips


def test_every_string_column_round_trips_non_ascii_text(
    tmp_path: Path, schedule_doc: dict[str, Any]
) -> None:
    path = tmp_path / "run.h5"
    telemetry = [StageTelemetry(1.0 + i, i, 0.1 * i, -0.5, s) for i, s in enumerate(NON_ASCII)]
    events = [RunEvent(EVENT_KINDS[i], i, 0, f"{s} ✓ {i}") for i, s in enumerate(NON_ASCII)]
    estimates = [_estimate(i, s) for i, s in enumerate(NON_ASCII)]
    with _writer(path, schedule_doc) as w:
        for t in telemetry:
            w.append_telemetry(t)
        for e in events:
            w.append_event(e)
        w.append_estimates(estimates)
    with RunRecording.open(path) as rec:
        assert rec.telemetry() == telemetry
        assert rec.events() == events
        assert rec.estimates() == estimates
        assert rec.estimates("停止中") == [estimates[2]]
        assert all(type(e.receiver) is str for e in rec.estimates())


def test_the_kind_column_round_trips_non_ascii_text_at_its_byte_limit() -> None:
    # RunEvent admits only EVENT_KINDS; the column itself holds any text of up to 16 bytes.
    kinds = ["ümlaut–dash", "停止中", "ü" * 8, "a" * 16, "𝄞" * 4, "note"]
    with _memory_file("kinds.h5") as f:
        group = create_table(f, "events", schema.TABLES["events"])
        n = len(kinds)
        texts = [k * 3 for k in kinds]
        append_rows(
            group, {"kind": kinds, "sample_index": range(n), "length": [0] * n, "text": texts}
        )
        t = read_table(group, refresh=False)
        assert t["kind"].tolist() == kinds
        assert t["text"].tolist() == texts
        assert all(type(k) is str for k in t["kind"])


# ---------------------------------------------------------------------------- event text cut

TEXT_SPEC = dict(schema.TABLES["events"])["text"]
ANY_CHAR = st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00")
FOUR_BYTE_CHAR = st.characters(min_codepoint=0x10000, blacklist_categories=("Cs",))
CHAR = st.one_of(ANY_CHAR, FOUR_BYTE_CHAR)
# Short texts, and long ones of which about half pass 512 bytes (a trailing NUL is padding,
# so the alphabet has none).
TEXT = st.one_of(st.text(CHAR, max_size=40), st.text(CHAR, min_size=200, max_size=700))


@settings(max_examples=60, deadline=None, derandomize=True)
@given(texts=st.lists(TEXT, min_size=1, max_size=4))
@example(texts=["a" * 512, "a" * 513, "a" * 508 + "𝄞", "a" * 511 + "𝄞" + "b", "€" * 200])
def test_a_long_event_text_is_cut_on_a_character_boundary_and_ends_with_an_ellipsis(
    texts: list[str],
) -> None:
    n = len(texts)
    with _memory_file("text.h5") as f:
        group = create_table(f, "events", schema.TABLES["events"])
        append_rows(
            group,
            {"kind": ["note"] * n, "sample_index": range(n), "length": range(n), "text": texts},
        )
        got = read_table(group, refresh=False)["text"].tolist()
    assert len(got) == n
    for text, stored in zip(texts, got, strict=True):
        assert type(stored) is str
        if len(text.encode()) <= 512:
            assert stored == text
            continue
        assert len(stored.encode()) <= 512
        assert stored.endswith("…")
        head = stored[:-1]
        assert text.startswith(head)
        # The longest whole-character prefix that leaves room for the 3-byte "…".
        assert len(head.encode()) <= 509 < len(text[: len(head) + 1].encode())


def test_the_cut_of_a_known_text() -> None:
    # 200 x "€" (3 bytes each): 169 fit in 512 - 3 bytes.
    assert fit_text("€" * 200, TEXT_SPEC, "events.text").decode() == "€" * 169 + "…"
    assert fit_text("€" * 170, TEXT_SPEC, "events.text") == ("€" * 170).encode()  # 510 bytes


def test_the_writer_records_a_long_event_text_cut(
    tmp_path: Path, schedule_doc: dict[str, Any]
) -> None:
    path = tmp_path / "run.h5"
    with _writer(path, schedule_doc) as w:
        w.append_event(RunEvent("alarm", 5, 0, "€" * 200))
    with RunRecording.open(path) as rec:
        assert rec.events() == [RunEvent("alarm", 5, 0, "€" * 169 + "…")]


# ---------------------------------------------------------------------------- refused names


def test_a_too_long_state_is_refused_when_appended_and_the_writer_goes_on(
    tmp_path: Path, schedule_doc: dict[str, Any]
) -> None:
    path = tmp_path / "run.h5"
    good = StageTelemetry(1.0, 10, 0.0, 0.0, "Run")
    with _writer(path, schedule_doc) as w:
        with pytest.raises(ConfigError) as err:
            w.append_telemetry(StageTelemetry(1.0, 10, 0.0, 0.0, "Hold:0 (door open)"))
        assert str(err.value) == (
            "telemetry.state = 'Hold:0 (door open)' is not allowed: must be at most 16 bytes "
            "of UTF-8 (it has 18); record the controller's state word; longer text goes in "
            "an event"
        )
        # Bytes, not characters: 9 x "ü" is 18 bytes.
        with pytest.raises(ConfigError, match=r"must be at most 16 bytes of UTF-8 \(it has 18\)"):
            w.append_telemetry(StageTelemetry(1.0, 10, 0.0, 0.0, "ü" * 9))
        w.append_telemetry(good)
    with RunRecording.open(path) as rec:
        assert rec.telemetry() == [good]


def test_a_too_long_receiver_is_refused_and_none_of_the_estimates_is_appended(
    tmp_path: Path, schedule_doc: dict[str, Any]
) -> None:
    path = tmp_path / "run.h5"
    name = "gcas-with-a-very-long-variant-name"  # 34 bytes
    with _writer(path, schedule_doc) as w:
        with pytest.raises(ConfigError) as err:
            w.append_estimates([_estimate(0, "gcas"), _estimate(1, name)])
        assert str(err.value) == (
            f"estimates.receiver = '{name}' is not allowed: must be at most 32 bytes of UTF-8 "
            "(it has 34); a cut name would not find the receiver on replay; register a "
            "shorter name"
        )
        w.append_estimates([_estimate(2, "stft")])
    with RunRecording.open(path) as rec:
        assert rec.estimates() == [_estimate(2, "stft")]


def test_a_too_long_kind_is_refused_and_the_table_left_as_it_was() -> None:
    with _memory_file("kinds.h5") as f:
        group = create_table(f, "events", schema.TABLES["events"])
        row = {"sample_index": [1, 2], "length": [0, 0], "text": ["a", "b"]}
        append_rows(group, {"kind": ["note", "gap"], **row})
        with pytest.raises(ConfigError) as err:
            append_rows(group, {"kind": ["note", "ü" * 9], **row})
        assert str(err.value) == (
            "events.kind = 'üüüüüüüüü' is not allowed: must be at most 16 bytes of UTF-8 "
            "(it has 18); use one of EVENT_KINDS"
        )
        t = read_table(group, refresh=False)
        assert t["kind"].tolist() == ["note", "gap"]
        assert {c: v.shape[0] for c, v in t.items()} == dict.fromkeys(t, 2)


# ---------------------------------------------------------------------------- version 1


def _as_version_1(path: Path) -> None:
    """Rewrite a version-2 recording as version 1 wrote it: variable-length table strings."""
    with h5py.File(path, "r+") as f:
        for table, columns in schema.TABLES.items():
            for column, spec in columns:
                if not isinstance(spec, schema.FixedText):
                    continue
                name = f"{table}/{column}"
                values = f[name].asstr()[:].tolist()
                del f[name]
                f.create_dataset(
                    name,
                    data=np.asarray(values, dtype=object),
                    maxshape=(None,),
                    dtype=h5py.string_dtype("utf-8"),
                    chunks=(schema.TABLE_CHUNK_ROWS,),
                )
        # Nor had its estimates the bound and track columns, nor its telemetry the reply times.
        for table, gone in (("estimates", ("crlb_range_m", "crlb_speed_mps", "track_id")),
                            ("telemetry", ("reply_s",))):  # fmt: skip
            for column in gone:
                del f[f"{table}/{column}"]
            kept = [str(c) for c in f[table].attrs["columns"] if str(c) not in gone]
            f[table].attrs["columns"] = kept
        f.attrs["format_version"] = 1


def test_a_version_1_recording_still_reads(tmp_path: Path, schedule_doc: dict[str, Any]) -> None:
    path = tmp_path / "v1.h5"
    telemetry = [
        StageTelemetry(1.0, 1, 0.1, -0.5, "Hold:0", 0.3),
        StageTelemetry(2, 2, 0, 0, "停止中"),
    ]
    events = [RunEvent("note", 7, 0, "ümlaut–dash"), RunEvent("alarm", 9, 2, "停止中 𝄞")]
    estimates = [_estimate(0, "gcas"), _estimate(1, "ümlaut–dash"), _estimate(2, "stft")]
    with _writer(path, schedule_doc) as w:
        w.append_samples(100, np.arange(50, dtype=np.int16))
        w.append_samples(160, np.arange(10, dtype=np.int16))  # a gap event: 150 .. 159
        for t in telemetry:
            w.append_telemetry(t)
        for e in events:
            w.append_event(e)
        w.append_estimates(estimates)
    _as_version_1(path)
    with h5py.File(path, "r") as f:  # the layout of version 1
        assert f.attrs["format_version"] == 1
        for name in ("telemetry/state", "events/kind", "events/text", "estimates/receiver"):
            info = h5py.check_string_dtype(f[name].dtype)
            assert (info.encoding, info.length) == ("utf-8", None)
    with RunRecording.open(path) as rec:
        # Its reports had no reply time: each reads as prompt (0 s), so every one is used.
        assert rec.telemetry() == [replace(t, reply_s=0.0) for t in telemetry]
        assert rec.events() == [RunEvent("gap", 150, 10, "samples 150 .. 159 missing"), *events]
        assert rec.estimates() == estimates  # the bounds read NaN, as they were written
        assert all(math.isnan(e.crlb_range_m) for e in rec.estimates())
        assert [e.track_id for e in rec.estimates()] == [-1, -1, -1]
        assert not rec.has_track_ids
        assert rec.gaps() == [(150, 10)]
        assert math.isclose(rec.fs_hz, FS)


def test_the_estimates_bounds_round_trip(tmp_path: Path, schedule_doc: dict[str, Any]) -> None:
    path = tmp_path / "run.h5"
    estimates = [replace(_estimate(i, "gcas"), crlb_range_m=1e-3 * (i + 1), crlb_speed_mps=2e-3)
                 for i in range(3)]  # fmt: skip
    with _writer(path, schedule_doc) as w:
        w.append_estimates(estimates)
    with RunRecording.open(path) as rec:
        assert rec.estimates() == estimates
        assert rec.table("estimates")["crlb_range_m"].tolist() == [1e-3, 2e-3, 3e-3]


# ---------------------------------------------------------------------------- live (SWMR)

STATES = ("Run", "Hold:0", "ümlaut–dash", "停止中", "Jog")
RECEIVERS = ("gcas", "ümlaut–dash", "停止中")


def _telemetry_row(i: int) -> StageTelemetry:
    return StageTelemetry(i * 0.1, i * 1000, i * 0.01, 0.5, STATES[i % len(STATES)])


def _event_row(i: int) -> RunEvent:
    # What recording_child.py writes, as stored: its 600-byte texts cut to 169 x "€" + "…".
    text = "€" * 169 + "…" if i % 7 == 3 else f"event {i}: ümlaut–dash 停止中 𝄞"
    return RunEvent(EVENT_KINDS[i % len(EVENT_KINDS)], i * 1000, i, text)


def _estimate_row(i: int) -> Estimate:
    return Estimate(i / FS, float(i), 0.0, i, 1.0, 0.0, 1.0, 0.0, i % 4, RECEIVERS[i % 3])


def _read_and_check(path: Path, rounds: int) -> tuple[int, int, int]:
    """Open the recording ``rounds`` times and read every string-bearing table three times
    per opening; each read must be a prefix of what the writer writes. Returns the last
    row counts."""
    counts = (0, 0, 0)
    for _ in range(rounds):
        with RunRecording.open(path) as rec:
            for _ in range(3):
                telemetry, events, estimates = rec.telemetry(), rec.events(), rec.estimates()
                assert telemetry == [_telemetry_row(i) for i in range(len(telemetry))]
                assert events == [_event_row(i) for i in range(len(events))]
                assert estimates == [_estimate_row(i) for i in range(len(estimates))]
                counts = (len(telemetry), len(events), len(estimates))
    return counts


@pytest.mark.slow
def test_a_live_reader_reads_every_string_column_while_the_writer_appends(
    tmp_path: Path,
) -> None:
    path = tmp_path / "live.h5"
    proc = subprocess.Popen(
        [sys.executable, str(CHILD), "strings", str(path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None and proc.stdin is not None
        line = proc.stdout.readline()
        if line != "flushed 1\n":
            pytest.fail(
                f"writer did not start: {line!r} {proc.stderr.read() if proc.stderr else ''}"
            )
        # The writer flushes a batch about every millisecond while this process reads.
        first = _read_and_check(path, rounds=1)
        assert first[0] >= 2 and first[1] >= 1 and first[2] >= 1  # the first flush at least
        _read_and_check(path, rounds=40)
        # Closing stdin stops the writer: it closes the recording and reports.
        out, err = proc.communicate(input="", timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    batches = int(out.split()[-1])
    assert out.split() == ["done", str(batches)]
    # After the writer closed: everything it wrote.
    assert _read_and_check(path, rounds=1) == (2 * batches, batches, batches)
