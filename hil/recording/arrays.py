"""A run recording as NumPy arrays, for notebooks and scripts.

:func:`load_arrays` reads a ``run.h5`` (finished, or still being written: what was flushed)
into plain arrays: the received samples with the board sample index of every row, and one
array per column of the estimates, telemetry and events. Gaps are not filled: compare
``sample_index`` with ``np.arange`` to find them, or use ``gaps``.

>>> import tempfile, pathlib
>>> from hil.recording.writer import RunWriter
>>> from hil.signals.presets import check_design, get_preset
>>> from hil.signals.schedule_file import schedule_document
>>> doc = schedule_document(check_design(get_preset("att").spec("random-cyclic")), 100e3, 0.0,
...                         sound_speed_mps=1500.0)
>>> path = pathlib.Path(tempfile.mkdtemp()) / "run.h5"
>>> with RunWriter.create(path, fs_hz=100e3, n_channels=1, dtype="int16",
...                       schedule_document=doc) as w:
...     w.append_samples(10, np.arange(3, dtype=np.int16))
...     w.append_samples(15, np.arange(2, dtype=np.int16))
>>> a = load_arrays(path)
>>> a.sample_index.tolist(), a.samples[:, 0].tolist(), a.gaps
([10, 11, 12, 15, 16], [0, 1, 2, 0, 1], [(13, 2)])
>>> a.time_s[:2].tolist()  # s, the schedule's t = 0 at the first recorded sample
[0.0, 1e-05]
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.estimation.base import ESTIMATE_FIELDS
from hil.recording.reader import RunRecording


@dataclass(frozen=True)
class RunArrays:
    """The arrays of a recording.

    ``samples``: ``(n, n_channels)`` as captured (ADC counts or float32 full scale);
    ``sample_index``: ``(n,)`` board sample index of each row; ``time_s``: ``(n,)`` seconds
    from the schedule's t = 0 (``origin_sample``); ``estimates``, ``telemetry``, ``events``:
    column name -> ``(rows,)`` array; ``gaps``: ``(first missing index, count)`` pairs.
    """

    fs_hz: float
    origin_sample: int
    samples: NDArray[Any]
    sample_index: NDArray[np.int64]
    estimates: dict[str, NDArray[Any]] = field(default_factory=dict)
    telemetry: dict[str, NDArray[Any]] = field(default_factory=dict)
    events: dict[str, NDArray[Any]] = field(default_factory=dict)
    gaps: list[tuple[int, int]] = field(default_factory=list)

    @property
    def time_s(self) -> NDArray[np.float64]:
        """Seconds of each sample row from the schedule's t = 0."""
        return np.asarray((self.sample_index - self.origin_sample) / self.fs_hz)


def _columns(rows: list[Any], names: tuple[str, ...]) -> dict[str, NDArray[Any]]:
    return {name: np.asarray([getattr(r, name) for r in rows]) for name in names}


def load_arrays(path: str | Path) -> RunArrays:
    """Read the recording at ``path`` into a :class:`RunArrays`."""
    with RunRecording.open(path) as rec:
        blocks = rec.samples()
        if blocks:
            samples = np.concatenate([b.data for b in blocks], axis=0)
            index = np.concatenate(
                [np.arange(b.first_index, b.stop_index, dtype=np.int64) for b in blocks]
            )
        else:
            samples = np.zeros((0, rec.metadata.n_channels), dtype=rec.metadata.sample_dtype)
            index = np.zeros(0, dtype=np.int64)
        return RunArrays(
            fs_hz=rec.fs_hz,
            origin_sample=rec.origin_sample,
            samples=samples,
            sample_index=index,
            estimates=_columns(rec.estimates(), tuple(ESTIMATE_FIELDS)),
            telemetry=_columns(
                rec.telemetry(),
                ("host_time_s", "sample_index", "position_m", "velocity_mps", "state", "reply_s"),
            ),
            events=_columns(rec.events(), ("kind", "sample_index", "length", "text")),
            gaps=rec.gaps(),
        )
