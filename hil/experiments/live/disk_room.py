"""Room left for a growing recording, so that a full disk stops a run while its recording can
still be closed whole.

A recording that hits a full disk (or the process's file-size limit, ``ulimit -f``) in the
middle of a write cannot take its stop event or close: HDF5 leaves it unreadable. So the run
checks, before the first block of samples and then once every :data:`CHECK_EVERY_S` of
samples, the bytes the recording may still grow by (the disk's free space for this user and
the file-size limit minus the file's size) against a reserve (:func:`reserve_bytes`: what
closing needs) and stops with :class:`RecordingSpaceError` while the reserve is still there.
"""

from __future__ import annotations

import errno
import os
import resource
from pathlib import Path

#: Seconds of samples the reserve holds: the writer buffers up to one second between its
#: flushes, and the last blocks of the stop follow.
RESERVE_SIGNAL_S = 2.0
#: Bytes the reserve holds besides the samples: HDF5's metadata, the tables' last chunks
#: (events, telemetry, estimates), the stop event.
RESERVE_FIXED_BYTES = 2 * 1024 * 1024
#: Seconds of samples a recording takes between two checks of its room (a block arrives
#: every few milliseconds, and a check asks the file system twice): a fortieth of the
#: reserve, so the reserve left at a check is at least 1.95 s of samples.
CHECK_EVERY_S = 0.05


class RecordingSpaceError(OSError):
    """The recording's disk (or the file-size limit) leaves less room than closing it needs;
    the message says how much is left and what to do."""

    def __init__(self, text: str) -> None:
        super().__init__(errno.ENOSPC, text)

    def __str__(self) -> str:
        return str(self.strerror)


def reserve_bytes(fs_hz: float, n_channels: int, itemsize: int) -> int:
    """Bytes kept for closing a recording of ``n_channels`` samples of ``itemsize`` bytes at
    ``fs_hz``: :data:`RESERVE_SIGNAL_S` of them plus :data:`RESERVE_FIXED_BYTES`.

    >>> reserve_bytes(192000.0, 2, 2) == 2 * 192000 * 2 * 2 + 2 * 1024 * 1024
    True
    """
    return int(RESERVE_SIGNAL_S * fs_hz * n_channels * itemsize) + RESERVE_FIXED_BYTES


def room_left(path: Path) -> tuple[int, str]:
    """Bytes the file at ``path`` may still grow by, and what bounds it: the free space of
    its disk for this user, or the process's file-size limit minus its size.

    >>> import tempfile
    >>> room, bound = room_left(Path(tempfile.mkdtemp()) / "run.h5")
    >>> room > 0 and bound in ("free space on its disk", "the file-size limit (ulimit -f)")
    True
    """
    disk = os.statvfs(path.parent)
    free = disk.f_bavail * disk.f_frsize
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    if limit == resource.RLIM_INFINITY:
        return free, "free space on its disk"
    size = path.stat().st_size if path.exists() else 0
    by_limit = max(0, limit - size)
    if by_limit < free:
        return by_limit, "the file-size limit (ulimit -f)"
    return free, "free space on its disk"


def check_room(path: Path, reserve: int) -> None:
    """Raise :class:`RecordingSpaceError` when ``path`` may grow by less than ``reserve``
    bytes more (:func:`room_left`)."""
    room, bound = room_left(path)
    if room < reserve:
        raise RecordingSpaceError(
            f"{path.name} has {room / 1e6:.3g} MB left to grow ({bound}), less than the"
            f" {reserve / 1e6:.3g} MB kept to close it readable: the run stopped there; free"
            " space (or raise the limit) and run again"
        )
