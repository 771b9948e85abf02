"""bluesky plans for the tank.

:func:`towed_pass` is one bluesky run of one tank run: a start document with the tow plan
and the devices in its metadata, a descriptor and an event with the run's data (the
:class:`~hil.bluesky.tank_run.TankRunDetector` reading: the recording, its summary figures,
the stage telemetry of the pass and the estimates), and a stop document whose
``exit_status`` is ``"fail"`` with the run's error when the tank run failed. A run that
stopped after it started (an alarm, the board's watchdog, ``run.max_duration_s``) still has
its event, with what it recorded and its ``error``; one refused before it started (a missing
calibration, a tow outside the stage's limits) has none.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any

import bluesky.plan_stubs as bps
import bluesky.preprocessors as bpp
from bluesky.utils import FailedStatus, Msg

from hil.bluesky.tank_run import TankRunDetector, TankRunError


def towed_pass(
    run: TankRunDetector, *, md: dict[str, Any] | None = None
) -> Generator[Msg, Any, None]:
    """One tank run of ``run``'s experiment (its ``tow`` plan: ``repeats`` passes from
    ``start_m`` to ``end_m`` at ``speed_mps``) as a bluesky run; ``md`` adds start-document
    metadata.

    The stage moves inside the run, driven by the run at its tow speed with the telemetry
    on the board's sample clock (what the estimates are scored against); the event carries
    that telemetry as ``<run>-stage_position_m`` / ``<run>-stage_time_s``.
    """
    exp = run.experiment
    tow = exp.tow
    metadata: dict[str, Any] = {
        "plan_name": "towed_pass",
        "detectors": [run.name],
        "experiment": exp.name,
        "simulated": exp.simulated,
        "board_url": exp.board_url,
        "stage_url": exp.stage_url,
        "tow": {
            "start_m": tow.start_m,
            "end_m": tow.end_m,
            "speed_mps": tow.speed_mps,
            "repeats": tow.repeats,
            "run_up_m": tow.run_up_m,
            "run_down_m": tow.run_down_m,
        },
        "receiver": exp.receiver,
        **(md or {}),
    }

    @bpp.stage_decorator([run])
    @bpp.run_decorator(md=metadata)
    def inner() -> Generator[Msg, Any, None]:
        failure: FailedStatus | None = None
        try:
            yield from bps.trigger(run, wait=True)
        except FailedStatus as exc:
            if not isinstance(exc.__cause__, TankRunError):
                raise  # refused before it started: nothing was recorded
            failure = exc
        # A run that stopped after it started still recorded: its event is saved first.
        yield from bps.create("primary")
        yield from bps.read(run)
        yield from bps.save()
        if failure is not None:
            raise failure

    yield from inner()
