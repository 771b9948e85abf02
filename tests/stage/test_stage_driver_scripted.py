"""GrblStage against a scripted serial peer: exact bytes out, GRBL 1.1 answers in.

The peer replays the exchanges of the GRBL 1.1 interface documentation; any write that is
not the next expected one fails the test. A manual clock makes every wait deterministic.
"""

from __future__ import annotations

import itertools
import math

import pytest

from hil.devices.grbl import QUERY_FORGOTTEN_S, QUERY_LOST_S, GrblStage
from hil.devices.stage import StageState
from hil.devices.stage_errors import (
    StageAlarmError,
    StageCommandError,
    StageHeldError,
    StageLimitError,
    StageTimeoutError,
)
from hil.errors import ConfigError
from sim_devices.stage.clock import ManualClock

BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"
SETTINGS = (
    b"$0=10\r\n$10=3\r\n$13=0\r\n$20=1\r\n$21=1\r\n$22=1\r\n$23=0\r\n$24=25.000\r\n"
    b"$25=500.000\r\n$27=1.000\r\n$100=80.000\r\n$110=600.000\r\n$120=50.000\r\n"
    b"$130=400.000\r\nok\r\n"
)
IDLE = b"<Idle|MPos:-100.000,0.000,0.000|Bf:15,128|FS:0,0|WCO:0.000,0.000,0.000>\r\n"
STARTUP = [(b"\x18", BANNER), (b"$$\n", SETTINGS), (b"?", IDLE)]


class ScriptedSerial:
    """A serial peer that checks each write against a script and queues the reply."""

    def __init__(self, script: list[tuple[bytes, bytes]]) -> None:
        self.script = list(script)
        self.written: list[bytes] = []
        self.timeout: float | None = None
        self._rx = bytearray()
        self.closed = False

    def write(self, data: bytes) -> int:
        self.written.append(data)
        assert self.script, f"unexpected write {data!r}: script finished"
        expected, reply = self.script.pop(0)
        assert data == expected, f"wrote {data!r}, script expected {expected!r}"
        self._rx += reply
        return len(data)

    def read(self, size: int = 1) -> bytes:
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def reset_input_buffer(self) -> None:
        self._rx.clear()

    def close(self) -> None:
        self.closed = True


def open_stage(
    script: list[tuple[bytes, bytes]], soft_limits: tuple[float, float] | None = None
) -> tuple[GrblStage, ScriptedSerial]:
    peer = ScriptedSerial(STARTUP + script)
    stage = GrblStage(peer, clock=ManualClock(0.0), soft_limits=soft_limits)
    stage.open()
    return stage, peer


def test_startup_reads_banner_settings_and_status() -> None:
    stage, peer = open_stage([])
    assert peer.written == [b"\x18", b"$$\n", b"?"]
    assert stage.settings.max_rate == pytest.approx(0.01)
    assert stage.limits == (-0.4, 0.0)
    status = stage.last_status
    assert status is not None
    assert (status.state, status.position) == (StageState.IDLE, -0.1)
    assert (status.planner_blocks_free, status.rx_bytes_free) == (15, 128)
    assert not peer.script and not peer.closed


def test_move_sends_mm_and_mm_per_min_and_waits_with_dwell() -> None:
    running = b"<Run|MPos:-150.000,0.000,0.000|Bf:14,128|FS:600,0>\r\n"
    done = b"<Idle|MPos:-200.000,0.000,0.000|Bf:15,128|FS:0,0>\r\n"
    stage, peer = open_stage(
        [
            (b"G53 G1 X-200.000 F600.000\n", b"ok\r\n"),
            (b"G4 P0.000\n", running),
            (b"?", b"ok\r\n"),
            (b"?", done),
        ]
    )
    status = stage.move_to(-0.2, 0.01)
    assert status.position == pytest.approx(-0.2) and status.state is StageState.IDLE
    assert not peer.script


def test_error_response_raises_with_official_text() -> None:
    stage, _ = open_stage([(b"$X\n", b"error:8\r\n")])
    with pytest.raises(StageCommandError, match=r"'\$X' with error:8 \(Not idle: Grbl '\$' "
                       r"command cannot be used unless Grbl is IDLE"):  # fmt: skip
        stage.unlock()


