"""GrblStage against GRBL 1.1h's behaviour where the driver used to fail on the firmware.

The peer is a scripted GRBL on the injected clock: every write must be the next one the
script expects, replies come the firmware's ``ok`` latency (2.4 ms) later or at the times
given, and after a critical alarm (``ALARM:1``/``ALARM:2``) it does what ``protocol.c`` does:
``[MSG:Reset to continue]`` 0.5 s after the alarm, a soft reset received before then is
dropped, every other byte (``?``, ``!``, lines) is ignored until a reset. Times asserted are
clock times; nothing sleeps.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from hil.devices.grbl import GrblStage
from hil.devices.grbl_connection import (
    RESET_RETRY_S,
    Alarm,
    GrblConnection,
    LineAnswered,
    Message,
    Noise,
    Report,
    Reset,
    Setting,
)
from hil.devices.stage import StageState
from hil.devices.stage_errors import StageAlarmError, StageError, StageTimeoutError
from hil.errors import ConfigError
from sim_devices.stage.clock import ManualClock

OK_LATENCY_S = 0.0024  # GRBL 1.1h on an Uno answers a short line in about 2.4 ms
BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"
LOCKED = b"[MSG:'$H'|'$X' to unlock]\r\n"
CRITICAL_MSG = b"[MSG:Reset to continue]\r\n"

#: A 3-axis machine as a tank stage sets it up: homing and limits on, Z travel the longest.
TANK_SETTINGS = {
    0: "10", 1: "25", 2: "0", 3: "0", 4: "0", 5: "0", 6: "0", 10: "1", 11: "0.010",
    12: "0.002", 13: "0", 20: "1", 21: "1", 22: "1", 23: "0", 24: "25.000", 25: "500.000",
    26: "250", 27: "1.000", 30: "1000", 31: "0", 32: "0", 100: "80.000", 101: "80.000",
    102: "80.000", 110: "600.000", 111: "600.000", 112: "600.000", 120: "50.000",
    121: "50.000", 122: "50.000", 130: "400.000", 131: "200.000", 132: "500.000",
}  # fmt: skip


def dump(settings: dict[int, str]) -> bytes:
    return b"".join(b"$%d=%s\r\n" % (n, v.encode()) for n, v in settings.items()) + b"ok\r\n"


def report(state: str, x_mm: float, feed: int = 0) -> bytes:
    return b"<%s|MPos:%.3f,0.000,0.000|FS:%d,0>\r\n" % (state.encode(), x_mm, feed)


Reply = bytes | list[tuple[float, bytes]] | Callable[[float], bytes]


class Grbl11Peer:
    """A scripted GRBL 1.1h (see the module docstring); ``script``: (expected write, reply)
    where the reply is bytes (after :data:`OK_LATENCY_S`), ``[(delay_s, bytes), ...]`` or a
    function of the write's time returning bytes."""

    def __init__(self, clock: ManualClock, script: list[tuple[bytes, Reply]]) -> None:
        self.clock = clock
        self.script = list(script)
        self.written: list[tuple[float, bytes]] = []
        self.ignored: list[tuple[float, bytes]] = []
        self.timeout = 0.0
        self._out: list[tuple[float, bytes]] = []
        self._alarm_at: float | None = None

    def critical_alarm(self, at: float, code: int) -> None:
        """GRBL raises ``ALARM:<code>`` at ``at`` (clock s), locked until a reset."""
        self._alarm_at = at
        self.push(at, b"ALARM:%d\r\n" % code)
        self.push(at + 0.5, CRITICAL_MSG)

    def push(self, at: float, data: bytes) -> None:
        self._out.append((at, data))
        self._out.sort(key=lambda item: item[0])

    def write(self, data: bytes) -> int:
        now = self.clock.now()
        self.written.append((now, data))
        if self._alarm_at is not None and now >= self._alarm_at:
            if data != b"\x18" or now < self._alarm_at + 0.5:
                self.ignored.append((now, data))  # locked: only a reset after the message
                return len(data)
            self._alarm_at = None
        assert self.script, f"unexpected write {data!r} at {now:.4f} s: script finished"
        expected, reply = self.script.pop(0)
        assert data == expected, f"wrote {data!r} at {now:.4f} s, script expected {expected!r}"
        if callable(reply):
            self.push(now + OK_LATENCY_S, reply(now))
        elif isinstance(reply, list):
            for delay, chunk in reply:
                self.push(now + delay, chunk)
        else:
            self.push(now + OK_LATENCY_S, reply)
        return len(data)

    def read(self, size: int) -> bytes:
        now = self.clock.now()
        out = bytearray()
        while self._out and self._out[0][0] <= now and len(out) < size:
            out += self._out.pop(0)[1]
        return bytes(out)

    def close(self) -> None:
        pass

    def sent(self, data: bytes) -> list[float]:
        """Times at which ``data`` was written."""
        return [t for t, d in self.written if d == data]


