"""bluesky plans for the tank.

:func:`towed_pass` is one bluesky run of one tank run: a start document with the tow plan
and the devices in its metadata; the ``primary`` stream with one event, the
:class:`~hil.bluesky.tank_run.TankRunDetector` reading (the recording, its summary figures);
the ``estimates`` and ``telemetry`` streams with one event per live estimate and per stage
telemetry report (:func:`tank_streams`); and a stop document whose ``exit_status`` is
``"fail"`` with the run's error when the tank run failed. A run that stopped after it started
(an alarm, the board's watchdog, ``run.max_duration_s``) still has its events, with what it
recorded and its ``error``; one refused before it started (a missing calibration, a tow
outside the stage's limits) has none.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any

import bluesky.plan_stubs as bps
import bluesky.preprocessors as bpp
from bluesky.utils import FailedStatus, Msg

from hil.bluesky.tank_run import TankRunDetector, TankRunError


def tank_streams(run: TankRunDetector) -> Generator[Msg, Any, None]:
    """Plan stub: the last tank run of ``run`` as two event streams of the open bluesky
    run, one event per row: ``estimates`` (``<run>-estimate_time_s`` s,
    ``<run>-estimate_range_m`` m, ``<run>-estimate_speed_mps`` m/s: the live estimates)
    and ``telemetry`` (``<run>-stage_time_s`` s on the driver's clock,
    ``<run>-stage_position_m`` m, ``<run>-stage_velocity_mps`` m/s: the stage as GRBL
    reported it). Use it after each trigger, e.g. as ``bp.count``'s ``per_shot``
    (docs/bluesky.md)."""
    for stream, row in run.stream_rows().items():
        for i in range(len(row)):
            row.index = i
            yield from bps.create(stream)
            yield from bps.read(row)
            yield from bps.save()


def tank_shot(
    detectors: list[Any], take_reading: Any = bps.trigger_and_read
) -> Generator[Msg, Any, None]:
    """``per_shot`` for :func:`bluesky.plans.count`: each shot's reading, then the
    estimates and telemetry streams (:func:`tank_streams`) of every
    :class:`~hil.bluesky.tank_run.TankRunDetector` among ``detectors``."""
    yield from take_reading(list(detectors))
    for det in detectors:
        if isinstance(det, TankRunDetector):
            yield from tank_streams(det)


def towed_pass(
    run: TankRunDetector, *, md: dict[str, Any] | None = None
) -> Generator[Msg, Any, None]:
    """One tank run of ``run``'s experiment (its ``tow`` plan: ``repeats`` passes from
    ``start_m`` to ``end_m`` at ``speed_mps``) as a bluesky run; ``md`` adds start-document
    metadata.

    The stage moves inside the run, driven by the run at its tow speed with the telemetry
    on the board's sample clock (what the estimates are scored against); the ``telemetry``
    stream carries it. A pause stops the run in flight safely; a resume runs it again from
    the start (a new run folder).
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
        yield from bps.checkpoint()  # a resume after a pause runs the pass again from here
        try:
            yield from bps.trigger(run, wait=True)
        except FailedStatus as exc:
            if not isinstance(exc.__cause__, TankRunError):
                raise  # refused before it started: nothing was recorded
            failure = exc
        # A run that stopped after it started still recorded: its events are saved first.
        yield from bps.create("primary")
        yield from bps.read(run)
        yield from bps.save()
        yield from tank_streams(run)
        if failure is not None:
            raise failure

    yield from inner()
