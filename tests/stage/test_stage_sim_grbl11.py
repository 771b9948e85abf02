"""Golden conversations with the simulated GRBL 1.1h: host bytes in at given instants of the
injected clock, the device's lines out with the instant each appeared.

Each test is one row of issue 20's table, written from GRBL 1.1h's sources and
``doc/markdown/interface.md`` / ``commands.md``: ``report_alarm_message`` waits 0.5 s after
every ``ALARM:n``; ``protocol_exec_rt_system`` then prints ``[MSG:Reset to continue]`` for
ALARM 1 and 2 and clears a pending reset; ``protocol_exec_rt_suspend`` blocks the main loop
during a hold; ``limits_go_home`` homes cycle by cycle; ``report_realtime_status`` refreshes
``WCO`` every 10 (idle) / 30 (busy) reports and ``Ov`` every 10 / 20.
The instants are sampled every 0.5 ms, so the times below hold to half a millisecond.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_devices.stage import GrblSimConfig, GrblState, ManualClock, SimulatedGrbl
from sim_devices.stage.motion import Path, Piece, plan_move
from sim_devices.stage.planner import plan_blocks

STOCK = GrblSimConfig()
BANNER = ["", "Grbl 1.1h ['$' for help]"]
LOCK = "[MSG:'$H'|'$X' to unlock]"
STEP = 0.0005


class Conversation:
    """Plays a script of ``(t, host bytes)`` and records ``(t, line)`` from the device."""

    def __init__(self, config: GrblSimConfig = STOCK) -> None:
        self.clock = ManualClock(0.0)
        self.sim = SimulatedGrbl(config, clock=self.clock)
        self._buffer = ""
        self.power_up = self._lines()

    def _lines(self) -> list[str]:
        self._buffer += self.sim.data_to_send().decode()
        *lines, self._buffer = self._buffer.split("\r\n")
        return lines

    def play(self, script: list[tuple[float, bytes]], until: float) -> list[tuple[float, str]]:
        got: list[tuple[float, str]] = []
        pending = sorted(script, key=lambda s: s[0])
        for k in range(round(until / STEP) + 1):
            t = k * STEP
            self.clock.advance(t - self.clock.now())
            self.sim.tick()
            while pending and pending[0][0] <= t + 1e-12:
                self.sim.receive_data(pending.pop(0)[1])
            got += [(round(t, 4), line) for line in self._lines()]
        return got


def move_time(distance: float, v_max: float, accel: float = 10.0) -> float:
    """Rest-to-rest move time (s): trapezoid or triangle."""
    if distance >= v_max**2 / accel:
        return distance / v_max + v_max / accel
    return 2 * (distance / accel) ** 0.5


def reach_time(distance: float, v_max: float, accel: float = 10.0) -> float:
    """Time (s) to cover ``distance`` from rest on a long move: accelerate, then cruise
    (a homing approach stops on its switch before its planned end)."""
    d_acc = v_max**2 / (2 * accel)
    if distance <= d_acc:
        return (2 * distance / accel) ** 0.5
    return v_max / accel + (distance - d_acc) / v_max


def lines(got: list[tuple[float, str]]) -> list[str]:
    return [line for _, line in got]


def at(got: list[tuple[float, str]], line: str) -> float:
    return next(t for t, text in got if text == line)


def test_power_up_stock_defaults_and_blank_eeprom() -> None:
    stock = Conversation()
    assert stock.power_up == BANNER
    dump = lines(stock.play([(0.0, b"$$\n")], 0.01))
    assert dump[:8] == ["$0=10", "$1=25", "$2=0", "$3=0", "$4=0", "$5=0", "$6=0", "$10=1"]
    for setting in ("$22=0", "$100=250.000", "$110=500.000", "$120=10.000", "$130=200.000"):
        assert setting in dump
    assert dump[-1] == "ok"
    blank = Conversation(replace(STOCK, blank_eeprom=True))
    assert blank.power_up[0] == "error:7"
    assert blank.power_up[1:-2] == dump[:-1]  # the restored settings, then the banner
    assert blank.power_up[-2:] == BANNER


def test_ok_latency_is_2_4_ms_per_line() -> None:
    got = Conversation().play([(0.0, b"G21\nG90\n$X\n")], 0.02)
    assert got == [(0.0025, "ok"), (0.005, "ok"), (0.0075, "ok")]


def test_hard_limit_alarm_then_message_half_a_second_later_and_a_lost_reset() -> None:
    conv = Conversation(replace(STOCK, hard_limits=True, power_up_position_mm=-195.0))
    got = conv.play(
        [(0.0, b"G1 X-10 F300\n"), (1.6, b"\x18"), (1.7, b"?"), (2.2, b"?"), (2.5, b"\x18"),
         (2.6, b"?")],
        3.0,
    )  # fmt: skip
    # 6 mm to the far switch at -201 mm: 0.5 s (1.25 mm) ramp to 5 mm/s, then 4.75 mm.
    t_hit = 0.0024 + 0.5 + 4.75 / 5.0
    assert lines(got) == [
        "ok", "ALARM:1", "[MSG:Reset to continue]",
        *BANNER, "[MSG:Check Limits]", LOCK,
        "<Alarm|MPos:-6.000,0.000,0.000|FS:0,0|Pn:X|WCO:0.000,0.000,0.000>",
    ]  # fmt: skip
    assert at(got, "ALARM:1") == pytest.approx(t_hit, abs=STEP)
    assert at(got, "[MSG:Reset to continue]") == pytest.approx(t_hit + 0.5, abs=STEP)
    assert at(got, "[MSG:Check Limits]") == 2.5  # the reset at 1.6 s (in the gap) was lost


def test_critical_alarm_ignores_status_queries_until_reset() -> None:
    conv = Conversation(replace(STOCK, homing=True, soft_limits=True))
    got = conv.play(
        [(0.0, b"$X\n"), (0.01, b"G1 X10 F100\n"), (0.2, b"?"), (0.8, b"?$$\n"), (1.0, b"\x18")],
        1.1,
    )
    assert got == [
        (0.0025, "[MSG:Caution: Unlocked]"), (0.0025, "ok"),
        (0.0125, "ALARM:2"), (0.5125, "[MSG:Reset to continue]"),
        (1.0, "ok"), (1.0, ""), (1.0, "Grbl 1.1h ['$' for help]"), (1.0, LOCK),
    ]  # fmt: skip


def test_lines_sent_during_a_feed_hold_wait_for_the_resume() -> None:
    conv = Conversation()
    got = conv.play([(0.0, b"G1 X-20 F300\n"), (1.0, b"!"), (1.5, b"G1 X-1\n?"), (2.0, b"~")], 2.1)
    assert got[0] == (0.0025, "ok")
    assert got[1][1].startswith("<Hold:0|MPos:-4.988,")  # the line is not answered while held
    assert got[2] == (2.0025, "ok")
    conv.play([], 12.0)
    assert conv.sim.status().machine_mm == -1.0  # then executed, after the rest of X-20


def test_reset_discards_lines_queued_during_a_hold() -> None:
    conv = Conversation()
    got = conv.play([(0.0, b"G1 X-20 F300\n"), (1.0, b"!"), (1.5, b"G1 X-1\n"), (2.0, b"\x18")], 3)
    assert lines(got) == ["ok", *BANNER]  # hold complete: no alarm, the queued line is gone
    assert conv.sim.status().state is GrblState.IDLE


def test_reset_while_moving_alarm_3_then_banner_and_the_waiting_dwell_ok_first() -> None:
    conv = Conversation()
    got = conv.play([(0.0, b"G1 X-20 F300\nG4 P0\n"), (1.0, b"\x18")], 2.0)
    assert got == [
        (0.0025, "ok"), (1.0, "ALARM:3"),
        (1.5, "ok"), (1.5, ""), (1.5, "Grbl 1.1h ['$' for help]"), (1.5, LOCK),
    ]  # fmt: skip


def test_homing_z_then_x_and_y_needs_every_switch() -> None:
    config = replace(STOCK, homing=True, power_up_position_mm=-10.0, power_up_yz_mm=(-20, -5))
    conv = Conversation(config)
    got = conv.play([(0.0, b"$H\n"), (1.0, b"?")], 15.0)
    assert lines(got) == ["ok"]  # no report while homing
    # Each cycle: approach at $25 (500 mm/min), pull-off 1 mm at $25, locate 1 mm at $24
    # (25 mm/min), pull-off 1 mm at $25, each followed by $26 = 250 ms. Z starts 5 mm from
    # its switch; then X and Y together, Y (20 mm away) last.
    seek, feed = 500 / 60, 25 / 60
    rest = move_time(1, seek) + reach_time(1, feed) + move_time(1, seek) + 4 * 0.25
    expected = 0.0024 + reach_time(5, seek) + rest + reach_time(20, seek) + rest
    assert at(got, "ok") == pytest.approx(expected, abs=STEP)
    report = lines(conv.play([(15.0, b"?")], 15.01))[0]
    assert report.startswith("<Idle|MPos:-1.000,-1.000,-1.000|")
    no_y = Conversation(replace(config, switch_axes="XZ"))
    got = no_y.play([(0.0, b"$H\n")], 80.0)
    assert lines(got) == ["ALARM:9", "ok", *BANNER, LOCK]
    assert at(got, "ok") - at(got, "ALARM:9") == pytest.approx(0.5, abs=STEP)


def test_homing_with_an_x_only_cycle_homes_x_alone() -> None:
    conv = Conversation(replace(STOCK, homing=True, homing_cycles=("X",), switch_axes="X"))
    got = conv.play([(0.0, b"$H\n")], 40.0)
    assert lines(got) == ["ok"]
    assert lines(conv.play([(40.0, b"?")], 40.01))[0].startswith("<Idle|MPos:-1.000,0.000,")


def test_leaving_a_limit_switch_is_a_hard_limit_too() -> None:
    conv = Conversation(replace(STOCK, hard_limits=True, power_up_position_mm=-201.0))
    assert conv.power_up == [*BANNER, "[MSG:Check Limits]", LOCK]
    got = conv.play([(0.0, b"$X\n"), (0.01, b"G91 G1 X1 F300\n")], 0.6)
    assert got == [
        (0.0025, "[MSG:Caution: Unlocked]"), (0.0025, "ok"),
        (0.0125, "ok"), (0.0125, "ALARM:1"), (0.5125, "[MSG:Reset to continue]"),
    ]  # fmt: skip


def test_planner_blends_collinear_blocks() -> None:
    conv = Conversation()
    # Streamed a line every 3 ms (the 128-byte serial buffer would drop a burst).
    script = [(0.003 * k, b"G91 G1 X-0.5 F300\n") for k in range(20)] + [(0.06, b"G4 P0\n")]
    got = conv.play(script, 3.0)
    # The dwell's ok marks the planner empty: 10 mm with one ramp up and one down, 2.5 s
    # (stopping after each 0.5 mm block would take 20 x 2 sqrt(0.5 / 10) = 8.9 s).
    assert lines(got) == ["ok"] * 21
    assert got[-1][0] == pytest.approx(0.0024 + 2.5, abs=STEP)
    assert conv.sim.status().machine_mm == -10.0


def test_wco_and_overrides_refresh_and_offsets() -> None:
    conv = Conversation()
    reports = lines(conv.play([(0.001 * k, b"?") for k in range(12)], 0.02))
    assert reports[0] == "<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>"
    assert reports[1] == "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"
    assert [k for k, r in enumerate(reports) if "WCO" in r] == [0, 10]
    assert [k for k, r in enumerate(reports) if "Ov" in r] == [1, 11]
    got = lines(conv.play([(0.1, b"G10 L2 P1 X-5\n"), (0.2, b"?"), (0.3, b"G92 X1\n?")], 0.4))
    assert got[:2] == ["ok", "<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:-5.000,0.000,0.000>"]
    assert got[2:] == ["<Idle|MPos:0.000,0.000,0.000|FS:0,0>", "ok"]  # '?' before the line
    wpos = lines(conv.play([(0.4, b"$10=0\n"), (0.5, b"?")], 0.51))
    assert wpos == ["ok", "<Idle|WPos:1.000,0.000,0.000|FS:0,0|WCO:-1.000,0.000,0.000>"]
    params = lines(conv.play([(0.6, b"$#\n")], 0.61))
    assert params[0] == "[G54:-5.000,0.000,0.000]" and "[G92:4.000,0.000,0.000]" in params


def test_wco_refresh_is_30_while_busy() -> None:
    conv = Conversation()
    script = [(0.0, b"G1 X-50 F300\n")] + [(0.01 + 0.001 * k, b"?") for k in range(32)]
    reports = lines(conv.play(script, 0.05))[1:]
    assert [k for k, r in enumerate(reports) if "WCO" in r] == [0, 30]


@pytest.mark.parametrize(
    ("line", "reply"),
    [
        ("$Q", ["error:2"]),
        ("G53", ["ok"]),
        ("G4 P-1", ["error:4"]),
        ("G20", ["ok"]),
        ("G92 X0", ["ok"]),
        ("G10 L20 P1 X0", ["ok"]),
        ("M3 S1000", ["ok"]),
        ("M8", ["ok"]),
        ("$N", ["$N0=", "$N1=", "ok"]),
        ("$C", ["[MSG:Enabled]", "ok"]),
        ("$SLP", ["ok", "[MSG:Sleeping]"]),
        ("$J X1", ["error:3"]),
        ("$300=1", ["error:3"]),
        ("G2 X1", ["error:20"]),
        ("G10 L2 X1", ["error:28"]),
        ("G10 L2 P7 X1", ["error:29"]),
        ("G1 X1 F-1", ["error:4"]),
        ("G80 X1", ["error:31"]),
        ("G4 G53 P1", ["error:21"]),  # both non-modal (group 0)
        ("G0 P1", ["error:36"]),
    ],
)
def test_error_codes_and_accepted_commands(line: str, reply: list[str]) -> None:
    assert lines(Conversation().play([(0.0, line.encode() + b"\n")], 0.01)) == reply


def test_unlock_while_moving_is_ok_and_a_jog_after_a_cancel_waits() -> None:
    conv = Conversation()
    got = conv.play(
        [(0.0, b"G1 X-5 F300\n"), (0.1, b"$X\n"), (0.2, b"$J=G91 X-5 F300\n"), (0.5, b"\x85"),
         (0.5001, b"$J=G91 X1 F300\n")],
        1.2,
    )  # fmt: skip
    assert got[:2] == [(0.0025, "ok"), (0.1025, "ok")]
    assert got[2] == (0.2025, "error:8")  # $J= is refused while a G1 runs (state Run)
    assert got[3] == (0.503, "error:8")  # 0x85 cancels jogs only: the G1 still runs
    jog = Conversation()
    got = jog.play([(0.0, b"$J=G91 X-5 F300\n"), (0.5, b"\x85"), (0.501, b"$J=G91 X1 F300\n")], 1.2)
    # The cancel at 0.5 s decelerates from 4.976 mm/s at 10 mm/s²; the new jog waits for it.
    assert got == [(0.0025, "ok"), (pytest.approx(0.5 + 0.4976 + 0.0024, abs=STEP), "ok")]


def test_sync_commands_wait_for_the_planner() -> None:
    got = Conversation().play([(0.0, b"G1 X-1 F300\nM8\n")], 1.0)
    # 1 mm at F300 with 10 mm/s²: triangle peaking at sqrt(10) mm/s, 2 / sqrt(10) s.
    assert lines(got) == ["ok", "ok"]
    # M8 is parsed while the move runs; its ok comes as the planner empties.
    assert got[1][0] == pytest.approx(0.0024 + 2 / 10**0.5, abs=STEP)


def test_reset_while_homing_is_alarm_6_and_a_stuck_pull_off_alarm_8() -> None:
    homing = replace(STOCK, homing=True, homing_cycles=("X",), switch_axes="X")
    got = Conversation(homing).play([(0.0, b"$H\n"), (1.0, b"\x18")], 2.0)
    assert got == [
        (1.0, "ALARM:6"), (1.5, "ok"), (1.5, ""), (1.5, "Grbl 1.1h ['$' for help]"), (1.5, LOCK),
    ]  # fmt: skip
    # Resting on the far switch (one pin per axis): the approach locks at once, the pull-off
    # moves further onto the switch, which stays engaged.
    stuck = Conversation(replace(homing, power_up_position_mm=-201.5))
    got = stuck.play([(0.0, b"$H\n")], 2.0)
    assert lines(got) == ["ALARM:8", "ok", *BANNER, LOCK]
    # Locked at once, the $26 debounce (0.25 s), then the 1 mm pull-off.
    assert at(got, "ALARM:8") == pytest.approx(0.0024 + 0.25 + move_time(1, 500 / 60), abs=STEP)


def test_soft_limit_while_running_stops_then_alarms() -> None:
    conv = Conversation(replace(STOCK, homing=True, soft_limits=True, power_up_position_mm=0))
    got = conv.play([(0.0, b"$X\nG1 X-20 F300\n"), (1.0, b"G1 X-300\n")], 3.0)
    # The offending line is parsed at 1.0024 s; the cycle decelerates (0.5 s) first.
    assert lines(got) == ["[MSG:Caution: Unlocked]", "ok", "ok", "ALARM:2",
                          "[MSG:Reset to continue]"]  # fmt: skip
    assert at(got, "ALARM:2") == pytest.approx(1.0024 + 0.5, abs=STEP)
    assert at(got, "[MSG:Reset to continue]") == pytest.approx(1.0024 + 1.0, abs=STEP)
    assert conv.sim.status().velocity_mm_s == 0.0


def test_a_full_planner_holds_the_line_until_a_block_ends() -> None:
    conv = Conversation()
    script = [(0.003 * k, f"G1 X{-1 - (k % 2)} F300\n".encode()) for k in range(17)]
    got = conv.play(script, 0.3)
    # 16 lines are not all answered: after the first 15 blocks the planner is full (the
    # first runs, 14 wait); the 16th line waits for room (the first 1 mm takes 0.63 s).
    assert len(got) == 15
    got = lines(conv.play([(0.31, b"\x18")], 1.0))
    assert got[:2] == ["ALARM:3", "ok"]  # the line blocked in the planner, answered at reset


def test_inches_check_mode_sleep_and_restore() -> None:
    conv = Conversation()
    got = lines(conv.play([(0.0, b"G20 G1 X-0.1 F10\nG4 P0\n")], 2.0))
    assert got == ["ok", "ok"]  # 2.54 mm at 254 mm/min
    assert conv.sim.status().machine_mm == -2.54  # reported in mm
    check = lines(conv.play([(2.0, b"$C\n"), (2.1, b"G1 X-50 F100\n"), (2.2, b"$C\n")], 2.3))
    assert check == ["[MSG:Enabled]", "ok", "ok", "[MSG:Disabled]", "ok", *BANNER]
    assert conv.sim.status().machine_mm == -2.54  # checked, not moved
    sleep = lines(conv.play([(2.4, b"$SLP\n"), (2.5, b"?"), (2.6, b"\x18")], 2.7))
    assert sleep[:2] == ["ok", "[MSG:Sleeping]"]
    assert sleep[2].startswith("<Sleep|")
    assert sleep[3:] == [*BANNER, LOCK]
    restored = lines(conv.play([(2.8, b"$110=900\n"), (2.9, b"$RST=$\n"), (3.0, b"$$\n")], 3.1))
    assert restored[:3] == ["ok", "[MSG:Restoring defaults]", "ok"]
    assert "$110=500.000" in restored


@given(
    lengths=st.lists(st.floats(0.05, 20.0), min_size=1, max_size=15),
    rate=st.floats(0.5, 50.0),
)
@settings(max_examples=60, deadline=None)
def test_collinear_blocks_at_one_rate_run_as_one_move(lengths: list[float], rate: float) -> None:
    """Chunks == whole: blocks along one direction at one rate take as long as one move."""
    targets = list(np.cumsum(lengths))
    _, ends = plan_blocks(0.0, 0.0, 0.0, targets, [rate] * len(targets), 10.0, 0.01)
    whole = plan_move(0.0, 0.0, targets[-1], rate, 10.0)[-1].t
    assert ends[-1] == pytest.approx(whole, rel=1e-7)
    assert all(b > a for a, b in zip([0.0, *ends], ends, strict=False))


def test_a_reversal_stops_at_the_junction() -> None:
    pieces, ends = plan_blocks(0.0, 0.0, 0.0, [10.0, 0.0], [5.0, 5.0], 10.0, 0.01)
    assert ends == pytest.approx([2.5, 5.0])
    assert path_state(pieces, 2.5) == pytest.approx((10.0, 0.0))


def path_state(pieces: list[Piece], t: float) -> tuple[float, float]:
    path = Path(pieces[0].t, pieces[0].x)
    path.replace_from(pieces[0].t, pieces)
    return path.state_at(t)


def test_jogs_wait_for_planner_room_too() -> None:
    conv = Conversation()
    script = [(0.003 * k, f"$J=G90 X{-1 - (k % 2)} F300\n".encode()) for k in range(16)]
    assert len(conv.play(script, 0.3)) == 15
    assert lines(conv.play([], 1.0)) == ["ok"]  # when the first 1 mm jog block ends
