"""Short garbage-collector passes during a live run (``gc.freeze`` of the setup's objects)."""

from __future__ import annotations

import gc
from types import TracebackType


class HeapFreeze:
    """Keeps the objects alive at :meth:`start` out of the collector's full passes until
    :meth:`stop` (also a context manager).

    A full (generation 2) collection walks every tracked object with the GIL held. With
    numba, SciPy and a receiver loaded that is about 150 000 objects and 75 ms, long enough
    for the board's reader thread to fall 75 ms behind the stream; a live run hit one such
    pass every 20–30 s. The setup's objects (modules, compiled kernels, receiver tables)
    live for the whole run anyway: frozen, a full pass walks only what the run allocates.
    Objects frozen are never collected while frozen, so freeze after setup, not before.

    ``collect``: collect once before freezing (default), so the setup's garbage is freed, not
    kept frozen with it. That pass walks the whole heap (about 0.05 s of CPU); a run on
    virtual time, where no stream waits on the collector, passes False and keeps the setup's
    garbage until :meth:`stop` instead (the collector frees it at its next full pass after).

    >>> import gc
    >>> with HeapFreeze():
    ...     gc.get_freeze_count() > 0
    True
    """

    def __init__(self, *, collect: bool = True) -> None:
        self._frozen = False
        self._collect = bool(collect)

    def start(self) -> None:
        """Collect once (unless ``collect`` is False), then freeze everything alive now (a
        second start does nothing)."""
        if self._frozen:
            return
        if self._collect:
            gc.collect()
        gc.freeze()
        self._frozen = True

    def stop(self) -> None:
        """Hand the frozen objects back to the collector (idempotent)."""
        if self._frozen:
            gc.unfreeze()
            self._frozen = False

    def __enter__(self) -> HeapFreeze:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
