"""GrblStage over a real raw pty against the simulated GRBL controller.

Most tests share one manual clock between driver and simulator (the driver's waits advance
it), so long moves take milliseconds; one test runs in real time with a short move; the
safety test kills a host process mid-move.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hil.devices.grbl import GrblStage
from hil.devices.stage import StageState
from hil.devices.stage_errors import StageLimitError
from sim_devices.pty_endpoint import PtyEndpoint, tick_wait_s
from sim_devices.stage import GrblState, ManualClock, SimulatedGrblOnPty
from tests.stage.conftest import INSTANT, LAB

ROOT = Path(__file__).resolve().parents[2]


def wait_until(predicate: object, timeout: float = 10.0) -> bool:
    """Poll ``predicate()`` in wall time (for the real-time tests only)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():  # type: ignore[operator]
            return True
        time.sleep(0.01)
    return False


@pytest.mark.slow
def test_home_move_and_profile_on_simulated_time() -> None:
    clock = ManualClock(1000.0)
    # The driver reads in 0.2 s steps of the manual clock: a reply latency would be read a
    # step late and date the profile 0.2 s late, so the lines here are answered at once.
    config = replace(INSTANT, power_up_position_mm=-120.0)
    with (
        SimulatedGrblOnPty(config, clock=clock) as sim,
        GrblStage(sim.port_name, clock=clock, wait_step=0.2) as stage,
    ):
        assert stage.status().state is StageState.ALARM
        homed = stage.home()
        assert (homed.state, homed.position) == (StageState.IDLE, pytest.approx(-0.001))
        moved = stage.move_to(-0.1, 0.01)
        assert moved.position == pytest.approx(-0.1)
        assert sim.status().physical_mm == pytest.approx(-100.0)

        window = stage.run_profile(-0.12, -0.22, 0.005, 0.002, 0.002)
        assert window.t_end - window.t_start == pytest.approx(20.0)
        t = np.linspace(window.t_start, window.t_end, 41)
        truth = sim.call(lambda g: g.true_position(t))
        step = 1e-3 / 80.0
        np.testing.assert_allclose(truth, np.linspace(-0.12, -0.22, 41), atol=step)
        speed = sim.call(lambda g: g.true_velocity(t))
        np.testing.assert_allclose(speed, -0.005, rtol=1e-9)
        assert stage.status().position == pytest.approx(-0.222)


def test_soft_limit_refused_over_pty_sends_nothing() -> None:
    clock = ManualClock(0.0)
    config = replace(
        LAB, homing=False, soft_limits=False, hard_limits=False, power_up_position_mm=0.0
    )
    with (
        SimulatedGrblOnPty(config, clock=clock) as sim,
        GrblStage(sim.port_name, clock=clock, wait_step=0.2) as stage,
    ):
        received: list[bytes] = []
        original = sim.grbl.receive_data

        def spy(data: bytes) -> None:
            received.append(data)
            original(data)

        sim.call(lambda g: setattr(g, "receive_data", spy))
        with pytest.raises(StageLimitError, match=r"x \(axis X\) = -0.6 .* \[-0.5, 0\] m"):
            stage.move_to(-0.6, 0.01)
        with pytest.raises(StageLimitError, match=r"v \(axis X\) = 0.05 .* \(0, 0.02\] m/s"):
            stage.move_to(-0.1, 0.05)
        # A status query answered is a barrier: the pty keeps order, so anything the refused
        # moves had written would have reached the controller before the "?".
        stage.status()
        assert b"".join(received) == b"?"


def test_short_move_in_real_time() -> None:
    config = replace(LAB, homing=False, soft_limits=False, hard_limits=False,
                     power_up_position_mm=0.0,
                           acceleration_mm_s2=500.0)  # fmt: skip
    with SimulatedGrblOnPty(config) as sim, GrblStage(sim.port_name) as stage:
        status = stage.move_to(-0.002, 0.02)  # 2 mm at 20 mm/s: about 0.14 s
        assert (status.state, status.position) == (StageState.IDLE, pytest.approx(-0.002))
        assert sim.status().machine_mm == pytest.approx(-2.0)


