"""Collection rules for the whole suite (pyproject's testpaths run doctests over the packages).

``hil.bluesky`` needs the optional ``bluesky`` extra: without it, its modules are not imported
for their doctests (``tests/bluesky`` says why it skips, or fails under
``HIL_REQUIRE_SYSTEM_DEPS=1``).
"""

from __future__ import annotations

import importlib.util

collect_ignore_glob: list[str] = []
if importlib.util.find_spec("bluesky") is None or importlib.util.find_spec("ophyd_async") is None:
    collect_ignore_glob.append("hil/bluesky/*")