def test_soft_limit_refused_before_sending() -> None:
    stage, peer = open_stage([])
    before = list(peer.written)
    with pytest.raises(StageLimitError, match=r"x \(axis X\) = -0.5 is not allowed: must be "
                       r"within the soft limits \[-0.4, 0\] m of axis X \(max travel \$130 = "
                       r"400.000 mm"):  # fmt: skip
        stage.move_to(-0.5, 0.005)
    with pytest.raises(StageLimitError, match=r"x \(axis X\) = 0.001 .* \[-0.4, 0\] m"):
        stage.move_to(0.001, 0.005)
    assert peer.written == before


def test_speed_and_acceleration_limits_refused_before_sending() -> None:
    stage, peer = open_stage([])
    before = list(peer.written)
    with pytest.raises(StageLimitError, match=r"v \(axis X\) = 0.02 is not allowed: must be in "
                       r"\(0, 0.01\] m/s, the axis X max rate \$110 = 600.000 mm/min"):  # fmt: skip
        stage.move_to(-0.2, 0.02)
    with pytest.raises(StageLimitError, match=r"a \(axis X\) = 0.2 .* \(0, 0.05\] m/s\^2"):
        stage.move_to(-0.2, 0.005, a=0.2)
    with pytest.raises(StageLimitError, match=r"run_up = 0.0001 .* >= 0.001 m, the distance to "
                       r"reach 0.01 m/s"):  # fmt: skip
        stage.run_profile(-0.1, -0.3, 0.01, 0.0001, 0.01)
    with pytest.raises(StageLimitError, match=r"run-down end x \(end \+ run_down\) \(axis X\) = "
                       r"-0.41"):  # fmt: skip
        stage.run_profile(-0.1, -0.3, 0.01, 0.01, 0.11)
    assert peer.written == before


def test_user_soft_limits_narrow_the_machine_range() -> None:
    stage, peer = open_stage([], soft_limits=(-0.3, -0.05))
    assert stage.limits == (-0.3, -0.05)
    with pytest.raises(StageLimitError, match=r"= -0.01 .* \[-0.3, -0.05\] m"):
        stage.move_to(-0.01, 0.005)
    assert peer.written == [b"\x18", b"$$\n", b"?"]


def test_alarm_state_refuses_motion_and_says_how_to_recover() -> None:
    peer = ScriptedSerial(
        [
            (b"\x18", BANNER + b"[MSG:'$H'|'$X' to unlock]\r\n"),
            (b"$$\n", SETTINGS),
            (b"?", b"<Alarm|MPos:0.000,0.000,0.000|FS:0,0>\r\n"),
        ]
    )
    stage = GrblStage(peer, clock=ManualClock())
    stage.open()
    with pytest.raises(StageAlarmError, match=r"stage is in ALARM \(locked at power-up or reset"
                       r".*home with \$H \(GrblStage.home\(\), hil stage home\)"
                       r".*unlock with \$X"):  # fmt: skip
        stage.move_to(-0.1, 0.005)
    assert len(peer.written) == 3


def test_profile_from_where_the_carriage_rests_sends_only_the_tow_move() -> None:
    # The last report has the carriage idle at -100 mm, the run-up start of a tow from
    # -0.11 m to -0.3 m with a 10 mm run-up: no positioning move, no dwell, no status wait.
    stage, peer = open_stage([(b"G53 G1 X-310.000 F300.000\n", b"ok\r\n")])
    window = stage.run_profile(-0.11, -0.3, 0.005, 0.01, 0.01, wait=False)
    assert peer.written[-1] == b"G53 G1 X-310.000 F300.000\n" and not peer.script
    # From the ok: 0.1 s to reach speed, then the rest of the 10 mm run-up, then 190 mm.
    assert (window.x_start, window.x_end) == (-0.11, -0.3)
    assert window.t_end - window.t_start == pytest.approx(38.0)


def test_profile_from_elsewhere_positions_first() -> None:
    running = b"<Run|MPos:-100.000,0.000,0.000|Bf:14,128|FS:600,0>\r\n"
    stage, peer = open_stage(
        [
            (b"G53 G1 X-90.000 F600.000\n", b"ok\r\n"),
            (b"G4 P0.000\n", running + b"ok\r\n"),
            (b"?", b"<Idle|MPos:-90.000,0.000,0.000|Bf:15,128|FS:0,0>\r\n"),
            (b"G53 G1 X-310.000 F300.000\n", b"ok\r\n"),
        ]
    )
    stage.run_profile(-0.1, -0.3, 0.005, 0.01, 0.01, wait=False)
    assert not peer.script  # every line above, in that order