def startup(settings: dict[int, str], state: str = "Idle", x_mm: float = -100.0) -> list[Any]:
    locked = LOCKED if state == "Alarm" else b""
    return [(b"\x18", BANNER + locked), (b"$$\n", dump(settings)), (b"?", report(state, x_mm))]


def open_stage(
    script: list[tuple[bytes, Reply]],
    settings: dict[int, str] | None = None,
    state: str = "Idle",
    x_mm: float = -100.0,
    **kw: Any,
) -> tuple[GrblStage, Grbl11Peer, ManualClock]:
    clock = ManualClock(0.0)
    peer = Grbl11Peer(clock, startup(settings or TANK_SETTINGS, state, x_mm) + script)
    stage = GrblStage(peer, clock=clock, **kw)
    stage.open()
    return stage, peer, clock


# ---------------------------------------------------------------- critical alarms
@pytest.mark.parametrize("code", [1, 2])
def test_status_straight_after_a_critical_alarm_answers_from_what_is_known(code: int) -> None:
    # The move is cut by the alarm; GRBL ignores the '?' that follows. status() must not
    # wait for the [MSG:Reset to continue] 0.5 s later, nor for a report that never comes.
    stage, peer, clock = open_stage(
        [
            (b"G53 G1 X-200.000 F600.000\n", b"ok\r\n"),
            (b"G4 P0.000\n", b""),
            (b"?", report("Run", -150.0, 600)),
        ]
    )
    peer.critical_alarm(at=0.3, code=code)
    with pytest.raises(StageAlarmError, match=rf"ALARM:{code} .*send a soft reset first"):
        stage.move_to(-0.2, 0.01)
    raised = clock.now()
    assert raised - 0.3 < 0.05
    status = stage.status()
    assert clock.now() - raised < 1.0
    assert (status.state, status.alarm, status.velocity) == (StageState.ALARM, code, 0.0)
    assert status.position == pytest.approx(-0.15)  # the last report's
    assert stage.critical and stage.stop().state is StageState.ALARM
    assert clock.now() - raised < 1.0


def test_reset_straight_after_a_critical_alarm_is_resent_until_the_banner() -> None:
    # The first 0x18 reaches GRBL inside the 0.5 s it sleeps after printing the alarm and is
    # dropped; the resend after RESET_RETRY_S lands after the message and is taken.
    stage, peer, clock = open_stage(
        [
            (b"G53 G1 X-200.000 F600.000\n", b"ok\r\n"),
            (b"G4 P0.000\n", b""),
            (b"?", report("Run", -150.0, 600)),
            (b"\x18", BANNER + LOCKED),
            (b"?", report("Alarm", -150.0)),
        ]
    )
    peer.critical_alarm(at=0.3, code=1)
    with pytest.raises(StageAlarmError):
        stage.move_to(-0.2, 0.01)
    raised = clock.now()
    status = stage.reset()
    assert clock.now() - raised < 1.0
    resets = peer.sent(b"\x18")[1:]  # [0] is open()'s
    assert len(resets) == 2 and (raised, b"\x18") in peer.ignored
    assert resets[1] - resets[0] == pytest.approx(RESET_RETRY_S, abs=0.021)
    assert (status.state, status.alarm, status.position) == (StageState.ALARM, 1, -0.15)
    assert not stage.critical and not peer.script
    with pytest.raises(StageAlarmError, match=r"ALARM:1 .*home with \$H .*do not unlock"):
        stage.move_to(-0.1, 0.01)


def test_reset_lost_on_the_line_is_sent_again() -> None:
    stage, peer, clock = open_stage([(b"\x18", b""), (b"\x18", BANNER), (b"?", report("Idle", 0))])
    t0 = clock.now()
    assert stage.reset().state is StageState.IDLE
    first, second = peer.sent(b"\x18")[1:]
    assert second - first == pytest.approx(RESET_RETRY_S, abs=0.021)
    assert clock.now() - t0 < 1.0 and not peer.script


