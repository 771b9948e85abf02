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
    # The readback is named after the device (ophyd-async's movable convention) and hinted.
    assert keys["stage"]["units"] == "m" and keys["stage-velocity"]["units"] == "m/s"
    assert docs[1][1]["hints"]["stage"]["fields"] == ["stage"]
    config = docs[1][1]["configuration"]["stage"]["data"]
    assert config["stage-speed"] == SPEED_MPS
    assert config["stage-low_limit"] < -0.04 and config["stage-high_limit"] == 0.0
    events = [d["data"] for n, d in docs if n == "event"]
    for target, data in zip(targets, events, strict=True):
        assert data["stage"] == pytest.approx(target, abs=STEP_M)
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
    assert "stage target (axis X) = -0.2 is not allowed" in str(cause)
    assert "within the soft limits [-0.1, 0] m" in str(cause)
    stop = docs[-1][1]
    assert docs[-1][0] == "stop" and stop["exit_status"] == "fail"
    # Nothing moved: the driver refuses before sending.
    from bluesky.run_engine import call_in_bluesky_event_loop

    reading = call_in_bluesky_event_loop(stage.read())
    assert reading["stage"]["value"] == 0.0


def _held_by_stop(stage: Any, clock: GatedClock) -> None:
    """The gate opens once the device has sent its feed hold: the move goes on from the
    gate's instant and meets the hold there, whatever the threads' timing."""
    send_hold = stage.hold_now

    def hold_then_release() -> None:
        send_hold()
        clock.release.set()

    stage.hold_now = hold_then_release


@pytest.mark.parametrize("success", [True, False])
def test_stop_feed_holds_a_move_in_flight_and_keeps_the_position(
    run_engine: Any, success: bool
) -> None:
    from bluesky.run_engine import call_in_bluesky_event_loop

    clock = GatedClock()
    stage = _stage(clock)
    _held_by_stop(stage, clock)

    async def scenario() -> tuple[float, str, BaseException | None]:
        await stage.connect()
        await stage.speed.set(SPEED_MPS)
        clock.gate_s = clock.now() + 2.0  # 2 s into a 10 s move
        move = stage.set(-0.05)
        await asyncio.to_thread(clock.reached.wait)
        await stage.stop(success=success)
        try:
            await move
            failure = None
        except RuntimeError as exc:
            failure = exc
        reading = await stage.read()
        return reading["stage"]["value"], reading["stage-state"]["value"], failure

    position, state, failure = call_in_bluesky_event_loop(scenario())
    # Stopped near where the gate held it: ~2 s at 5 mm/s, plus the deceleration.
    assert position == pytest.approx(-0.01, abs=0.002)
    assert state == "IDLE"  # the held move was cancelled; GRBL kept the position
    # ophyd-async's rule: a stop with success completes the move's status where it stopped,
    # one without fails it.
    if success:
        assert failure is None
    else:
        assert str(failure) == "Device stage was stopped."


@pytest.mark.parametrize("plan_kind", ["mv", "list_scan"])
def test_a_paused_move_holds_and_resume_completes_it(run_engine: Any, plan_kind: str) -> None:
    import bluesky.plan_stubs as bps
    import bluesky.plans as bp
    from bluesky.run_engine import call_in_bluesky_event_loop
    from bluesky.utils import RunEngineInterrupted

    clock = GatedClock()
    stage = _stage(clock)
    _connect(stage)
    run_engine(bps.mv(stage.speed, SPEED_MPS))
    _held_by_stop(stage, clock)
    clock.gate_s = clock.now() + 2.0
    pauser = threading.Thread(target=lambda: (clock.reached.wait(), run_engine.request_pause()))
    pauser.start()
    docs: list[tuple[str, dict[str, Any]]] = []
    plan = bps.mv(stage, -0.05) if plan_kind == "mv" else bp.list_scan([], stage, [-0.05])
    with pytest.raises(RunEngineInterrupted):
        run_engine(plan, lambda name, doc: docs.append((name, doc)))
    pauser.join()
    assert run_engine.state == "paused"
    held = call_in_bluesky_event_loop(stage.read())
    assert held["stage"]["value"] == pytest.approx(-0.01, abs=0.002)
    assert held["stage-state"]["value"] == "IDLE"

    run_engine.resume()
    final = call_in_bluesky_event_loop(stage.read())
    assert final["stage"]["value"] == pytest.approx(-0.05, abs=STEP_M)
    if plan_kind == "list_scan":
        assert [n for n, _ in docs] == ["start", "descriptor", "event", "stop"]
        assert docs[2][1]["data"]["stage"] == pytest.approx(-0.05, abs=STEP_M)
        assert docs[-1][1]["exit_status"] == "success"


