"""The simulated GRBL controller on a manual clock: limits, alarms, homing, holds, jogs."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from hil.errors import ConfigError
from sim_devices.stage import GrblSimConfig, GrblState, ManualClock, SimulatedGrbl
from tests.stage.conftest import FREE, INSTANT


class Bench:
    """A simulator on a manual clock with a line-oriented view of its output."""

    def __init__(self, config: GrblSimConfig = FREE, t0: float = 10.0) -> None:
        self.clock = ManualClock(t0)
        self.sim = SimulatedGrbl(config, clock=self.clock)
        self.power_up = self.read()

    def read(self) -> list[str]:
        return self.sim.data_to_send().decode().split("\r\n")[:-1]

    def send(self, data: bytes | str) -> list[str]:
        self.sim.receive_data(data.encode() if isinstance(data, str) else data)
        return self.read()

    def at(self, t: float) -> list[str]:
        self.clock.advance(t - self.clock.now())
        self.sim.tick()
        return self.read()


def test_power_up_banner_and_homing_lock() -> None:
    assert Bench(FREE).power_up == ["", "Grbl 1.1h ['$' for help]"]
    locked = Bench(INSTANT)
    assert locked.power_up == ["", "Grbl 1.1h ['$' for help]", "[MSG:'$H'|'$X' to unlock]"]
    assert locked.send("G1 X-1 F100\n") == ["error:9"]
    assert locked.send("?")[0].startswith("<Alarm|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0")
    assert locked.send("$X\n") == ["[MSG:Caution: Unlocked]", "ok"]
    assert locked.sim.status().state is GrblState.IDLE


@pytest.mark.parametrize(
    ("line", "reply"),
    [
        ("", "ok"),
        ("G1 X1 X2", "error:25"),
        ("G1 X-1", "error:22"),
        ("123", "error:1"),
        ("G1 Xabc F100", "error:2"),
        ("G2 X1", "error:20"),
        ("G1 Y1 F100", "error:20"),
        ("G0 G1 X1", "error:21"),
        ("G4", "error:28"),
        ("$Q", "error:2"),  # read_float fails on Q: bad number format
        ("$110=-5", "error:4"),
        ("$0=2", "error:6"),
        ("$20=1", "error:10"),
        ("$H", "error:5"),
        ("$J X1 F100", "error:3"),  # $J without = is an invalid statement
        ("$J=G1 X1 F100", "error:16"),
        ("$999=1", "error:3"),
        ("G1 X-1 F100 " + "(" + "x" * 80 + ")", "ok"),  # comments are not stored
        ("G1 F100 X-" + "1" * 80, "error:11"),
    ],
)
def test_error_codes_for_bad_lines(line: str, reply: str) -> None:
    assert Bench().send(line + "\n")[-1] == reply


def test_settings_dump_and_write() -> None:
    bench = Bench()
    dump = bench.send("$$\n")
    assert dump[-1] == "ok"
    assert "$100=80.000" in dump and "$110=1200.000" in dump and "$10=3" in dump
    assert bench.send("$110=600\n") == ["ok"]
    assert "$110=600.000" in bench.send("$$\n")


def test_trapezoid_position_within_one_step_and_quantised() -> None:
    bench = Bench()
    assert bench.send("G1 X-100 F600\n") == ["ok"]  # 10 mm/s, 100 mm/s² -> 0.1 s ramps
    t = 10.0 + np.linspace(0.0, 10.3, 1031)
    x = bench.sim.true_position(t) * 1000.0
    tau = np.clip(t - 10.0, 0.0, 10.1)
    expected = -np.where(
        tau < 0.1,
        50 * tau**2,
        np.where(tau < 10.0, 0.5 + 10 * (tau - 0.1), 100 - 50 * (10.1 - tau) ** 2),
    )
    step = 1.0 / 80.0
    assert np.max(np.abs(x - expected)) <= step
    np.testing.assert_allclose(x * 80.0, np.round(x * 80.0), atol=1e-9)
    assert bench.at(20.2) == []
    assert bench.send("?")[0].startswith("<Idle|MPos:-100.000,")


def test_triangular_profile_for_a_short_move() -> None:
    bench = Bench()
    bench.send("G1 X-1 F6000\n")  # 1 mm at up to 100 mm/s, 100 mm/s²: peaks at 10 mm/s
    v = bench.sim.true_velocity(10.0 + np.linspace(0, 0.2, 201)) * 1000.0
    assert float(np.min(v)) == pytest.approx(-10.0, abs=1e-9)
    bench.at(10.1)
    assert bench.send("?")[0].startswith("<Run|MPos:-0.500,0.000,0.000|Bf:14,128|FS:600,0")


def test_step_quantisation_of_reports() -> None:
    bench = Bench(replace(INSTANT, homing=False, soft_limits=False, hard_limits=False,
                          steps_per_mm=3.0,
                                power_up_position_mm=0))  # fmt: skip
    bench.send("G1 X-1 F600\n")
    bench.at(20.0)
    # 1 mm is 3 steps; -0.5 mm is -1.5 steps and rounds to -2 steps = -0.667 mm.
    assert bench.send("?")[0].startswith("<Idle|MPos:-1.000,")
    bench.send("G91 G1 X0.5\n")
    bench.at(30.0)
    assert bench.send("?")[0].startswith("<Idle|MPos:-0.667,")


def test_soft_limit_alarm_is_critical_until_reset() -> None:
    bench = Bench(INSTANT)
    bench.send("$X\n")
    assert bench.send("G1 X-600 F600\n") == ["ALARM:2"]
    assert bench.send(b"\x18") == []  # lost: GRBL clears a reset that comes in the 0.5 s
    assert bench.at(10.5) == ["[MSG:Reset to continue]"]
    assert bench.send("?") == []  # ignored in a critical alarm
    assert bench.send("$X\n") == []
    # The G1 the main loop was inside is answered when the reset aborts it.
    assert bench.send(b"\x18") == [
        "ok", "", "Grbl 1.1h ['$' for help]", "[MSG:'$H'|'$X' to unlock]",
    ]  # fmt: skip
    assert bench.send("?")[0].startswith("<Alarm|")


def test_soft_limit_while_running_decelerates_then_alarms() -> None:
    bench = Bench(replace(INSTANT, homing_dir_mask=0))
    bench.send("$X\n")
    bench.send("G1 X-100 F600\n")
    bench.at(11.0)
    assert bench.send("G1 X-700\n") == []  # hold first
    assert bench.send("?")[0].startswith("<Hold:1|")
    assert bench.at(11.2) == ["ALARM:2"]
    assert bench.at(11.7) == ["[MSG:Reset to continue]"]
    assert bench.sim.status().velocity_mm_s == 0.0


def test_jog_beyond_travel_is_an_error_not_an_alarm() -> None:
    bench = Bench(INSTANT)
    bench.send("$X\n")
    assert bench.send("$J=G91 X-600 F600\n") == ["error:15"]
    assert bench.sim.status().state is GrblState.IDLE


def test_hard_limit_halts_instantly_with_alarm_1() -> None:
    config = replace(INSTANT, homing=True, soft_limits=False, hard_limits=True,
                           power_up_position_mm=-495.0)  # fmt: skip
    bench = Bench(config)
    bench.send("$X\n")
    bench.send("G1 X-10 F600\n")  # physically to -505 mm: the far switch is at -501 mm
    lines = bench.at(20.0)
    assert lines == ["ALARM:1", "[MSG:Reset to continue]"]  # 0.5 s apart
    status = bench.sim.status()
    assert status.velocity_mm_s == 0.0 and status.critical
    assert status.physical_mm == pytest.approx(-501.0, abs=1 / 80)
    assert bench.send(b"\x18")[-2:] == ["[MSG:Check Limits]", "[MSG:'$H'|'$X' to unlock]"]
    bench.send("$X\n")
    assert "Pn:X" in bench.send("?")[0]
    # Leaving the switch changes the pin: a hard limit again.
    assert bench.send("G1 X0 F600\n") == ["ok", "ALARM:1"]
    assert bench.at(30.0) == ["[MSG:Reset to continue]"]
    assert bench.sim.status().state is GrblState.ALARM


def test_homing_sets_machine_zero_and_clears_the_alarm() -> None:
    bench = Bench(replace(INSTANT, power_up_position_mm=-100.0))
    assert bench.send("$H\n") == []
    assert bench.send("?") == []  # no reports while homing
    # Seek 100 mm at 1000 mm/min (~6 s), then pull-off/locate/pull-off of 1 mm: done by 20 s.
    assert bench.at(20.0) == ["ok"]
    status = bench.sim.status()
    assert status.state is GrblState.IDLE
    assert status.machine_mm == pytest.approx(-1.0) and status.physical_mm == pytest.approx(-1.0)
    assert bench.send("G1 X-50 F600\n") == ["ok"]


def test_homing_fails_with_alarm_9_when_no_switch_is_found() -> None:
    bench = Bench(replace(INSTANT, max_travel_mm=100.0, power_up_position_mm=-50.0,
                          switch_axes=""))  # fmt: skip
    bench.send("$H\n")
    lines = bench.at(100.0)
    assert lines == ["ALARM:9", "ok", "", "Grbl 1.1h ['$' for help]", "[MSG:'$H'|'$X' to unlock]"]


def test_feed_hold_and_resume() -> None:
    bench = Bench()
    bench.send("G1 X-100 F600\n")
    bench.at(12.0)
    bench.send("!")
    assert bench.send("?")[0].startswith("<Hold:1|")
    bench.at(12.2)  # 10 mm/s at 100 mm/s² stops in 0.1 s
    held = bench.send("?")[0]
    assert held.startswith("<Hold:0|MPos:-20.000,")  # 19.5 mm + 0.5 mm to stop
    bench.at(15.0)
    # The first report after a reset carries the WCO, the second the overrides.
    assert held.endswith("|Ov:100,100,100>")
    assert bench.send("?")[0] == held.replace("|Ov:100,100,100", "")
    bench.send("~")
    assert bench.send("?")[0].startswith("<Run|")
    bench.at(40.0)
    assert bench.send("?")[0].startswith("<Idle|MPos:-100.000,")


def test_feed_hold_when_idle_then_resume() -> None:
    bench = Bench()
    bench.send("!")
    assert bench.send("?")[0].startswith("<Hold:0|")
    bench.send("~")
    assert bench.send("?")[0].startswith("<Idle|")


def test_jog_cancel_decelerates_flushes_and_idles() -> None:
    bench = Bench()
    assert bench.send("$J=G91 X-50 F600\n") == ["ok"]
    assert bench.send("$J=G91 X-50 F600\n") == ["ok"]
    assert bench.send("G1 X0 F100\n") == ["error:9"]  # g-code locked while jogging
    bench.at(11.0)
    assert bench.send("?")[0].startswith("<Jog|MPos:-9.500,0.000,0.000|Bf:13,")
    bench.send(b"\x85")
    bench.at(11.05)
    assert bench.send("?")[0].startswith("<Jog|")  # still decelerating
    bench.at(12.0)
    assert bench.send("?")[0].startswith("<Idle|MPos:-10.000,0.000,0.000|Bf:15,")


def test_soft_reset_in_motion_alarms_3_and_keeps_position() -> None:
    bench = Bench()
    bench.send("G1 X-100 F600\n")
    bench.at(12.0)
    assert bench.send(b"\x18") == ["ALARM:3"]
    assert bench.send("?") == []  # the firmware sits in the 0.5 s after an ALARM
    assert bench.at(12.5) == ["", "Grbl 1.1h ['$' for help]", "[MSG:'$H'|'$X' to unlock]"]
    assert bench.send("?")[0].startswith("<Alarm|MPos:-19.500,")  # halted at once
    bench.at(20.0)
    assert bench.sim.status().machine_mm == -19.5


def test_soft_reset_from_completed_hold_is_not_an_alarm() -> None:
    bench = Bench()
    bench.send("G1 X-100 F600\n")
    bench.at(12.0)
    bench.send("!")
    bench.at(13.0)
    assert bench.send(b"\x18") == ["", "Grbl 1.1h ['$' for help]"]
    assert bench.send("?")[0].startswith("<Idle|MPos:-20.000,")


def test_dwell_answers_when_the_planner_is_empty() -> None:
    bench = Bench()
    bench.send("G1 X-10 F600\n")
    assert bench.send("G4 P0\n") == []
    assert bench.send("$$\n") == []  # lines wait behind the dwell
    assert bench.at(11.0) == []
    lines = bench.at(11.2)  # the move takes 1.1 s
    assert lines[0] == "ok" and lines[-1] == "ok" and "$110=1200.000" in lines


def test_host_silence_watchdog_holds_a_move_and_stays_held() -> None:
    config = replace(INSTANT, homing=False, soft_limits=False, hard_limits=False,
                     power_up_position_mm=0,
                           host_silence_timeout_s=0.5)  # fmt: skip
    bench = Bench(config)
    bench.send("G1 X-100 F600\n")
    bench.at(10.4)
    bench.send("?")  # the host is alive: the watchdog restarts
    bench.at(10.8)
    assert bench.sim.status().state is GrblState.RUN
    bench.at(15.0)
    status = bench.sim.status()
    assert (status.state, status.substate, status.watchdog_tripped) == (GrblState.HOLD, 0, True)
    # Held at 0.9 s (0.5 s after the last byte), stopped 0.05 mm later.
    assert status.machine_mm == pytest.approx(-(0.5 + 10 * 0.8 + 0.5), abs=1 / 80)
    bench.at(100.0)
    assert bench.sim.status().machine_mm == status.machine_mm


def test_host_hang_up_holds_a_move_at_once() -> None:
    config = replace(INSTANT, homing=False, soft_limits=False, hard_limits=False,
                     power_up_position_mm=0,
                           host_silence_timeout_s=5.0)  # fmt: skip
    bench = Bench(config)
    bench.sim.connection_made()
    bench.send("G1 X-100 F600\n")
    bench.at(12.0)
    bench.sim.connection_lost()
    bench.at(13.0)
    status = bench.sim.status()
    assert status.state is GrblState.HOLD and status.machine_mm == pytest.approx(-20.0)


def test_true_position_is_vectorised_over_any_shape() -> None:
    bench = Bench()
    bench.send("G1 X-10 F600\n")
    t = 10.0 + np.array([[0.0, 0.5], [1.0, 5.0]])
    x = bench.sim.true_position(t)
    assert x.shape == (2, 2)
    assert x[1, 1] == -0.01 and x[0, 0] == 0.0


def test_bad_simulator_configuration() -> None:
    with pytest.raises(ConfigError, match=r"soft_limits = True is not allowed: must be False "
                       r"when homing is False"):  # fmt: skip
        replace(INSTANT, homing=False)
    with pytest.raises(ConfigError, match=r"max_rate_mm_min = 0.0 .* > 0"):
        replace(INSTANT, max_rate_mm_min=0.0)
    with pytest.raises(ConfigError, match=r"host_silence_timeout_s = -1"):
        replace(INSTANT, host_silence_timeout_s=-1)
    assert math.isfinite(INSTANT.max_travel_mm)
