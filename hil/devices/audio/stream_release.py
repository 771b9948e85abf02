"""Stopping and closing a PortAudio stream without hanging on a host that went away.

PortAudio's stop, abort and close wait for the host API's audio thread to acknowledge them.
When that thread is gone they do not return in useful time: PortAudio's JACK host API
(``pa_jack.c``, PortAudio 19.7) marks every stream inactive when its server shuts down,
without calling the stream's finished callback, and ``Pa_StopStream``/``Pa_AbortStream``
(and ``Pa_CloseStream``, which aborts a running stream first) then wait 10 minutes for the
dead server's process thread; after that wait, closing unregisters the stream's ports from
the dead client, an assertion that aborts the process. ``Pa_Terminate`` (sounddevice calls
it at exit) closes every stream still open, and deactivates the JACK client, whose
assertion also fails once its server has died.

So a stream is stopped and closed on a daemon thread (:func:`call_bounded`), waited for at
most :func:`release_timeout_s` (derived from the stream's own longest wait between
callbacks); a stream that stopped without finishing (its host took it away) gets no call at
all. Either
way a stream that cannot be released is *abandoned*: referenced for the life of the process
(its callbacks stay valid), and PortAudio is no longer terminated at exit, so the
interpreter exits at once; the operating system releases what PortAudio held. In this
process PortAudio cannot be re-initialised afterwards (:func:`abandoned_why` says why).
"""

from __future__ import annotations

import atexit
import logging
import threading
from collections.abc import Callable
from typing import Any

_LOG = logging.getLogger(__name__)

#: Least wait for a stop or close, s. Measured on a live dummy JACK server (192 kHz,
#: 1024-frame periods, 10 streams at load 7.8-11.4 on 2 cores): stop 32-69 ms, close
#: 0.5-53 ms; 2 s is 29 times the longest.
RELEASE_FLOOR_S = 2.0
#: The wait in units of the stream's longest gap between two callbacks. Measured there:
#: stop and close each took at most 4.5 of those gaps (the audio thread has to run the
#: stop through, then flush the last block); 100 leaves 20 times that for a busier host.
RELEASE_GAPS = 100.0

_abandoned: list[Any] = []
_abandoned_why: list[str] = []
_lock = threading.Lock()


def release_timeout_s(longest_gap_s: float) -> float:
    """How long to wait for a stop or close of a stream whose callbacks came at most
    ``longest_gap_s`` seconds apart: :data:`RELEASE_GAPS` such gaps, at least
    :data:`RELEASE_FLOOR_S`.

    >>> release_timeout_s(0.005), release_timeout_s(0.05)
    (2.0, 5.0)
    """
    return max(RELEASE_FLOOR_S, RELEASE_GAPS * longest_gap_s)


def call_bounded(call: Callable[[], object], timeout_s: float, name: str) -> bool:
    """Run ``call`` on a daemon thread called ``name``; True if it returned within
    ``timeout_s`` seconds (an exception it raised is raised here), False if it is still
    running (it is left to finish, or not, on its own thread)."""
    errors: list[BaseException] = []

    def run() -> None:
        try:
            call()
        except BaseException as exc:  # handed to the caller's thread
            errors.append(exc)

    worker = threading.Thread(target=run, name=name, daemon=True)
    worker.start()
    worker.join(timeout_s)
    if worker.is_alive():
        return False
    if errors:
        raise errors[0]
    return True


def abandon(stream: Any, why: str) -> None:
    """Give up on ``stream``: keep it referenced until the process exits, and do not let
    sounddevice terminate PortAudio at exit (it would wait on the stream, or abort on its
    dead host). ``why`` is logged and returned by :func:`abandoned_why`."""
    import sounddevice

    with _lock:
        if not _abandoned:
            atexit.unregister(sounddevice._exit_handler)
        _abandoned.append(stream)
        _abandoned_why.append(why)
    _LOG.warning("PortAudio stream abandoned: %s", why)


def abandoned_why() -> str | None:
    """Why this process holds an abandoned stream (the first reason), None when it holds
    none: PortAudio can then be re-initialised."""
    with _lock:
        return _abandoned_why[0] if _abandoned_why else None
