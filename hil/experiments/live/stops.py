"""Why a live run stops, found as early as it can be, and recorded.

- :class:`StopSignals`: SIGTERM and SIGHUP stop a run as Ctrl-C does (a safe stop, the summary
  written), raised in the run's thread as :class:`RunInterrupted`.
- :class:`LinkWatch`: a board whose link dropped and did not come back within
  :data:`LOST_AFTER_S` of the driver clock is lost: the run stops with its name and what to
  check, instead of waiting for samples until ``run.max_duration_s``.
- :class:`DeviceLostError`: a device that stopped answering, named, with what to check.
- :func:`stop_text`: the recording's event for a stop, whatever its reason.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from types import FrameType, TracebackType
from typing import Any

from hil.acquisition.annotations import AnnotationKind
from hil.acquisition.device import Annotations
from hil.errors import DeviceLost
from hil.interrupts import STOP_SIGNALS, RunInterrupted, deferring

#: Driver-clock seconds a board's link may stay down (its driver reconnecting: a USB glitch
#: comes back within a few hundred ms) before the run counts the board as lost.
LOST_AFTER_S = 0.5

__all__ = [
    "LOST_AFTER_S",
    "STOP_SIGNALS",
    "DeviceLostError",
    "LinkWatch",
    "RunInterrupted",
    "StopSignals",
    "stop_text",
]


class DeviceLostError(DeviceLost, RuntimeError):
    """A device of the run stopped answering (its process killed, its cable out, its
    power off). The message names the device and its URL and says what to check."""

    def __init__(self, device: str, url: str, why: str, check: str) -> None:
        super().__init__(f"{device} {url} lost: {why}; check {check}", url=url)
        self.device = device


class StopSignals:
    """While active (a context manager), SIGTERM and SIGHUP raise :class:`RunInterrupted` in
    the main thread and SIGINT raises KeyboardInterrupt, which a run handles as Ctrl-C; the
    previous handlers come back on exit. The first of them switches all three to being noted
    (:attr:`ignored`) before it raises, so a second Ctrl-C or signal, however soon, cannot
    break off the safe stop the first one started (``kill -9`` still ends the process).
    Outside the main thread (signals cannot be set there) it does nothing."""

    def __init__(self) -> None:
        self._previous: dict[signal.Signals, Any] = {}
        #: Stop signals that came during the safe stop (names).
        self.ignored: list[str] = []

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, *STOP_SIGNALS):
                self._previous[sig] = signal.signal(sig, self._raise)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()

    def stopping(self) -> None:
        """The run is stopping safely: a further stop signal or Ctrl-C is noted, not raised,
        so it cannot break off the safe stop (``kill -9`` still ends the process at once)."""
        for sig in self._previous:
            signal.signal(sig, self._note)

    def _note(self, signum: int, frame: FrameType | None) -> None:
        self.ignored.append(signal.Signals(signum).name)

    def _raise(self, signum: int, frame: FrameType | None) -> None:
        if deferring(signum):
            return  # raised again at the end of a step that must be done whole
        self.stopping()
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise RunInterrupted(signal.Signals(signum).name)


class LinkWatch:
    """Whether a device's link is lost, from its annotations (DISCONNECT, RECONNECT) and a
    clock (driver seconds): down for :data:`LOST_AFTER_S` without a reconnect is lost.

    >>> from hil.acquisition.annotations import Annotation, AnnotationLog
    >>> log, t = AnnotationLog(), [0.0]
    >>> watch = LinkWatch(log, lambda: t[0])
    >>> log.add(Annotation(500, AnnotationKind.DISCONNECT, 0, "read failed: EIO"))
    >>> watch.lost(), (t.__setitem__(0, 0.49), watch.lost())[1]
    (None, None)
    >>> t[0] = 0.51
    >>> watch.lost()
    'its link dropped at sample 500 (read failed: EIO) and has not come back for 0.51 s'
    """

    def __init__(self, annotations: Annotations, now: Callable[[], float]) -> None:
        self._annotations = annotations
        self._now = now
        self._down_since: float | None = None

    def lost(self) -> str | None:
        """Why the link is lost, or None while it is up (or down for less than
        :data:`LOST_AFTER_S`)."""
        links = [
            a
            for a in self._annotations.all()
            if a.kind in (AnnotationKind.DISCONNECT, AnnotationKind.RECONNECT)
        ]
        if not links or links[-1].kind is AnnotationKind.RECONNECT:
            self._down_since = None
            return None
        now = self._now()
        if self._down_since is None:
            self._down_since = now
        down = now - self._down_since
        if down < LOST_AFTER_S:
            return None
        last = links[-1]
        return (
            f"its link dropped at sample {last.sample_index} ({last.detail}) and has not come"
            f" back for {down:.2f} s"
        )


def stop_text(*, interrupted: bool, error: str) -> tuple[str, str]:
    """The recording's event ``(kind, text)`` for a run's stop: every run ends with one, so a
    recording tells how its run ended (one without it was killed before it could write it).

    >>> stop_text(interrupted=False, error="")
    ('note', 'stop: completed')
    >>> stop_text(interrupted=True, error="interrupted (SIGTERM)")
    ('alarm', 'stop: interrupted (SIGTERM)')
    >>> stop_text(interrupted=False, error="DeviceLostError: board sim://board lost: ...")
    ('alarm', 'stop: error: DeviceLostError: board sim://board lost: ...')
    """
    if interrupted:
        return "alarm", f"stop: {error or 'interrupted'}"
    if error:
        return "alarm", f"stop: error: {error}"
    return "note", "stop: completed"