def test_alarm_during_a_move_raises_with_the_alarm_text() -> None:
    stage, _ = open_stage(
        [
            (b"G53 G1 X-200.000 F600.000\n", b"ok\r\n"),
            (b"G4 P0.000\n", b"ALARM:1\r\n[MSG:Reset to continue]\r\n"),
        ]
    )
    with pytest.raises(StageAlarmError, match=r"ALARM:1 \(Hard limit: .*\); to recover: send a "
                       r"soft reset first"):  # fmt: skip
        stage.move_to(-0.2, 0.01)
    status = stage.status()  # '?' is not sent: GRBL ignores it in a critical alarm
    assert (status.state, status.alarm) == (StageState.ALARM, 1)
    with pytest.raises(StageAlarmError, match="soft reset first"):
        stage.unlock()


def test_feed_hold_during_a_move_raises_held() -> None:
    stage, _ = open_stage(
        [
            (b"G53 G1 X-200.000 F600.000\n", b"ok\r\n"),
            (b"G4 P0.000\n", b""),
            (b"?", b"<Hold:0|MPos:-150.000,0.000,0.000|FS:0,0>\r\n"),
        ]
    )
    with pytest.raises(StageHeldError, match=r"resume\(\) to continue or stop\(\) to cancel"):
        stage.move_to(-0.2, 0.01)


def test_estop_is_latched_until_unlock() -> None:
    stage, peer = open_stage(
        [
            (b"\x18", b"ALARM:3\r\n" + BANNER + b"[MSG:'$H'|'$X' to unlock]\r\n"),
            (b"?", b"<Alarm|MPos:-120.000,0.000,0.000|FS:0,0>\r\n"),
            (b"$X\n", b"[MSG:Caution: Unlocked]\r\nok\r\n"),
            (b"?", IDLE),
        ]
    )
    status = stage.estop()
    assert (status.state, status.alarm) == (StageState.ALARM, 3)
    with pytest.raises(StageAlarmError, match=r"emergency stop latched by estop\(\); "
                       r"controller ALARM:3 \(Abort during cycle.*home with \$H"):  # fmt: skip
        stage.move_to(-0.2, 0.01)
    assert stage.unlock().state is StageState.IDLE
    assert "[MSG:Caution: Unlocked]" in stage.messages
    assert not peer.script


def test_exception_inside_with_block_sends_feed_hold() -> None:
    peer = ScriptedSerial([*STARTUP, (b"!", b"")])
    with pytest.raises(RuntimeError, match="boom"), GrblStage(peer, clock=ManualClock()):
        raise RuntimeError("boom")
    assert peer.written[-1] == b"!"
    assert not peer.closed  # an injected port belongs to the caller


def test_status_polling_never_faster_than_5_hz() -> None:
    clock = ManualClock(0.0)
    peer = ScriptedSerial(STARTUP + [(b"?", IDLE)] * 3)
    stage = GrblStage(peer, clock=clock)
    stage.open()
    times = [stage.status().host_time for _ in range(3)]
    assert [round(b - a, 9) for a, b in itertools.pairwise(times)] == [0.2, 0.2]


def test_silent_controller_times_out_with_advice() -> None:
    # The reset unanswered for RESET_RETRY_S (0.7 s) is sent once more within the 1 s.
    peer = ScriptedSerial([(b"\x18", b""), (b"\x18", b"")])
    stage = GrblStage(peer, clock=ManualClock(), open_timeout=1.0)
    with pytest.raises(StageTimeoutError, match=r"no banner from GRBL within 1 s: "
                       r"check the cable"):  # fmt: skip
        stage.open()
    assert peer.written == [b"\x18", b"\x18"] and not peer.script


