"""What C libraries print on the process's stderr (file descriptor 2), held back.

PortAudio probes every host API when it initialises; its JACK host API then has libjack
print several lines ("Cannot connect to server socket", "JackShmReadWritePtr::...") on
fd 2 when no JACK server runs, which is normal and says nothing a user must act on.
:func:`held_c_stderr` sends fd 2 to a temporary file for the length of a block and logs
what came at debug level, so a command's own messages stay readable. Python's
``sys.stderr`` writes of the block go the same way when it is fd 2 (it is flushed first).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import tempfile
from collections.abc import Iterator

_LOG = logging.getLogger(__name__)


class HeldText:
    """The text held back by :func:`held_c_stderr`, once its block has ended."""

    def __init__(self) -> None:
        self.text = ""


@contextlib.contextmanager
def held_c_stderr(what: str) -> Iterator[HeldText]:
    r"""Within the block, fd 2 writes go to a temporary file; after it, they are logged at
    debug level (``what``: whose output, for the log) and handed back as ``.text``.

    >>> import os
    >>> with held_c_stderr("a doctest") as held:
    ...     _ = os.write(2, b"Cannot connect to server socket\n")
    >>> held.text
    'Cannot connect to server socket\n'
    """
    held = HeldText()
    fd = 2  # where C libraries write, whatever Python's sys.stderr is at the moment
    with tempfile.TemporaryFile() as sink:
        if sys.stderr is not None:
            with contextlib.suppress(Exception):
                sys.stderr.flush()
        saved = os.dup(fd)
        os.dup2(sink.fileno(), fd)
        try:
            yield held
        finally:
            if sys.stderr is not None:
                with contextlib.suppress(Exception):
                    sys.stderr.flush()
            os.dup2(saved, fd)
            os.close(saved)
            sink.seek(0)
            held.text = sink.read().decode(errors="replace")
    if held.text:
        _LOG.debug("%s printed on stderr: %s", what, held.text.strip())
