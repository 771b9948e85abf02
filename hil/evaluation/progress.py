"""A plain-text progress bar with rate and ETA for stderr.

On a terminal the line is redrawn in place (carriage return); otherwise (a log file, CI) a full
line is printed at most every ``interval_s`` seconds and once at the end, so logs stay short.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO


def format_duration(seconds: float) -> str:
    """``H:MM:SS`` (``--:--:--`` when unknown).

    >>> format_duration(3725.4), format_duration(float("inf"))
    ('1:02:05', '--:--:--')
    """
    if not seconds < float("inf") or seconds < 0:
        return "--:--:--"
    s = int(round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


class Progress:
    """Counts finished trials and shows ``done/total``, percent, rate, ETA and failures.

    ``already_done`` trials (a resumed sweep) count towards ``done`` but not towards the rate.
    ``clock`` (seconds, monotonic) and ``tty`` can be injected for tests.

    >>> import io
    >>> t = [0.0]
    >>> out = io.StringIO()
    >>> p = Progress(4, label="demo", stream=out, tty=False, interval_s=10, clock=lambda: t[0])
    >>> t[0] = 2.0; p.update(ok=True)
    >>> t[0] = 4.0; p.update(ok=False)
    >>> p.close()
    >>> print(out.getvalue(), end="")
    demo [##########----------]   2/4   50.0%  0.50 trials/s  ETA 0:00:04  1 failed
    """

    def __init__(
        self,
        total: int,
        *,
        already_done: int = 0,
        label: str = "sweep",
        stream: TextIO | None = None,
        tty: bool | None = None,
        interval_s: float = 10.0,
        width: int = 20,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.total = total
        self.done = already_done
        self.failed = 0
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        self.tty = self.stream.isatty() if tty is None else tty
        self.interval_s = interval_s
        self.width = width
        self._clock = clock
        self._start = clock()
        self._start_done = already_done
        self._last_print = self._start
        # Trials count when the last line was shown; -1 so that close() always shows one.
        self._printed = -1

    def update(self, ok: bool) -> None:
        """One more trial finished (``ok`` False: it failed)."""
        self.done += 1
        self.failed += not ok
        now = self._clock()
        if self.tty:
            self.stream.write("\r" + self.line(now))
            self.stream.flush()
            self._printed = self.done
        elif now - self._last_print >= self.interval_s:
            self._emit(now)

    def close(self) -> None:
        """Final state: end the redrawn line, or print the last line if not yet shown."""
        if self.tty:
            if self._printed == self.done:
                self.stream.write("\n")
            else:
                self.stream.write("\r" + self.line(self._clock()) + "\n")
            self.stream.flush()
        elif self._printed != self.done:
            self._emit(self._clock())

    def _emit(self, now: float) -> None:
        self.stream.write(self.line(now) + "\n")
        self.stream.flush()
        self._last_print = now
        self._printed = self.done

    def line(self, now: float) -> str:
        """The progress text at time ``now`` (no line ending)."""
        frac = self.done / self.total if self.total else 1.0
        filled = int(round(frac * self.width))
        bar = "#" * filled + "-" * (self.width - filled)
        ran = self.done - self._start_done
        elapsed = now - self._start
        rate = ran / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else float("inf")
        digits = len(str(self.total))
        text = (
            f"{self.label} [{bar}] {self.done:>{digits + 2}}/{self.total}  {100 * frac:5.1f}%  "
            f"{rate:.2f} trials/s  ETA {format_duration(eta)}"
        )
        if self.failed:
            text += f"  {self.failed} failed"
        return text