def test_a_reset_given_up_on_is_not_resent_behind_later_commands() -> None:
    stage, peer, _ = open_stage(
        [(b"\x18", b""), (b"\x18", b""), (b"$X\n", b"ok\r\n"), (b"?", report("Idle", 0))],
        response_timeout=1.0,
    )
    with pytest.raises(StageTimeoutError, match="no banner from GRBL within 1 s"):
        stage.reset()
    assert stage.unlock().state is StageState.IDLE  # no 0x18 during the unlock's wait
    assert not peer.script


def test_a_reset_in_motion_is_not_resent_while_grbl_reports_alarm_3() -> None:
    # Reset while moving: ALARM:3, then GRBL's 0.5 s alarm sleep, then the banner. The ALARM
    # line shows the reset was taken, so no second 0x18 (it would reset GRBL twice).
    stage, peer, _ = open_stage(
        [
            (b"\x18", [(OK_LATENCY_S, b"ALARM:3\r\n"), (0.9, BANNER + LOCKED)]),
            (b"?", report("Alarm", -120.0)),
        ]
    )
    status = stage.estop()
    assert (status.state, status.alarm) == (StageState.ALARM, 3)
    assert len(peer.sent(b"\x18")) == 2 and not peer.script  # open()'s and estop()'s


def test_hard_limit_mid_profile_stops_the_run_within_a_second() -> None:
    # A tow in progress (GRBL reports Run); the carriage hits a hard-limit switch at 5 s.
    # The run sees the alarm, stops (feed hold is pointless: GRBL halted and answers no
    # status) and closes, all within a second of the alarm.
    run = report("Run", -150.0, 300)
    stage, peer, clock = open_stage(
        [(b"G53 G1 X-310.000 F300.000\n", b"ok\r\n"), (b"G4 P0.000\n", b"")] + [(b"?", run)] * 30,
    )
    peer.critical_alarm(at=5.0, code=1)
    with pytest.raises(StageAlarmError, match=r"ALARM:1 \(Hard limit"):
        stage.run_profile(-0.11, -0.3, 0.005, 0.01, 0.01)
    assert clock.now() - 5.0 < 0.25
    status = stage.stop()
    stage.close()
    assert clock.now() - 5.0 < 1.0
    assert status.state is StageState.ALARM and status.alarm == 1
    assert [d for t, d in peer.written if t >= 5.0] == [d for t, d in peer.ignored]


def test_the_tank_runs_stop_sequence_after_a_hard_limit_takes_under_a_second() -> None:
    # hil tank-run's stop on an error: feed hold unconditionally (hold=True), flush, close.
    from hil.experiments.live.devices import RunDevices

    stage, peer, clock = open_stage(
        [(b"G53 G1 X-310.000 F300.000\n", b"ok\r\n"), (b"G4 P0.000\n", b"")]
        + [(b"?", report("Run", -150.0, 300))] * 30,
    )
    peer.critical_alarm(at=3.0, code=1)
    with pytest.raises(StageAlarmError):
        stage.run_profile(-0.11, -0.3, 0.005, 0.01, 0.01)
    RunDevices(stage=stage).safe_stop(hold=True)
    assert clock.now() - 3.0 < 1.0
    assert stage.last_status is not None and stage.critical
    with pytest.raises(StageError, match="the stage is not open"):
        stage.status()  # closed by the stop sequence


def test_hard_limit_seen_by_a_status_poll_during_a_run_without_wait() -> None:
    # hil tank-run tows with wait=False and polls status(): the poll after the alarm reports
    # it, and the stop that follows returns at once.
    stage, peer, clock = open_stage(
        [(b"G53 G1 X-310.000 F300.000\n", b"ok\r\n")] + [(b"?", report("Run", -150.0, 300))] * 2
    )
    stage.run_profile(-0.11, -0.3, 0.005, 0.01, 0.01, wait=False)
    assert stage.status().state is StageState.RUN
    peer.critical_alarm(at=clock.now() + 0.1, code=1)
    seen = None
    while seen is None or seen.state is StageState.RUN:
        seen = stage.status()
    assert (seen.state, seen.alarm) == (StageState.ALARM, 1)
    assert stage.stop().state is StageState.ALARM
    assert clock.now() < 1.0


# ---------------------------------------------------------------- homing
def test_homing_timeout_covers_every_homed_axis() -> None:
    # Stock GRBL homes Z (500 mm of travel here) and then X and Y: the wait covers both
    # cycles. Golden: Z 1.5*500/500*60 + 2*1/500*60 + 5*1/25*60 + 4*0.25 = 103.24 s, XY
    # (400 mm) 72 + 0.24 + 12 + 1 = 85.24 s; 1.5 x 188.48 + 10 s response timeout.
    stage, _, _ = open_stage([])
    assert stage.homing_timeout() == pytest.approx(1.5 * 188.48 + 10.0)
    stage_x, _, _ = open_stage([], homing_cycles=("X",))
    assert stage_x.homing_timeout() == pytest.approx(1.5 * 85.24 + 10.0)