def test_check_value_and_check_limits_refuse_a_target_outside_the_soft_limits(
    run_engine: Any,
) -> None:
    import bluesky.plan_stubs as bps
    from bluesky.run_engine import call_in_bluesky_event_loop
    from bluesky.simulators import check_limits

    from hil.bluesky import GrblStageDevice
    from hil.devices.stage_errors import StageLimitError

    stage = GrblStageDevice(
        "sim://stage?via=memory", clock=ManualClock(), soft_limits=(-0.1, 0.0), name="stage"
    )
    _connect(stage)
    call_in_bluesky_event_loop(stage.check_value(-0.05))  # inside: no error
    message = r"stage target \(axis X\) = 10.0 is not allowed: must be within the soft limits"
    with pytest.raises(StageLimitError, match=message):
        call_in_bluesky_event_loop(stage.check_value(10.0))
    with pytest.raises(StageLimitError, match=r"= -0.2 is not allowed: .*\[-0.1, 0\] m"):
        check_limits(bps.mv(stage, -0.2))
    with pytest.raises(StageLimitError, match="= nan is not allowed"):
        call_in_bluesky_event_loop(stage.check_value(math.nan))


def test_locate_gives_the_setpoint_and_the_readback_and_set_reports_progress(
    run_engine: Any,
) -> None:
    from bluesky.run_engine import call_in_bluesky_event_loop

    stage = _stage(ManualClock())
    updates: list[dict[str, Any]] = []

    async def scenario() -> Any:
        await stage.connect()
        await stage.speed.set(SPEED_MPS)
        status = stage.set(-0.02)
        status.watch(lambda **kw: updates.append(kw))
        await status
        return await stage.locate()

    location = call_in_bluesky_event_loop(scenario())
    assert location["setpoint"] == -0.02
    assert location["readback"] == pytest.approx(-0.02, abs=STEP_M)
    assert updates, "the move's status reported no progress"
    first = updates[0]
    assert first["name"] == "stage" and first["unit"] == "m"
    assert first["initial"] == 0.0 and first["target"] == -0.02


def test_a_move_past_its_timeout_holds_the_stage_and_fails_saying_so(run_engine: Any) -> None:
    from bluesky.run_engine import call_in_bluesky_event_loop

    clock = GatedClock()
    stage = _stage(clock)
    _held_by_stop(stage, clock)

    async def scenario() -> float:
        await stage.connect()
        await stage.speed.set(SPEED_MPS)
        clock.gate_s = clock.now() + 2.0
        # The gate holds the move at 2 s until the timeout's feed hold releases it. set()'s
        # timeout is the device's own, on the event loop's (wall) clock: it must outlast the
        # move's run to the gate on the simulated clock (a few ms of CPU; 1 s leaves room
        # for a starved machine: a timeout that expires before the gate holds it early).
        with pytest.raises(TimeoutError, match=r"did not end within its timeout 1 s"):
            await stage.set(-0.05, timeout=1.0)
        return (await stage.read())["stage"]["value"]

    position = call_in_bluesky_event_loop(scenario())
    assert position == pytest.approx(-0.01, abs=0.002)


def test_the_planned_timeout_is_the_move_duration_plus_the_margin(run_engine: Any) -> None:
    from bluesky.run_engine import call_in_bluesky_event_loop

    from hil.bluesky.stage import TIMEOUT_MARGIN_S

    stage = _stage(ManualClock())

    async def timeout() -> float | None:
        await stage.connect()
        await stage.speed.set(SPEED_MPS)
        return await stage.movable_logic.calculate_timeout(0.0, -0.05)

    value = call_in_bluesky_event_loop(timeout())
    accel = stage.driver.settings.acceleration
    assert value == pytest.approx(0.05 / SPEED_MPS + 2 * SPEED_MPS / accel + TIMEOUT_MARGIN_S)


def test_a_move_before_connect_says_to_connect(run_engine: Any) -> None:
    from bluesky.run_engine import call_in_bluesky_event_loop

    from hil.devices.stage_errors import StageError

    stage = _stage(ManualClock())

    async def move() -> None:
        await stage.set(-0.01)

    with pytest.raises(StageError, match=r"sim://stage\?via=memory\) is not connected"):
        call_in_bluesky_event_loop(move())


def test_a_stage_connected_in_mock_mode_moves_at_once_within_its_soft_limits(
    run_engine: Any,
) -> None:
    import bluesky.plan_stubs as bps
    import bluesky.plans as bp
    from bluesky.run_engine import call_in_bluesky_event_loop
    from bluesky.utils import FailedStatus

    from hil.bluesky import GrblStageDevice
    from hil.devices.stage_errors import StageLimitError

    stage = GrblStageDevice("no-such-port", soft_limits=(-0.5, 0.0), name="stage")
    call_in_bluesky_event_loop(stage.connect(mock=True))  # nothing is opened
    docs: list[tuple[str, dict[str, Any]]] = []
    run_engine(bp.list_scan([], stage, [-0.1, -0.3]), lambda n, d: docs.append((n, d)))
    assert [d["data"]["stage"] for n, d in docs if n == "event"] == [-0.1, -0.3]
    assert call_in_bluesky_event_loop(stage.locate()) == {"setpoint": -0.3, "readback": -0.3}
    with pytest.raises(FailedStatus) as err:
        run_engine(bps.mv(stage, -0.6))
    assert isinstance(err.value.__cause__, StageLimitError)
    assert "within the soft limits [-0.5, 0] m" in str(err.value.__cause__)
