"""An HDF5 file that says it is a run recording but lacks what every recording holds is
refused at open from its structure, in one line naming what is missing (``hil report`` and
``hil replay``: exit status 2), never a KeyError on the first read."""

from __future__ import annotations

from pathlib import Path

import h5py
import pytest

from hil.cli.main import main
from hil.errors import ConfigError
from hil.recording import RunRecording, schema


def _header_only(path: Path) -> Path:
    with h5py.File(path, "w") as f:
        f.attrs[schema.ATTR_FORMAT] = schema.FORMAT_NAME
        f.attrs[schema.ATTR_VERSION] = schema.FORMAT_VERSION
    return path


def _recording_without(path: Path, attribute: str) -> Path:
    from hil.recording.writer import RunWriter
    from hil.signals.presets import check_design, get_preset
    from hil.signals.schedule_file import schedule_document

    spec = get_preset("att").spec("random-cyclic")
    doc = schedule_document(check_design(spec), 100e3, 0.0, sound_speed_mps=1500.0)
    with RunWriter.create(path, fs_hz=100e3, n_channels=1, dtype="int16", schedule_document=doc):
        pass
    with h5py.File(path, "a") as f:
        del f.attrs[attribute]
    return path


def test_a_file_with_the_format_attributes_only_is_refused_naming_what_it_lacks(
    tmp_path: Path,
) -> None:
    path = _header_only(tmp_path / "run.h5")
    with pytest.raises(ConfigError) as err:
        RunRecording.open(path)
    message = str(err.value)
    assert message.startswith(
        f"recording = '{path}' is not allowed: must be a complete hil run recording; it lacks"
        " the attribute fs_hz, the attribute n_channels,"
    )
    assert "/samples, /schedule/document, /metadata/experiment_toml, /segments," in message
    assert message.endswith(
        "/estimates: it was not written by hil's recorder or was altered since; use the"
        " run.h5 the run wrote"
    )


def test_a_recording_missing_one_attribute_is_refused_naming_it(tmp_path: Path) -> None:
    path = _recording_without(tmp_path / "run.h5", "fs_hz")
    with pytest.raises(ConfigError, match=r"it lacks the attribute fs_hz: it was not written"):
        RunRecording.open(path)


@pytest.mark.parametrize("command", ["report", "replay"])
def test_report_and_replay_refuse_it_in_one_line(
    command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _recording_without(tmp_path / "run.h5", "created_utc")
    assert main([command, str(path)]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"hil {command}: error: RUN (recording) = '{path}' is not allowed: must be a complete"
        " hil run recording; it lacks the attribute created_utc: it was not written by hil's"
        " recorder or was altered since; use the run.h5 the run wrote\n"
    )


def _corrupted_metadata(path: Path) -> Path:
    """A recording whose object headers after the superblock are overwritten (seeded noise):
    the superblock is whole, and HDF5 loops for ever reading the root's attributes."""
    import numpy as np

    _recording_without(path, "created_utc")  # any small recording
    data = bytearray(path.read_bytes())
    data[96:4096] = np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8).tobytes()
    path.write_bytes(bytes(data))
    return path


#: Each case waits out the probe's 5 s of wall time (a child process hung in HDF5): the fast
#: tier runs the report's, ``--all`` both (they share the probe, each command calls it).
PROBED_COMMANDS = [
    pytest.param("report", id="report"),
    pytest.param("replay", id="replay", marks=pytest.mark.slow),
]


@pytest.mark.parametrize("command", PROBED_COMMANDS)
def test_a_recording_whose_metadata_hangs_hdf5_is_refused_within_the_probe_time(
    command: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import hil.recording.reader as reader

    monkeypatch.setattr(reader, "PROBE_TIMEOUT_S", 5.0)
    path = _corrupted_metadata(tmp_path / "run.h5")
    assert reader.hdf5_damage(path) is None  # the superblock alone does not tell
    assert main([command, str(path)]) == 2
    assert capsys.readouterr().err == (
        f"hil {command}: error: RUN (recording) = '{path}' is not allowed: must be an HDF5 run"
        " recording written by hil; its metadata is damaged: reading its structure did not"
        " end within 5 s; copy it again from where the run wrote it\n"
    )