def test_homing_a_3_axis_stage_from_power_up() -> None:
    # Power-up in ALARM (homing enabled). Z searches most of its 500 mm, then XY: the ok of
    # $H comes 160 s after it was sent, longer than the X axis alone would ever take.
    homed = report("Idle", -1.0)
    clock = ManualClock(0.0)
    peer = Grbl11Peer(
        clock,
        [
            *startup(TANK_SETTINGS, "Alarm", -250.0),
            (b"$H\n", [(160.0, b"ok\r\n")]),
            (b"?", homed),
        ],
    )
    stage = GrblStage(peer, clock=clock).open()
    assert stage.last_status is not None and stage.last_status.state is StageState.ALARM
    t0 = clock.now()
    status = stage.home()
    assert clock.now() - t0 == pytest.approx(160.0, abs=0.05)
    assert (status.state, status.position, status.alarm) == (StageState.IDLE, -0.001, None)
    assert not peer.script


def test_homing_that_finds_no_switch_raises_alarm_9_and_grbl_resets_itself() -> None:
    # A switch not wired: GRBL searches, ALARM:9, sleeps 0.5 s, 'ok' for the $H, then
    # resets itself, dropping the '?' received meanwhile; the driver asks again.
    stage, peer, _ = open_stage(
        [
            (b"$H\n", [(40.0, b"ALARM:9\r\n"), (40.5, b"ok\r\n" + BANNER + LOCKED)]),
            (b"?", b""),
            (b"?", report("Alarm", -5.0)),
        ],
        settings=TANK_SETTINGS,
        state="Alarm",
    )
    with pytest.raises(StageAlarmError, match=r"ALARM:9 \(Homing fail: Could not find limit"):
        stage.home()
    status = stage.status()
    assert (status.state, status.alarm) == (StageState.ALARM, 9)
    assert stage.connection.banners == 2 and not peer.script


def test_homing_cycles_are_checked() -> None:
    with pytest.raises(ConfigError, match=r"homing cycle = 'XA' is not allowed"):
        GrblStage(Grbl11Peer(ManualClock(), []), homing_cycles=("Z", "XA"))


# ---------------------------------------------------------------- URLs and DTR
def test_serial_url_and_plain_path_open_through_the_transport_registry() -> None:
    from sim_devices.stage import GrblSimConfig, SimulatedGrblOnPty

    clock = ManualClock(0.0)
    config = GrblSimConfig(homing=False, soft_limits=False, power_up_position_mm=0.0)
    with SimulatedGrblOnPty(config, clock=clock) as sim:
        for url, dtr in (
            (f"serial://{sim.port_name}?baud=115200", False),
            (sim.port_name, False),
            (f"serial://{sim.port_name}?dtr=1", True),
        ):
            with GrblStage(url, clock=clock, wait_step=0.2) as stage:
                assert stage.status().state is StageState.IDLE
                port = stage.transport.port  # type: ignore[attr-defined]
                # DTR low by default: an Uno/Nano is not reset by the open.
                assert (port.dtr, port.rts) == (dtr, False)


def test_spy_url_traces_the_stage_traffic(tmp_path: Any) -> None:
    from sim_devices.stage import GrblSimConfig, SimulatedGrblOnPty

    log = tmp_path / "stage.log"
    clock = ManualClock(0.0)
    config = GrblSimConfig(homing=False, soft_limits=False, power_up_position_mm=0.0)
    with (
        SimulatedGrblOnPty(config, clock=clock) as sim,
        GrblStage(f"spy://serial://{sim.port_name}?file={log}", clock=clock) as stage,
    ):
        stage.status()
    lines = log.read_text().splitlines()
    assert lines[0].split()[1:4] == ["TX", "0000", "18"]
    assert any("$$" in line for line in lines if " TX " in line)