def test_bad_driver_configuration_rejected_before_opening() -> None:
    with pytest.raises(ConfigError, match=r"poll_interval = 0.1 .* >= 0.2 s"):
        GrblStage("loop://", poll_interval=0.1)
    with pytest.raises(ConfigError, match=r"soft_limits = \(0.0, -1.0\) .* low < high"):
        GrblStage("loop://", soft_limits=(0.0, -1.0))
    peer = ScriptedSerial(STARTUP)
    stage = GrblStage(peer, clock=ManualClock(), soft_limits=(-0.5, 0.0))
    with pytest.raises(ConfigError, match=r"inside GRBL's machine range \[-0.4, 0\] m"):
        stage.open()


def test_write_setting_validates_then_sends() -> None:
    stage, peer = open_stage([(b"$110=900.000\n", b"ok\r\n")])
    with pytest.raises(ConfigError, match=r"max_rate_x \(\$110\) = -1"):
        stage.write_setting("max_rate_x", -1)
    assert len(peer.written) == 3
    stage.write_setting("max_rate_x", 900.0)
    assert stage.settings.max_rate == pytest.approx(0.015)


class DelayedSerial(ScriptedSerial):
    """A scripted peer whose replies reach the host ``delay`` s (clock time) after the write:
    a slow link or a host that reads late."""

    def __init__(self, script: list[tuple[bytes, bytes]], clock: ManualClock) -> None:
        super().__init__(script)
        self.clock, self.delay = clock, 0.0
        self.delays: list[float] = []  # per write, before falling back to ``delay``
        self.query_times: list[float] = []
        self._held: list[tuple[float, bytes]] = []

    def write(self, data: bytes) -> int:
        if data == b"?":
            self.query_times.append(self.clock.now())
        n = super().write(data)
        delay = self.delays.pop(0) if self.delays else self.delay
        self._held.append((self.clock.now() + delay, bytes(self._rx)))
        self._rx.clear()
        return n

    def _release(self) -> None:
        while self._held and self._held[0][0] <= self.clock.now():
            self._rx += self._held.pop(0)[1]

    def read(self, size: int = 1) -> bytes:
        self._release()
        return super().read(size)

    @property
    def in_waiting(self) -> int:
        self._release()
        return len(self._rx)


def _delayed_stage(
    script: list[tuple[bytes, bytes]], delay: float, **options: float
) -> tuple[GrblStage, DelayedSerial, ManualClock]:
    clock = ManualClock(0.0)
    peer = DelayedSerial(STARTUP + script, clock)
    stage = GrblStage(peer, clock=clock, **options)
    stage.open()
    peer.delay = delay
    return stage, peer, clock


def _report(mm: int, state: bytes = b"Run") -> bytes:
    return b"<%s|MPos:-%d.000,0.000,0.000|Bf:14,128|FS:600,0>\r\n" % (state, mm)


def test_a_status_is_dated_by_its_query_not_by_when_it_was_read() -> None:
    # The reply is read 0.7 s after the '?' (a stalled host): the position is GRBL's at
    # the query, so that is the report's time. No second '?' while one is in flight.
    stage, peer, clock = _delayed_stage([(b"?", _report(150))], delay=0.7)
    status = stage.status()
    assert status.host_time == peer.query_times[-1]
    assert clock.now() - status.host_time == pytest.approx(0.7, abs=0.021)
    assert status.reply_s == clock.now() - status.host_time
    assert status.position == pytest.approx(-0.15) and status.state is StageState.RUN
    assert not peer.script and peer.written.count(b"?") == 2  # open() and this one


def test_successive_reports_are_dated_by_their_own_queries() -> None:
    stage, peer, _ = _delayed_stage([(b"?", _report(m)) for m in (110, 120, 130)], 0.3)
    seen = [stage.status() for _ in range(3)]
    assert [s.host_time for s in seen] == peer.query_times[-3:]
    assert [s.position for s in seen] == pytest.approx([-0.11, -0.12, -0.13])
    # Each query waits for the previous answer (0.3 s, longer than the 5 Hz spacing).
    spacing = [round(b - a, 9) for a, b in itertools.pairwise(peer.query_times[-3:])]
    assert spacing == [0.3, 0.3]


