"""The bluesky tests need the optional ``bluesky`` extra (bluesky and ophyd-async): without it
they skip saying so, and fail under ``HIL_REQUIRE_SYSTEM_DEPS=1`` (CI installs the test extra,
which includes it)."""

from __future__ import annotations

import importlib.util
from collections.abc import Callable

import pytest


@pytest.fixture(autouse=True)
def _bluesky_installed(require_system: Callable[[bool, str], None]) -> None:
    missing = [m for m in ("bluesky", "ophyd_async") if importlib.util.find_spec(m) is None]
    require_system(
        not missing,
        f"{' and '.join(missing)} not installed: pip install 'cas-hil[bluesky]'",
    )


@pytest.fixture
def run_engine() -> object:
    """A RunEngine without SIGINT handlers (the suite's own process owns them); creating
    it starts the bluesky event loop the devices connect and move in."""
    from bluesky import RunEngine

    return RunEngine({}, context_managers=[])
