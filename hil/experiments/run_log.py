"""What a finished tank run puts in its ``run.log``: the outcome, the summary, the files.

The run itself logs as it goes (the recording's events, gaps and alarms through
:mod:`hil.recording.writer`); this adds the end: every summary figure at INFO, the error that
stopped the run at ERROR, and the files written.
"""

from __future__ import annotations

import logging
from typing import Any

_LOG = logging.getLogger("hil.run")


def log_outcome(outcome: Any, summary: dict[str, Any]) -> None:
    """Log the end of a run: ``outcome`` (a :class:`~hil.experiments.tank_run.RunOutcome`)
    and its ``summary`` (:func:`~hil.experiments.run_scoring.summarize`)."""
    if outcome.error:
        _LOG.error("run stopped: %s", outcome.error)
    elif outcome.interrupted:
        _LOG.warning("run interrupted by the user")
    for key, value in summary.items():
        _LOG.info("summary %s = %s", key, value)
    for path in sorted(p.name for p in outcome.folder.iterdir()):
        _LOG.debug("run folder holds %s", path)
    _LOG.info("run folder: %s", outcome.folder)