def test_an_unanswered_query_is_sent_again_after_query_lost_s() -> None:
    # A '?' the controller never answers (lost on the line): after QUERY_LOST_S the driver
    # asks again, and the report that comes is dated by the query it answers, not the lost
    # one.
    stage, peer, _ = _delayed_stage(
        [(b"?", b""), (b"?", _report(100, b"Idle"))], delay=0.0, response_timeout=3.0
    )
    status = stage.status()
    lost, answered = peer.query_times[-2:]
    assert answered - lost == pytest.approx(QUERY_LOST_S, abs=0.021)
    assert status.host_time == answered and not peer.script
    # The lost '?' might still have been answered late, so this report is not trusted.
    assert status.reply_s == math.inf


def test_reports_are_trusted_again_once_a_lost_query_is_forgotten() -> None:
    # The lost '?' is never answered: the reports read within QUERY_FORGOTTEN_S of it are
    # flagged, those read after are dated by their own queries again.
    script = [(b"?", b"")] + [(b"?", _report(100 + m, b"Idle")) for m in range(8)]
    stage, peer, clock = _delayed_stage(script, delay=0.01, response_timeout=3.0)
    seen = [stage.status()]
    for _ in range(7):
        clock.advance(0.2)
        seen.append(stage.status())
    q_lost = peer.query_times[1]  # [0] is open()'s
    flagged = [s.reply_s == math.inf for s in seen]
    assert flagged == [True] * 5 + [False] * 3  # golden for 0.2 s polls, 0.01 s replies
    assert seen[4].host_time < q_lost + QUERY_FORGOTTEN_S <= seen[5].host_time
    assert [s.host_time for s in seen[5:]] == peer.query_times[-3:]
    assert all(s.reply_s == pytest.approx(0.01, abs=0.021) for s in seen[5:])
    assert not peer.script


def test_a_report_nobody_asked_for_is_dated_on_receipt() -> None:
    stage, peer, clock = _delayed_stage([], delay=0.0)
    clock.advance(3.0)
    peer._rx += _report(120, b"Idle")  # e.g. a reply to a '?' typed on a shared terminal
    stage._wait(lambda: stage.connection.reports >= 2, 1.0, "the report")
    assert stage.last_status is not None and stage.last_status.host_time == 3.0
    assert stage.last_status.reply_s == math.inf  # when GRBL sampled it is unknown


def test_a_late_answer_to_a_lost_query_is_flagged_and_the_pairing_recovers() -> None:
    # The controller stalls 1.2 s on the first '?': given up as lost after QUERY_LOST_S, the
    # '?' is sent again; both answers then come together. Neither can be dated (a reply of
    # 0.2 s is too slow to trust, the extra one is marked infinite); the next query is
    # paired with its own answer again.
    stage, peer, _ = _delayed_stage(
        [(b"?", _report(110)), (b"?", _report(120)), (b"?", _report(130))], delay=0.01
    )
    peer.delays = [1.2]
    first = stage.status()
    assert first.reply_s == math.inf and first.position == pytest.approx(-0.12)
    q_resent = peer.query_times[-1]
    assert q_resent - peer.query_times[-2] == pytest.approx(QUERY_LOST_S, abs=0.021)
    after = stage.status()
    assert after.host_time == peer.query_times[-1] > q_resent
    assert after.position == pytest.approx(-0.13) and after.reply_s <= 0.021
    assert not peer.script


def test_a_late_answer_just_after_the_query_sent_again_is_not_taken_for_its_answer() -> None:
    # The first '?' is answered 1.03 s late, just after the driver gave it up (QUERY_LOST_S)
    # and asked again. That late answer looks like a prompt (0.03 s) reply to the second
    # '?', but it is GRBL's state at the first: it must not be dated by the second query.
    # The second answer (0.1 s later) is read, flagged, before the next '?'; from then on
    # each report is dated by its own query again.
    stage, peer, _ = _delayed_stage([(b"?", _report(110 + m)) for m in range(4)], delay=0.01)
    peer.delays = [1.03, 0.1]
    first = stage.status()
    q_lost, q_resent = peer.query_times[-2:]
    assert q_resent - q_lost == pytest.approx(QUERY_LOST_S, abs=0.021)
    assert first.position == pytest.approx(-0.11) and first.reply_s == math.inf
    later = [stage.status() for _ in range(2)]
    assert [s.position for s in later] == pytest.approx([-0.112, -0.113])
    assert [s.host_time for s in later] == peer.query_times[-2:]
    assert all(s.reply_s == pytest.approx(0.01, abs=0.021) for s in later)
    assert not peer.script