# ---------------------------------------------------------------- the sans-IO connection
def test_connection_turns_a_documented_conversation_into_events() -> None:
    conn = GrblConnection()
    assert conn.send_reset(now=0.0) == b"\x18"
    events = conn.receive_data(BANNER + LOCKED, now=0.01)
    assert events == [Reset("1.1h"), Message("[MSG:'$H'|'$X' to unlock]")]
    pending, data = conn.send_line("$X")
    assert data == b"$X\n"
    conn.alarm = 3
    events = conn.receive_data(b"[MSG:Caution: Unlocked]\r\nok\r\n$22=1\r\nnoise\r\n", now=0.02)
    assert [type(e) for e in events] == [Message, LineAnswered, Setting, Noise]
    assert pending.done and conn.alarm is None  # $X answered ok ends the alarm
    assert conn.send_query(now=0.1) == b"?" and conn.send_query(now=0.15) == b""
    (event,) = conn.receive_data(b"<Idle|WPos:1.000,0.000,0.000|WCO:-3.000,0.000,0.000>\r\n", 0.2)
    assert isinstance(event, Report)
    assert (event.mpos, event.host_time, event.reply_s) == ((-2.0, 0.0, 0.0), 0.1, 0.2 - 0.1)


def test_connection_marks_a_critical_alarm_from_its_code_and_drops_lines_at_reset() -> None:
    conn = GrblConnection()
    pending, _ = conn.send_line("G53 G1 X-5 F100")
    assert conn.receive_data(b"ALARM:2\r\n", now=1.0) == [Alarm(2, critical=True)]
    assert conn.critical and conn.critical_since == 1.0
    assert conn.receive_data(b"ALARM:3\r\n", now=1.1) == [Alarm(3, critical=False)]
    conn.send_reset(now=1.2)
    assert not conn.reset_due(1.2 + RESET_RETRY_S - 0.01) and conn.reset_due(1.2 + RESET_RETRY_S)
    (reset,) = conn.receive_data(BANNER, now=2.0)
    assert reset == Reset("1.1h", dropped=("G53 G1 X-5 F100",)) and pending.reset
    assert not conn.critical and not conn.resetting and conn.alarm == 3


def test_connection_refuses_a_line_grbl_cannot_take() -> None:
    conn = GrblConnection()
    with pytest.raises(ConfigError, match=r"one line of at most 79 characters"):
        conn.send_line("G1 X" + "1" * 80)
    with pytest.raises(ConfigError, match=r"line = '\$X\\nG0' is not allowed"):
        conn.send_line("$X\nG0")


# ---------------------------------------------------------------- make_ready (runs, calibrate)
def test_make_ready_resets_a_critical_alarm_then_homes() -> None:
    stage, peer, _ = open_stage(
        [
            (b"G53 G1 X-200.000 F600.000\n", b"ok\r\n"),
            (b"G4 P0.000\n", b""),
            (b"?", report("Run", -150.0, 600)),
            (b"\x18", BANNER + LOCKED),
            (b"?", report("Alarm", -150.0)),
            (b"$H\n", [(30.0, b"ok\r\n")]),
            (b"?", report("Idle", -1.0)),
        ]
    )
    peer.critical_alarm(at=0.3, code=1)
    with pytest.raises(StageAlarmError):
        stage.move_to(-0.2, 0.01)
    steps: list[str] = []
    status = stage.make_ready(steps.append)
    assert (status.state, status.position, status.alarm) == (StageState.IDLE, -0.001, None)
    assert steps == ["soft reset after ALARM:1 (Hard limit)", "homing ($H, up to 293 s)"]
    assert not peer.script


def test_make_ready_unlocks_when_homing_is_disabled_and_leaves_an_idle_stage_alone() -> None:
    no_homing = {**TANK_SETTINGS, 20: "0", 22: "0"}
    stage, peer, _ = open_stage(
        [
            (b"?", report("Alarm", -20.0)),
            (b"$X\n", b"[MSG:Caution: Unlocked]\r\nok\r\n"),
            (b"?", report("Idle", -20.0)),
            (b"?", report("Idle", -20.0)),
        ],
        settings=no_homing,
    )
    steps: list[str] = []
    assert stage.make_ready(steps.append).state is StageState.IDLE
    assert steps == ["unlocking ($X; homing is disabled, $22=0)"]
    assert stage.make_ready(steps.append).state is StageState.IDLE and len(steps) == 1
    assert not peer.script


def test_settings_asked_again_when_a_late_power_up_banner_drops_them() -> None:
    # An Uno reset by the open prints its power-up banner after the driver's reset was
    # answered: the '$$' sent meanwhile is dropped and is asked again.
    clock = ManualClock(0.0)
    peer = Grbl11Peer(
        clock,
        [
            (b"\x18", BANNER),
            (b"$$\n", BANNER + LOCKED),
            (b"$$\n", dump(TANK_SETTINGS)),
            (b"?", report("Alarm", 0.0)),
        ],
    )
    stage = GrblStage(peer, clock=clock).open()
    assert stage.settings.max_travel_z == 500.0 and not peer.script
    assert stage.connection.banners == 2
