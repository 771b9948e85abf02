"""A full disk mid-run stops the run safely: the recording is closed readable with its stop
event, the summary says why, the command exits 1 (an I/O failure at run time) in lines, never
a traceback or a crash. Tried with a real limit: the process's file-size limit
(``ulimit -f``, RLIMIT_FSIZE), under which writes past it fail as on a full disk."""

from __future__ import annotations

import gc
import json
import resource
from pathlib import Path

import pytest

from hil.experiments.live.disk_room import RecordingSpaceError, check_room

LIMIT_BYTES = 5_000_000  # the default run's recording is ~4.2 MB; the reserve ~3.6 MB


def test_less_room_than_the_reserve_is_refused_saying_how_much(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    path.write_bytes(b"")
    check_room(path, 1024)  # plenty
    with pytest.raises(RecordingSpaceError) as err:
        check_room(path, 10**18)
    message = str(err.value)
    assert message.startswith("run.h5 has ")
    assert message.endswith(
        "MB left to grow (free space on its disk), less than the 1e+12 MB kept to close it"
        " readable: the run stopped there; free space (or raise the limit) and run again"
    )
    assert err.value.errno == 28  # ENOSPC


def test_the_recorder_checks_the_room_once_every_check_span_of_samples(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before the first block, then once CHECK_EVERY_S of samples have been taken since the
    last check; a check that finds too little room refuses the block."""
    import numpy as np

    import hil.experiments.live.recorder as recorder_module
    from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
    from hil.experiments.live.disk_room import CHECK_EVERY_S
    from hil.experiments.live.recorder import RunRecorder
    from hil.recording.records import RunEvent
    from hil.signals.schedule_file import schedule_document

    exp = parse_experiment(DEFAULT_EXPERIMENT)
    fs = exp.waveform.fs_hz  # 192 kHz: 9600 samples between checks
    assert int(CHECK_EVERY_S * fs) == 9600
    checked: list[int] = []  # the samples taken before each check
    room = {"bytes": 10**12}

    def fake_check(path: Path, reserve: int) -> None:
        checked.append(taken)
        if room["bytes"] < reserve:
            raise RecordingSpaceError("no room")

    monkeypatch.setattr(recorder_module, "check_room", fake_check)
    doc = schedule_document(exp.schedule, fs, 0.0, sound_speed_mps=exp.sound_speed_mps)
    options = {"fs_hz": fs, "n_channels": 2, "dtype": "int16", "schedule_document": doc}
    recorder = RunRecorder(tmp_path / "run.h5", options)
    recorder.open(0, RunEvent("note", 0, 0, "start"))
    block = np.zeros((4000, 2), np.int16)
    taken = 0
    for _ in range(11):  # checks before samples 0, 12000, 24000 and 36000
        recorder.samples(taken, block)
        taken += 4000
    assert checked == [0, 12000, 24000, 36000]
    room["bytes"] = 0
    recorder.samples(taken, block)  # 8000 since the last check: not checked
    taken += 4000
    with pytest.raises(RecordingSpaceError):  # 12000 since: checked, refused
        recorder.samples(taken, block)
    assert checked[-1] == 48000
    recorder.close()


@pytest.mark.slow
def test_a_file_size_limit_mid_run_stops_it_with_a_readable_recording(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """``hil tank-run --virtual-time`` in this process under a file-size limit (its soft
    limit, put back after: Python ignores SIGXFSZ, so a write past it fails with EFBIG as
    on a full disk); on virtual time the run is this process alone, no tank process."""
    from hil.cli.main import main
    from hil.recording.reader import RunRecording, hdf5_damage

    out = tmp_path / "run"
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    assert hard == resource.RLIM_INFINITY or hard >= LIMIT_BYTES, hard
    capfd.readouterr()
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT_BYTES, hard))
    try:
        code = main(["tank-run", "--virtual-time", "--no-live", "--out", str(out)])
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    gc.collect()  # what the run left behind is finalised now, as at a process's exit
    err = capfd.readouterr().err
    assert code == 1, err  # an I/O failure at run time, no crash
    assert "Traceback" not in err and "Exception ignored" not in err
    summary = json.loads((out / "summary.json").read_text())
    why = summary["error"]
    assert why.startswith("RecordingSpaceError: run.h5 has ")
    assert "(the file-size limit (ulimit -f)), less than the" in why
    # The run streamed before the limit stopped it (0.39-0.49 s of signal measured: where the
    # 5 MB run out depends on when the writer flushed, by the wall clock).
    assert summary["interrupted"] is False and summary["signal_s"] > 0.1
    h5 = out / "run.h5"
    assert h5.stat().st_size < LIMIT_BYTES and hdf5_damage(h5) is None
    with RunRecording.open(h5) as rec:
        last = rec.events()[-1]
        assert rec.table_columns("estimates")["t_s"].size == summary["estimates"]
    assert (last.kind, last.text) == ("alarm", f"stop: error: {why}")
