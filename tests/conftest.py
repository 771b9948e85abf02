"""Shared pytest configuration.

``--device-url`` runs the hardware tier of the suite against a real device; without it those
tests are skipped with a reason. ``HIL_REQUIRE_SYSTEM_DEPS=1`` (set by ``.ci/run`` after it
installs JACK, PortAudio and libusb) turns skips for missing system components into failures.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import pytest


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--device-url",
        action="store",
        default=None,
        help="URL of a real device for the hardware tier (e.g. serial:///dev/ttyACM0)",
    )


def require_system_component(available: bool, reason: str) -> None:
    """Skip the calling test when a system component is missing, or fail under CI.

    ``.ci/run`` installs the components and sets ``HIL_REQUIRE_SYSTEM_DEPS=1``; there a
    missing component is a broken CI set-up, not a reason to skip.
    """
    if available:
        return
    if os.environ.get("HIL_REQUIRE_SYSTEM_DEPS") == "1":
        pytest.fail(f"{reason} (HIL_REQUIRE_SYSTEM_DEPS=1: .ci/run should have installed it)")
    pytest.skip(reason)


RequireSystem = Callable[[bool, str], None]


@pytest.fixture(scope="session")
def require_system() -> RequireSystem:
    """:func:`require_system_component` for tests and fixtures anywhere in the suite (the
    root conftest is not importable as a module under ``--import-mode=importlib``)."""
    return require_system_component
