"""What a live run records, and when: the recording is created once the loopback latency is
known (its origin is the receiver's sample 0, so a replay feeds the receiver exactly as live
did); what came before it (stage telemetry, the latency probe's blocks) is held and written
then. Telemetry and SYNC pairs are also kept in memory for the run's outcome.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hil.estimation.base import Estimate
from hil.experiments.live.disk_room import CHECK_EVERY_S, check_room, reserve_bytes
from hil.interrupts import stops_deferred
from hil.recording.records import RunEvent, StageTelemetry
from hil.recording.writer import RunWriter


class RunRecorder:
    """The run's recording at ``path``, opened by :meth:`open` with the options
    ``create_options`` (keyword arguments of :meth:`RunWriter.create` but the origin)."""

    def __init__(self, path: Path, create_options: dict[str, Any]) -> None:
        self.path = path
        self._options = create_options
        self.writer: RunWriter | None = None
        self._telemetry: list[StageTelemetry] = []  # until the writer exists
        self.sync_pairs: list[tuple[int, float]] = []  # every SYNC pair of the run
        self._sync_written = 0
        fs = float(create_options.get("fs_hz", 0.0))
        self._reserve = reserve_bytes(
            fs,
            int(create_options.get("n_channels", 1)),
            np.dtype(create_options.get("dtype", "int16")).itemsize,
        )
        #: Samples (per channel) between two checks of the room (CHECK_EVERY_S), and those
        #: taken since the last one (the first block is checked).
        self._check_every = int(CHECK_EVERY_S * fs)
        self._unchecked = self._check_every

    @property
    def open_(self) -> bool:
        """Whether the recording exists (the latency is known)."""
        return self.writer is not None

    def describe(self, instrument: Mapping[str, Mapping[str, Any]]) -> None:
        """What was connected (``device -> fields``), for the recording's NeXus entry: set
        before :meth:`open`."""
        self._options["instrument"] = instrument

    def open(self, origin_sample: int, note: RunEvent) -> None:
        """Create the recording with the receiver's sample 0 at ``origin_sample``; ``note``
        (the latency's) is its first event; the telemetry held so far is written. A stop
        (Ctrl-C, SIGTERM) meanwhile acts once the file exists whole, so the stop is recorded
        in it."""
        with stops_deferred():
            self.writer = RunWriter.create(self.path, origin_sample=origin_sample, **self._options)
        self.writer.append_event(note)
        for record in self._telemetry:
            self.writer.append_telemetry(record)
        self._telemetry.clear()

    def samples(self, first_index: int, data: np.ndarray[Any, Any]) -> None:
        """A captured block (from board index ``first_index``). Refused
        (:class:`~hil.experiments.live.disk_room.RecordingSpaceError`) when the disk or the
        file-size limit leaves less room than closing the recording needs: the run stops
        while its recording can still take its stop event and close readable. The room is
        checked before the first block and then once every
        :data:`~hil.experiments.live.disk_room.CHECK_EVERY_S` of samples."""
        if self.writer is not None:
            if self._unchecked >= self._check_every:
                check_room(self.path, self._reserve)
                self._unchecked = 0
            self.writer.append_samples(first_index, data)
            self._unchecked += len(data)

    def estimates(self, estimates: Sequence[Estimate]) -> None:
        """The receiver's estimates."""
        if self.writer is not None and estimates:
            self.writer.append_estimates(estimates)

    def telemetry(self, record: StageTelemetry) -> None:
        """A stage report (held until the recording exists)."""
        if self.writer is None:
            self._telemetry.append(record)
        else:
            self.writer.append_telemetry(record)

    def sync(self, collect: Callable[[list[tuple[int, float]]], None]) -> None:
        """Collect the new SYNC pairs (``collect`` appends them to the list it is given)
        and record those not yet written."""
        collect(self.sync_pairs)
        if self.writer is not None:
            for index, host_t in self.sync_pairs[self._sync_written :]:
                self.writer.append_sync(index, host_t)
            self._sync_written = len(self.sync_pairs)

    def map_telemetry_times(self, sample_index: Sequence[int]) -> None:
        """Every recorded stage report's board sample index, as the run's end maps them
        (:meth:`RunWriter.map_telemetry_times`)."""
        if self.writer is not None:
            self.writer.map_telemetry_times(sample_index)

    def events(self, events: Sequence[tuple[str, int, int, str]]) -> None:
        """Events ``(kind, sample_index, length, text)``."""
        if self.writer is not None:
            for kind, index, length, text in events:
                self.writer.append_event(RunEvent(kind, index, length, text))

    def flush(self) -> None:
        if self.writer is not None:
            self.writer.flush()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
