"""``os.environ`` set for a while, then put back: the BLAS thread variables a process pool's
workers inherit (:func:`hil.evaluation.worker.pinned_blas_env`), a JACK server's name for
this process's clients (the tests' module- and session-scoped fixtures, which pytest's
``monkeypatch`` cannot serve)."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator


@contextlib.contextmanager
def environment(**values: str) -> Iterator[None]:
    """``os.environ`` with ``values`` set; each name back to its value (or unset) on exit."""
    saved = {name: os.environ.get(name) for name in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