def test_exception_inside_with_block_holds_the_simulated_stage() -> None:
    clock = ManualClock(0.0)
    config = replace(
        LAB, homing=False, soft_limits=False, hard_limits=False, power_up_position_mm=0.0
    )
    with SimulatedGrblOnPty(config, clock=clock) as sim:
        with pytest.raises(KeyboardInterrupt), GrblStage(sim.port_name, clock=clock) as stage:
            stage.move_to(-0.3, 0.01, wait=False)
            clock.advance(2.0)
            raise KeyboardInterrupt
        assert wait_until(lambda: sim.status().state is GrblState.HOLD)
        clock.advance(5.0)
        status = sim.status()
        assert (status.state, status.substate, status.velocity_mm_s) == (GrblState.HOLD, 0, 0.0)
        assert -40.0 < status.machine_mm < -10.0


HOST_SCRIPT = textwrap.dedent(
    """
    import sys
    from hil.devices.grbl import GrblStage
    with GrblStage(sys.argv[1]) as stage:
        print("moving", flush=True)
        stage.move_to(-0.3, 0.01)
    print("finished", flush=True)
    """
)


@pytest.mark.slow
def test_killed_host_leaves_the_stage_held() -> None:
    config = replace(LAB, homing=False, soft_limits=False, hard_limits=False,
                     power_up_position_mm=0.0,
                           host_silence_timeout_s=2.0)  # fmt: skip
    with SimulatedGrblOnPty(config) as sim:
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        host = subprocess.Popen(
            [sys.executable, "-c", HOST_SCRIPT, sim.port_name],
            stdout=subprocess.PIPE,
            env=env,
            cwd=ROOT,
        )
        try:
            assert host.stdout is not None
            assert host.stdout.readline().strip() == b"moving"
            assert wait_until(lambda: sim.status().machine_mm < -3.0, timeout=60.0)
            assert sim.status().state is GrblState.RUN  # the live host kept the watchdog fed
            os.kill(host.pid, signal.SIGKILL)
            host.wait(timeout=10)
        finally:
            if host.poll() is None:
                host.kill()
                host.wait()
            if host.stdout is not None:
                host.stdout.close()
        assert wait_until(
            lambda: sim.status().state is GrblState.HOLD and sim.status().substate == 0,
            timeout=60.0,
        )
        frozen = sim.status()
        # The simulator's motion is analytic: its plan for the next minute (no host is left to
        # change it) must keep the carriage where the hold left it, at rest.
        ahead = time.monotonic() + np.array([0.3, 1.0, 60.0])
        planned = sim.call(lambda g: g.true_position(ahead))
        planned_speed = sim.call(lambda g: g.true_velocity(ahead))
        assert frozen.velocity_mm_s == 0.0
        np.testing.assert_array_equal(planned_speed, 0.0)
        np.testing.assert_allclose(planned * 1000.0, frozen.physical_mm, rtol=0, atol=1e-9)
        assert frozen.watchdog_tripped and -300.0 < frozen.machine_mm < -3.0


class Recorder:
    """A sans-IO device that records what happens and echoes upper-case."""

    def __init__(self) -> None:
        self.events: list[str] = []
        self.received = bytearray()
        self.ticks = 0

    def receive_data(self, data: bytes) -> None:
        self.received += data

    def data_to_send(self) -> bytes:
        out = bytes(self.received).upper()
        self.received.clear()
        return out

    def tick(self) -> None:
        self.ticks += 1

    def connection_made(self) -> None:
        self.events.append("made")

    def connection_lost(self) -> None:
        self.events.append("lost")


def test_pty_endpoint_is_raw_and_reports_connections() -> None:
    import serial

    device = Recorder()
    with PtyEndpoint(device) as endpoint:
        port = serial.serial_for_url(endpoint.port_name, timeout=2)
        payload = bytes(range(1, 128)).replace(b"\x11", b"").replace(b"\x13", b"")
        port.write(payload + b"\r\n\x03\x1a")
        expected = payload.upper() + b"\r\n\x03\x1a"
        got = port.read(len(expected))
        assert got == expected  # no echo, no CR/LF mapping, no signals from ^C/^Z
        port.close()
        assert wait_until(lambda: device.events == ["made", "lost"])
        assert device.ticks > 0


@pytest.mark.parametrize("ahead_s", [0.0004, 0.001, 0.0022, 0.0, -0.5])
def test_pty_pump_sleeps_until_the_next_tick_instead_of_spinning(ahead_s: float) -> None:
    # A sub-millisecond wait must stay a wait (a zero timeout would spin between ticks).
    assert tick_wait_s(ahead_s, 0.0) == max(0.0, ahead_s)
