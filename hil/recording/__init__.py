"""Run recording and replay: one HDF5 file per run (SWMR, append-only, flushed at least once
a second), read back as typed views, and any receiver re-run on it through the live path.

Format: docs/recording-format.md. Write with :class:`RunWriter`, read with
:meth:`RunRecording.open`, re-run a receiver with :func:`replay`.

>>> import tempfile, pathlib, numpy as np
>>> from hil.signals.presets import check_design, get_preset
>>> from hil.signals.schedule_file import schedule_document
>>> doc = schedule_document(check_design(get_preset("att").spec("random-cyclic")), 100e3, 0.0,
...                         sound_speed_mps=1500.0)
>>> folder = tempfile.TemporaryDirectory()
>>> path = pathlib.Path(folder.name) / "run.h5"
>>> with RunWriter.create(path, fs_hz=100e3, n_channels=1, dtype="int16",
...                       schedule_document=doc) as w:
...     w.append_samples(1000, np.arange(5, dtype=np.int16))
...     w.append_samples(1008, np.arange(3, dtype=np.int16))  # samples 1005..1007 lost
>>> with RunRecording.open(path) as rec:
...     [(b.first_index, b.data[:, 0].tolist()) for b in rec.samples()], rec.gaps()
([(1000, [0, 1, 2, 3, 4]), (1008, [0, 1, 2])], [(1005, 3)])
>>> folder.cleanup()
"""

from hil.recording.reader import RunRecording, Segments
from hil.recording.records import (
    ReceiverSetup,
    RunEvent,
    RunMetadata,
    SampleBlock,
    StageTelemetry,
    SyncPairs,
)
from hil.recording.replay import (
    build_receiver,
    compare_estimates,
    replay,
    replay_setup,
)
from hil.recording.schema import EVENT_KINDS, FORMAT_NAME, FORMAT_VERSION
from hil.recording.writer import RunWriter, software_versions

__all__ = [
    "EVENT_KINDS",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "ReceiverSetup",
    "RunEvent",
    "RunMetadata",
    "RunRecording",
    "RunWriter",
    "SampleBlock",
    "Segments",
    "StageTelemetry",
    "SyncPairs",
    "build_receiver",
    "compare_estimates",
    "replay",
    "replay_setup",
    "software_versions",
]
