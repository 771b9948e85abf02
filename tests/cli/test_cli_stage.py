"""``hil stage`` against the simulated GRBL 1.1 controller in memory on a manual clock.

Every command opens ``sim://stage?via=memory`` (the controller runs in the reader's thread),
with the clock and the machine injected through :data:`hil.cli.stage.STAGE_OPTIONS`: homing
and moves take milliseconds of wall time, and each command starts a fresh controller that
powers up locked (homing enabled) with the carriage 20 mm from its homing switch.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

import hil.cli.stage as stage_cli
from hil.cli.main import main
from hil.experiments.experiment import DEFAULT_EXPERIMENT
from sim_devices.stage import GrblSimConfig, ManualClock

from .conftest import one_line_error

URL = ["--url", "sim://stage?via=memory"]
#: Homing on, 400 mm of travel, 600 mm/min, 50 mm/s^2, 20 mm from the switch at power-up.
CONFIG = GrblSimConfig(
    max_travel_mm=400.0, max_rate_mm_min=600.0, acceleration_mm_s2=50.0,
    power_up_position_mm=-20.0, homing=True, soft_limits=True, hard_limits=True,
)  # fmt: skip


@pytest.fixture(autouse=True)
def simulated(monkeypatch: pytest.MonkeyPatch) -> ManualClock:
    clock = ManualClock(0.0)
    options = {"clock": clock, "transport_options": {"config": CONFIG}}
    monkeypatch.setattr(stage_cli, "STAGE_OPTIONS", options)
    monkeypatch.delenv(stage_cli.URL_ENV, raising=False)
    return clock


def _json(capsys: pytest.CaptureFixture[str]) -> dict:
    return json.loads(capsys.readouterr().out)


def test_status_at_power_up_says_locked_and_what_to_do(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["stage", "status", *URL]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "state      Alarm"
    assert out[3] == (
        "alarm      locked at power-up or reset: 'hil stage home' (or 'hil stage unlock')"
    )
    assert "message    [MSG:'$H'|'$X' to unlock]" in out


def test_home_without_homing_says_how_to_enable_it_or_unlock(
    simulated: ManualClock, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # The hint named only the Python API (write_setting, unlock()).
    config = dataclasses.replace(CONFIG, homing=False, soft_limits=False)
    options = {"clock": simulated, "transport_options": {"config": config}}
    monkeypatch.setattr(stage_cli, "STAGE_OPTIONS", options)
    # The refusal is the only line: no "stage: homing ($H, ...)" progress line before it.
    assert one_line_error(capsys, ["stage", "home", *URL]) == (
        "hil stage: error: homing_enabled ($22) = False is not allowed: must be True to run a"
        " homing cycle; set $22=1 on the controller (write_setting('homing_enabled', True)), or"
        " unlock it with $X instead (GrblStage.unlock(), hil stage unlock)"
    )


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["jog", "nan"], "DX (jog target x (axis X)) = nan"),
        (["jog", "-0.5"], "DX (jog target x (axis X)) = -0.5"),
        (["jog", "-0.01", "--speed", "0"], "--speed (v (axis X)) = 0.0"),
        (["move", "nan"], "X (x (axis X)) = nan"),
        (["move", "-0.1", "--speed", "inf"], "--speed (v (axis X)) = inf"),
        (["move", "-0.1", "--accel", "-1"], "--accel (a (axis X)) = -1.0"),
    ],
)
def test_a_refused_jog_or_move_says_only_why(
    argv: list[str],
    named: str,
    monkeypatch: pytest.MonkeyPatch,
    simulated: ManualClock,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # The driver's checks run before the progress line ("stage: jogging ..."), which would
    # announce a motion that never starts. Homing off: the controller powers up Idle at
    # machine 0, free to move (GRBL's soft limits need homing; the driver's do not).
    config = dataclasses.replace(CONFIG, homing=False, soft_limits=False)
    options = {"clock": simulated, "transport_options": {"config": config}}
    monkeypatch.setattr(stage_cli, "STAGE_OPTIONS", options)
    err = one_line_error(capsys, ["stage", *argv, *URL])
    assert err.startswith(f"hil stage: error: {named} is not allowed: must be "), err


def test_home_then_status_as_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["stage", "home", "--json", *URL]) == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert (doc["state"], doc["position_m"], doc["alarm"]) == ("Idle", -0.001, None)
    assert doc["messages"] == []  # the power-up lock message came before the homing
    assert captured.err.startswith("stage: homing ($H, up to ")


def test_unlock_and_a_jog_refused_while_locked(capsys: pytest.CaptureFixture[str]) -> None:
    # Each command starts its own simulated controller, locked at power-up: the jog is
    # refused with what to do about it (exit status 1).
    assert main(["stage", "unlock", "--json", *URL]) == 0
    assert _json(capsys)["state"] == "Idle"
    assert main(["stage", "jog", "--json", "-0.01", *URL]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1, err  # refused before the "stage: jogging" progress line
    assert err[0].startswith("hil stage jog: sim://stage?via=memory: stage is in ALARM"), err
    assert "home with $H" in err[0]


def test_move_and_jog_after_homing_in_the_same_controller(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # One controller for the three commands, as a lab's stage stays powered between them.
    from sim_devices.stage import SimulatedGrbl

    clock = stage_cli.STAGE_OPTIONS["clock"]
    grbl = SimulatedGrbl(CONFIG, clock=clock)
    import hil.transports.sim as sim_transport

    def keep_one(query: dict, options: dict, timeout: float) -> sim_transport.MemoryStageLink:
        return sim_transport.MemoryStageLink(grbl, timeout=timeout)

    monkeypatch.setattr(sim_transport, "open_sim_stage", keep_one)
    assert main(["stage", "home", "--json", *URL]) == 0
    capsys.readouterr()
    assert main(["stage", "move", "--json", "-0.1", "--speed", "0.01", *URL]) == 0
    assert _json(capsys)["position_m"] == pytest.approx(-0.1)
    assert main(["stage", "jog", "--json", "-0.02", *URL]) == 0
    assert _json(capsys)["position_m"] == pytest.approx(-0.12)
    assert grbl.status().machine_mm == pytest.approx(-120.0)
    assert main(["stage", "move", "-0.5", *URL]) == 2
    assert "= -0.5 is not allowed: must be within the soft limits [-0.4, 0] m" in (
        capsys.readouterr().err
    )
    assert main(["stage", "move", "-0.2", "--speed", "0.02", *URL]) == 2
    assert "--speed (v (axis X)) = 0.02 is not allowed: must be in (0, 0.01] m/s" in (
        capsys.readouterr().err
    )


def test_reset_answers_with_the_banner_and_the_status(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["stage", "reset", "--json", *URL]) == 0
    doc = _json(capsys)
    assert doc["state"] == "Alarm" and "[MSG:'$H'|'$X' to unlock]" in doc["messages"]


def _experiment(tmp_path: Path, tow: str) -> Path:
    head, _, tail = DEFAULT_EXPERIMENT.partition("[tow]\n")
    rest = tail.split("\n\n", 1)[1]
    # Long enough for the slowest tow here (0.005 m/s over 0.21 m).
    head = head.replace('output_dir = "runs"\n', 'output_dir = "runs"\nmax_duration_s = 600.0\n')
    path = tmp_path / "exp.toml"
    path.write_text(head + "[tow]\n" + tow + "\n\n" + rest, encoding="utf-8")
    return path


def test_settings_are_listed_by_name_with_units(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["stage", "settings", *URL]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "$110  max_rate_x                600.000 mm/min" in out
    assert "$22   homing_enabled                  1" in out
    assert "soft limits of X: [-0.4, 0] m" in out
    assert "ok      report_inches ($13) = '0': must be 0 (reports in mm)" in out


def test_settings_check_an_experiment_that_fits(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tow = "start_m = -0.1\nend_m = -0.3\nspeed_mps = 0.005\nrepeats = 2\nrun_up_m = 0.01\n"
    tow += "run_down_m = 0.01"
    exp = _experiment(tmp_path, tow)
    assert main(["stage", "settings", "--json", "--check", str(exp), *URL]) == 0
    checks = _json(capsys)["checks"]
    assert [c["field"] for c in checks if c["required"]] == [
        "report_inches ($13)",
        "tow.start_m - tow.run_up_m",
        "tow.end_m + tow.run_down_m",
        "tow.speed_mps",
        "tow.run_up_m",
        "tow.run_down_m",
    ]
    assert all(c["ok"] for c in checks)


def test_settings_check_names_every_failure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The built-in experiment tows -2 m .. -5 m at 1.5 m/s: far beyond this machine.
    exp = _experiment(tmp_path, "start_m = -0.1\nend_m = -0.5\nspeed_mps = 0.02\nrun_up_m = 0.001")
    assert main(["stage", "settings", "--check", str(exp), *URL]) == 1
    fails = [line for line in capsys.readouterr().out.splitlines() if line.startswith("FAIL")]
    assert fails == [
        "FAIL    tow.end_m + tow.run_down_m = -1.0: must be within the stage's soft limits "
        "[-0.4, 0.0] m",
        "FAIL    tow.speed_mps = 0.02: must be <= the stage max rate 0.010 m/s ($110); lower "
        "the speed or raise $110",
        "FAIL    tow.run_up_m = 0.001: must be >= 0.004 m, the distance to reach 0.02 m/s at "
        "the acceleration $120 = 50 mm/s^2; lengthen it or raise $120",
    ]


def test_url_defaults(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    parser_args = ["stage", "settings"]
    from hil.cli.main import build_parser

    args = build_parser().parse_args(parser_args)
    assert stage_cli.resolve_url(args) == "sim://stage"
    exp = _experiment(tmp_path, "start_m = -0.1\nend_m = -0.3\nspeed_mps = 0.005\nrun_up_m = 0.01")
    exp.write_text(exp.read_text().replace('"sim://stage"', '"serial:///dev/ttyUSB0"'))
    args = build_parser().parse_args([*parser_args, "--check", str(exp)])
    assert stage_cli.resolve_url(args) == "serial:///dev/ttyUSB0"
    monkeypatch.setenv(stage_cli.URL_ENV, "/dev/ttyACM3")
    assert stage_cli.resolve_url(args) == "/dev/ttyACM3"
    args = build_parser().parse_args([*parser_args, "--url", "spy://loop://"])
    assert stage_cli.resolve_url(args) == "spy://loop://"


def test_every_action_documents_its_units_and_defaults(
    capsys: pytest.CaptureFixture[str],
) -> None:
    for action, words in (
        ("jog", ["distance, m", "speed, m/s (default 0.005"]),
        ("move", ["machine position, m", "acceleration, m/s^2 (default: the controller's"]),
        ("settings", ["--check EXPERIMENT"]),
        ("status", ["--url URL", "HIL_STAGE_URL", "sim://stage"]),
    ):
        with pytest.raises(SystemExit):
            main(["stage", action, "--help"])
        out = " ".join(capsys.readouterr().out.split())
        assert all(w in out for w in words), (action, out)


def test_a_missing_port_exits_1_naming_it(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["stage", "status", "--url", "serial:///dev/does-not-exist"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("hil stage status: serial:///dev/does-not-exist: cannot open")
    assert "dialout" in err


def test_a_hard_limit_hit_by_a_move_exits_1_saying_reset_then_home(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # Not homed: GRBL counts from where it powered up, 480 mm from the homing switch, so a
    # move to machine -60 mm (inside the travel the driver knows) runs into the far
    # switch. The same controller then serves the reset.
    import hil.transports.sim as sim_transport
    from sim_devices.stage import SimulatedGrbl

    config = GrblSimConfig(
        max_travel_mm=500.0, max_rate_mm_min=600.0, acceleration_mm_s2=50.0,
        homing=True, soft_limits=False, hard_limits=True, power_up_position_mm=-480.0,
    )  # fmt: skip
    grbl = SimulatedGrbl(config, clock=stage_cli.STAGE_OPTIONS["clock"])
    monkeypatch.setattr(
        sim_transport,
        "open_sim_stage",
        lambda query, options, timeout: sim_transport.MemoryStageLink(grbl, timeout=timeout),
    )
    assert main(["stage", "unlock", *URL]) == 0
    capsys.readouterr()
    assert main(["stage", "move", "-0.06", "--speed", "0.01", *URL]) == 1
    err = capsys.readouterr().err
    assert "stage is in ALARM:1 (Hard limit" in err
    assert "send a soft reset first (GrblStage.reset() or hil stage reset: 0x18)" in err
    assert "home with $H (GrblStage.home(), hil stage home)" in err
