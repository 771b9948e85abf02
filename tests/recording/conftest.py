"""Shared fixtures of the recording tests: a transmit schedule document at 100 kHz."""

from __future__ import annotations

from typing import Any

import pytest

from hil.signals.presets import check_design, get_preset
from hil.signals.schedule import HopSchedule
from hil.signals.schedule_file import schedule_document

FS = 100_000.0


@pytest.fixture(scope="session")
def schedule() -> HopSchedule:
    """The ATT preset's random-cyclic HFC-CW schedule (10 ms hops)."""
    return check_design(get_preset("att").spec("random-cyclic"))


@pytest.fixture(scope="session")
def schedule_doc(schedule: HopSchedule) -> dict[str, Any]:
    """Its schedule JSON document at :data:`FS`."""
    spec = get_preset("att").spec("random-cyclic")
    return schedule_document(schedule, FS, 0.0, sound_speed_mps=1500.0, spec=spec.to_dict())
