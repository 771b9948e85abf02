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

    >>> import gc
    >>> with HeapFreeze():
    ...     gc.get_freeze_count() > 0
    True
    """

    def __init__(self) -> None:
        self._frozen = False

    def start(self) -> None:
        """Collect once, then freeze everything alive now (a second start does nothing)."""
        if self._frozen:
            return
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
