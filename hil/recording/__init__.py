"""Run recording and replay: one HDF5 file per run (SWMR, append-only, flushed at least once
a second), read back as typed views, and any receiver re-run on it through the live path.

Format: docs/recording-format.md. Write with :class:`RunWriter`, read with
:meth:`RunRecording.open`, re-run a receiver with :func:`replay`.

The reader's, the writer's and the schema's names are imported on first use (PEP 562), so a
command that only builds a receiver (``hil estimate``, through :mod:`hil.recording.replay`)
does not import h5py (0.05-0.15 s of CPU): it comes with those three modules.

>>> import tempfile, pathlib, numpy as np
>>> from hil.recording import RunRecording, RunWriter
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

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

# Imported here, not on first use: ``replay`` is both a submodule and a function, and the
# function must be the package's attribute once the submodule is imported.
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

if TYPE_CHECKING:  # the names imported on first use, as mypy sees them ("X as X": exported)
    from hil.recording.reader import RunRecording as RunRecording
    from hil.recording.reader import Segments as Segments
    from hil.recording.schema import EVENT_KINDS as EVENT_KINDS
    from hil.recording.schema import FORMAT_NAME as FORMAT_NAME
    from hil.recording.schema import FORMAT_VERSION as FORMAT_VERSION
    from hil.recording.writer import RunWriter as RunWriter
    from hil.recording.writer import software_versions as software_versions

_LAZY = {
    "EVENT_KINDS": "hil.recording.schema",
    "FORMAT_NAME": "hil.recording.schema",
    "FORMAT_VERSION": "hil.recording.schema",
    "RunRecording": "hil.recording.reader",
    "RunWriter": "hil.recording.writer",
    "Segments": "hil.recording.reader",
    "software_versions": "hil.recording.writer",
}
"""Names of the modules that import h5py -> the module defining each."""

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


def __getattr__(name: str) -> Any:
    """Import the module of a name in :data:`_LAZY` on first access and cache the name."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'hil.recording' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
