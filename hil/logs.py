"""Logging for the ``hil`` command: stdlib :mod:`logging` under the ``hil`` logger.

Library modules log through ``logging.getLogger(__name__)`` and never configure anything;
the command line configures once (:func:`configure_logging`: ``--log-level``,
``--log-file``) and a run folder gets its own complete ``run.log`` (:func:`run_log`, every
message at DEBUG and above while the run lasts, whatever ``--log-level`` says).

>>> LEVELS
('debug', 'info', 'warning', 'error')
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

LEVELS = ("debug", "info", "warning", "error")
FORMAT = "%(asctime)s %(levelname)-7s %(name)s: %(message)s"
CONSOLE_FORMAT = "hil: %(levelname)s: %(message)s"
RUN_LOG = "run.log"

_LOGGER = logging.getLogger("hil")


def _is_cli_handler(handler: logging.Handler) -> bool:
    """True for a handler :func:`configure_logging` installed (replaced on the next call)."""
    return getattr(handler, "_hil_cli", False) is True


def configure_logging(level: str = "warning", log_file: str | Path | None = None) -> None:
    """Show ``hil`` messages at ``level`` and above on stderr, and append them to ``log_file``.

    Replaces the handlers of an earlier call (the command can run many times in one
    process, as in the tests). ``level``: one of :data:`LEVELS`.
    """
    if level not in LEVELS:
        from hil.errors import ConfigError

        raise ConfigError("--log-level", level, f"one of {', '.join(LEVELS)}")
    threshold = getattr(logging, level.upper())
    reset_logging()
    console = logging.StreamHandler(sys.stderr)
    console.setFormatter(logging.Formatter(CONSOLE_FORMAT))
    handlers: list[logging.Handler] = [console]
    if log_file is not None:
        file_handler = logging.FileHandler(log_file, encoding="utf-8")
        file_handler.setFormatter(logging.Formatter(FORMAT))
        handlers.append(file_handler)
    for handler in handlers:
        handler.setLevel(threshold)
        handler._hil_cli = True  # type: ignore[attr-defined]
        _LOGGER.addHandler(handler)
    _LOGGER.setLevel(logging.DEBUG)
    _LOGGER.propagate = False


def reset_logging() -> None:
    """Remove and close the handlers :func:`configure_logging` installed."""
    for handler in [h for h in _LOGGER.handlers if _is_cli_handler(h)]:
        _LOGGER.removeHandler(handler)
        handler.close()


@contextmanager
def run_log(folder: Path) -> Iterator[Path]:
    """Write every ``hil`` message (DEBUG and above) into ``folder/run.log`` meanwhile.

    Yields the log's path. The folder is created if needed; the file is appended to, so a
    resumed run keeps its history.
    """
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / RUN_LOG
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setFormatter(logging.Formatter(FORMAT))
    handler.setLevel(logging.DEBUG)
    previous = _LOGGER.level
    _LOGGER.addHandler(handler)
    _LOGGER.setLevel(logging.DEBUG)
    try:
        yield path
    finally:
        _LOGGER.removeHandler(handler)
        _LOGGER.setLevel(previous)
        handler.close()
