"""How late this process's threads wake: a probe for the real-time tests that must tell a
fault of the code under test from a machine that kept the process off its CPUs.

A :class:`LatenessProbe` is a thread that sleeps ``period_s`` again and again and keeps how
much later than asked each wake-up came. A ready thread of this process waits about as long
for a CPU, so a real-time test whose deadline is ``D`` seconds can tell a miss the machine
caused (the probe saw the process kept away for a good part of ``D``) from one of its own
(it did not). The probe measures; it never decides a test's outcome by itself.
"""

from __future__ import annotations

import threading
import time
from types import TracebackType


class LatenessProbe:
    """Use as a context manager around the real-time part of a test; then read
    :attr:`longest_s` (the longest a wake-up came late, s) and :attr:`wakeups`."""

    def __init__(self, period_s: float = 0.005) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s = {period_s!r} must be > 0 s")
        self.period_s = float(period_s)
        self.longest_s = 0.0
        self.wakeups = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lateness-probe", daemon=True)

    def _run(self) -> None:
        due = time.monotonic() + self.period_s
        while not self._stop.wait(max(due - time.monotonic(), 0.0)):
            now = time.monotonic()
            self.longest_s = max(self.longest_s, now - due)
            self.wakeups += 1
            due = now + self.period_s

    def __enter__(self) -> LatenessProbe:
        self._thread.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._stop.set()
        self._thread.join()
