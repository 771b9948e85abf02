"""The GRBL stage as an ophyd-async movable, driven by the RunEngine against the simulated
GRBL controller (``sim://stage?via=memory``) on a manual clock: moves run in simulated time."""

from __future__ import annotations

import asyncio
import math
import threading
from typing import Any

import pytest

from sim_devices.stage.clock import ManualClock

# The simulated controller's default machine: 500 mm/min ($110) = 8.33 mm/s.
SPEED_MPS = 0.005
STEP_M = 1.0 / 250.0 / 1000.0  # its $100 = 250 steps/mm


class GatedClock(ManualClock):
    """A manual clock that, once past ``gate_s``, holds the sleeping thread until released:
    a test acts at a known instant of a move without any wall-clock timing."""

    def __init__(self) -> None:
        super().__init__(0.0)
        self.gate_s = math.inf
        self.reached = threading.Event()
        self.release = threading.Event()

    def sleep(self, seconds: float) -> None:
        super().sleep(seconds)
        if self.now() >= self.gate_s and not self.release.is_set():
            self.reached.set()
            self.release.wait()


def _stage(clock: ManualClock) -> Any:
    from hil.bluesky import GrblStageDevice

    return GrblStageDevice("sim://stage?via=memory", clock=clock, name="stage")


def _connect(device: Any) -> None:
    from bluesky.run_engine import call_in_bluesky_event_loop

    call_in_bluesky_event_loop(device.connect())


def test_a_list_scan_moves_the_stage_and_reads_back_each_position(run_engine: Any) -> None:
    import bluesky.plan_stubs as bps
    import bluesky.plans as bp

    stage = _stage(ManualClock())
    _connect(stage)
    run_engine(bps.mv(stage.speed, SPEED_MPS))
    docs: list[tuple[str, dict[str, Any]]] = []
    targets = [-0.01, -0.025, -0.04]
    run_engine(bp.list_scan([], stage, targets), lambda name, doc: docs.append((name, doc)))
    names = [n for n, _ in docs]
    assert names == ["start", "descriptor", "event", "event", "event", "stop"]
    keys = docs[1][1]["data_keys"]
    assert keys["stage-position"]["units"] == "m" and keys["stage-velocity"]["units"] == "m/s"
    config = docs[1][1]["configuration"]["stage"]["data"]
    assert config["stage-speed"] == SPEED_MPS
    assert config["stage-low_limit"] < -0.04 and config["stage-high_limit"] == 0.0
    events = [d["data"] for n, d in docs if n == "event"]
    for target, data in zip(targets, events, strict=True):
        assert data["stage-position"] == pytest.approx(target, abs=STEP_M)
        assert data["stage-state"] == "IDLE" and data["stage-velocity"] == 0.0
    assert docs[-1][1]["exit_status"] == "success"


def test_a_move_outside_the_soft_limits_fails_the_run_naming_the_limit(run_engine: Any) -> None:
    import bluesky.plans as bp
    from bluesky.utils import FailedStatus

    from hil.bluesky import GrblStageDevice

    stage = GrblStageDevice(
        "sim://stage?via=memory", clock=ManualClock(), soft_limits=(-0.1, 0.0), name="stage"
    )
    _connect(stage)
    docs: list[tuple[str, dict[str, Any]]] = []
    with pytest.raises(FailedStatus) as err:
        run_engine(bp.list_scan([], stage, [-0.2]), lambda n, d: docs.append((n, d)))
    cause = err.value.__cause__
    assert "x (axis X) = -0.2 is not allowed" in str(cause)
    assert "within the soft limits [-0.1, 0] m" in str(cause)
    stop = docs[-1][1]
    assert docs[-1][0] == "stop" and stop["exit_status"] == "fail"
    # Nothing moved: the driver refuses before sending.
    from bluesky.run_engine import call_in_bluesky_event_loop

    reading = call_in_bluesky_event_loop(stage.read())
    assert reading["stage-position"]["value"] == 0.0


def test_stop_feed_holds_a_move_in_flight_and_keeps_the_position(run_engine: Any) -> None:
    from bluesky.run_engine import call_in_bluesky_event_loop

    from hil.devices.stage_errors import StageHeldError

    clock = GatedClock()
    stage = _stage(clock)

    async def scenario() -> tuple[float, str]:
        await stage.connect()
        await stage.speed.set(SPEED_MPS)
        clock.gate_s = clock.now() + 2.0  # 2 s into a 10 s move
        move = stage.set(-0.05)
        await asyncio.to_thread(clock.reached.wait)
        stopping = asyncio.ensure_future(stage.stop())
        await asyncio.sleep(0)  # the stop task runs up to its first await: '!' is sent
        clock.release.set()
        with pytest.raises(StageHeldError, match="feed-held before reaching its target"):
            await move
        await stopping
        reading = await stage.read()
        return reading["stage-position"]["value"], reading["stage-state"]["value"]

    position, state = call_in_bluesky_event_loop(scenario())
    # Stopped near where the gate held it: ~2 s at 5 mm/s, plus the deceleration.
    assert -0.05 < position < -0.005
    assert position == pytest.approx(-0.01, abs=0.002)
    assert state == "IDLE"  # the held move was cancelled; GRBL kept the position


def test_a_move_before_connect_says_to_connect(run_engine: Any) -> None:
    from bluesky.run_engine import call_in_bluesky_event_loop

    from hil.devices.stage_errors import StageError

    stage = _stage(ManualClock())

    async def move() -> None:
        await stage.set(-0.01)

    with pytest.raises(StageError, match=r"sim://stage\?via=memory\) is not connected"):
        call_in_bluesky_event_loop(move())


def test_a_stage_connected_in_mock_mode_refuses_to_move_and_says_what_to_use(
    run_engine: Any,
) -> None:
    from bluesky.run_engine import call_in_bluesky_event_loop

    from hil.devices.stage_errors import StageError

    stage = _stage(ManualClock())

    async def move() -> None:
        await stage.connect(mock=True)
        await stage.set(-0.01)

    with pytest.raises(StageError, match=r"mock mode: .* connect it for real to sim://stage"):
        call_in_bluesky_event_loop(move())
