"""The time–codeword map of a recording, computed by the watch server itself.

``run.h5`` stores no codeword sums, so :class:`LiveCodewordMap` runs the recording's live
receiver (GCAS, with its recorded settings, through the same :class:`ReceiverFeed` as live
and replay) over the recorded samples, picking up where it stopped at each
:meth:`~LiveCodewordMap.update`, and keeps the map it hands out (``on_map``) max-pooled into
bins of half a hop. Costs about what the run's own receiver costs, so it is opt-in
(``hil watch --map``).
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.recording import RunRecording
from hil.recording.replay import ReceiverFeed, build_receiver, replay_setup

MAX_SENT_COLUMNS = 1500
"""Map columns sent to the page at most: longer maps are max-pooled to fit."""
FLOOR_DB = -30.0
"""The map's floor, dB re its maximum."""


def pool_columns(
    t_s: NDArray[np.float64], p: NDArray[np.float64], bin_s: float
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Max-pool map rows (times ``t_s`` s, shape ``(n,)``, ascending; ``p`` shape ``(n, J)``)
    into bins ``floor(t / bin_s)``: the bins (shape ``(b,)``) and their maxima ``(b, J)``.

    >>> b, m = pool_columns(np.array([0.0, 0.4, 1.1]), np.array([[1.0, 2], [3, 0], [5, 6]]), 1.0)
    >>> b.tolist(), m.tolist()
    ([0, 1], [[3.0, 2.0], [5.0, 6.0]])
    """
    bins = np.floor(np.asarray(t_s) / bin_s).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])
    return bins[starts], np.maximum.reduceat(np.asarray(p, dtype=np.float64), starts, axis=0)


class LiveCodewordMap:
    """The recording's time–codeword map, extended by each :meth:`update`.

    ``lock`` guards the recording (shared with the other readers of the same file).
    :class:`ConfigError` when the recording has no live receiver handing out a map.
    """

    def __init__(self, recording: RunRecording, lock: threading.Lock) -> None:
        self._rec = recording
        self._lock = lock
        live = recording.metadata.receiver
        if live is None or live.name not in ("gcas", "gcas-mti", "gcas-bg"):
            raise ConfigError(
                "--map",
                None if live is None else live.name,
                "a recording whose live receiver is gcas, gcas-mti or gcas-bg"
                " (those with a time–codeword map)",
                "watch it without --map",
            )
        setup = replay_setup(recording)
        schedule = recording.schedule()
        self.bin_s = schedule.hop_s / 2.0
        """Width of a map column, s (half a hop)."""
        self.n_codewords = schedule.period_hops
        self._bins: list[NDArray[np.int64]] = []
        self._cols: list[NDArray[np.float64]] = []
        self._result_lock = threading.Lock()
        self.error = ""
        """Why the map stopped growing (set by :meth:`follow`), empty while it is fine."""
        self._feed = ReceiverFeed(
            build_receiver(setup, schedule, recording.fs_hz, on_map=self._on_map),
            origin=recording.origin_sample,
            channel=setup.channel,
            scale=setup.scale,
        )

    def _on_map(self, t_s: NDArray[Any], p: NDArray[Any], speed: Any) -> None:
        if len(t_s) == 0:
            return
        bins, cols = pool_columns(np.asarray(t_s, dtype=np.float64), np.asarray(p), self.bin_s)
        with self._result_lock:
            if self._bins and self._bins[-1][-1] == bins[0]:
                self._cols[-1][-1] = np.maximum(self._cols[-1][-1], cols[0])
                bins, cols = bins[1:], cols[1:]
            if bins.size:
                self._bins.append(bins)
                self._cols.append(cols)

    @property
    def computed_to_s(self) -> float:
        """Receiver time (s) up to which samples have been fed."""
        return (self._feed.next_index - self._feed.origin) / self._rec.fs_hz

    def update(self, max_frames: int = 65536) -> int:
        """Feed the samples recorded since the last update (up to the writer's last flush)
        to the receiver; returns the number of sample frames fed."""
        fed = 0
        while True:
            with self._lock:
                block = next(self._rec.iter_blocks(max_frames, start=self._feed.next_index), None)
            if block is None:
                return fed
            self._feed.feed(block.first_index, block.data)
            fed += block.data.shape[0]

    def follow(self, stop: threading.Event, interval_s: float = 0.5) -> None:
        """:meth:`update` until ``stop`` is set, waiting ``interval_s`` (s) between updates
        that found nothing new (a server thread's loop). An error ends it, kept in
        :attr:`error` for the page."""
        try:
            while not stop.is_set():
                if self.update() == 0:
                    stop.wait(interval_s)
        except Exception as exc:  # any failure: shown on the page, the server goes on
            self.error = f"the time–codeword map stopped: {exc}"

    def snapshot(self) -> dict[str, Any]:
        """The map so far for the page: column start times ``t_s`` (s), ``db`` rows of
        ``n_codewords`` values (dB re the map's maximum, floor :data:`FLOOR_DB`), pooled to at
        most :data:`MAX_SENT_COLUMNS` columns."""
        with self._result_lock:
            bins = np.concatenate(self._bins) if self._bins else np.zeros(0, np.int64)
            cols = np.concatenate(self._cols) if self._cols else np.zeros((0, self.n_codewords))
        k = max(1, -(-bins.size // MAX_SENT_COLUMNS))
        if k > 1:
            bins, cols = pool_columns(bins.astype(np.float64), cols, float(k))
            bins = bins * k
        top = float(cols.max()) if cols.size else 1.0
        db = 10.0 * np.log10(np.maximum(cols / max(top, 1e-300), 10 ** (FLOOR_DB / 10)))
        return {
            "t_s": (bins * self.bin_s).tolist(),
            "column_s": self.bin_s * k,
            "db": np.round(db, 1).tolist(),
            "computed_to_s": self.computed_to_s,
            "error": self.error,
        }
