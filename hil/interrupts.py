"""Stop signals from a command's first instruction.

``hil`` installs :func:`raise_on_stop_signals` before anything else (parsing, imports of
the command, a run's set-up): SIGTERM and SIGHUP then raise :class:`RunInterrupted` in the
main thread exactly as Ctrl-C raises KeyboardInterrupt, so whatever phase they reach, the
command stops the way it stops on Ctrl-C (a run safely, with its stop recorded; anything
else with one line and exit status 130), never by the signal's default action that leaves
a recording without its stop event. Light on purpose: ``hil --help`` imports it.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from types import FrameType

#: The signals that stop a command as Ctrl-C does, besides SIGINT.
STOP_SIGNALS: tuple[signal.Signals, ...] = (signal.SIGTERM, signal.SIGHUP)


class RunInterrupted(KeyboardInterrupt):
    """A stop signal arrived (SIGTERM, SIGHUP): handled exactly as Ctrl-C."""

    def __init__(self, signal_name: str) -> None:
        super().__init__(signal_name)
        self.signal_name = signal_name


def interruption(exc: KeyboardInterrupt) -> str:
    """What interrupted: the signal's name, or ``Ctrl-C``.

    >>> interruption(RunInterrupted("SIGTERM")), interruption(KeyboardInterrupt())
    ('SIGTERM', 'Ctrl-C')
    """
    return exc.signal_name if isinstance(exc, RunInterrupted) else "Ctrl-C"


def interruption_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or stop signal behind ``exc``, if any: a handler's exception raised while
    compiled code was running (a numba kernel) comes out as that call's ``SystemError``
    ("returned a result with an exception set") caused by it, not as itself.

    >>> try:
    ...     raise SystemError("a result with an exception set") from RunInterrupted("SIGHUP")
    ... except SystemError as err:
    ...     interruption(interruption_behind(err)), interruption_behind(ValueError())
    ('SIGHUP', None)
    """
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            return cause
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return None


#: Stop signals held by :func:`stops_deferred` (signal numbers), and how deep it is entered.
_pending: list[int] = []
_depth = [0]


@contextlib.contextmanager
def stops_deferred() -> Iterator[None]:
    """A stop signal or Ctrl-C that arrives meanwhile takes effect at the end of the block,
    not inside it: for a step that must be done whole (a recording's file created with every
    table, or not at all). Main thread only (where signal handlers run); elsewhere it
    changes nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _depth[0] += 1
    try:
        yield
    finally:
        _depth[0] -= 1
        if _depth[0] == 0 and _pending:
            signum = _pending[0]
            _pending.clear()
            signal.raise_signal(signum)  # the handler in force acts on it now


def deferring(signum: int) -> bool:
    """Whether a handler must hold ``signum`` (inside :func:`stops_deferred`): then it is
    kept for the block's end and the handler returns at once."""
    if _depth[0] > 0 and threading.current_thread() is threading.main_thread():
        _pending.append(signum)
        return True
    return False


def _raise(signum: int, frame: FrameType | None) -> None:
    if deferring(signum):
        return
    raise RunInterrupted(signal.Signals(signum).name)


def raise_on_stop_signals() -> Callable[[], None]:
    """SIGTERM and SIGHUP raise :class:`RunInterrupted` from now on (main thread only;
    elsewhere nothing changes); returns the function that puts the previous handlers back."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = {sig: signal.signal(sig, _raise) for sig in STOP_SIGNALS}

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    return restore
