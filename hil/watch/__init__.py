"""``hil watch``: a live view of a run recording in the browser.

A small stdlib HTTP server (:mod:`hil.watch.server`) serves one static page
(``page.html``: vanilla JavaScript, canvas plots, nothing fetched from the internet) and the
JSON it polls, built from a ``run.h5`` by :class:`hil.watch.api.WatchData`: run metadata,
device status, events and alarms, counts, the estimates (incrementally), the truth from the
stage telemetry and the decoded codewords against time. The recording is opened as an SWMR
reader, so the page follows a run while ``hil tank-run`` writes it (what the writer last
flushed, at least once a second) and shows a finished run the same way.
"""

from __future__ import annotations

from hil.watch.api import WatchData
from hil.watch.server import WatchServer

__all__ = ["WatchData", "WatchServer"]
