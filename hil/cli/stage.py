"""``hil stage``: the GRBL motion stage at the bench.

Examples::

    hil stage status --url serial:///dev/ttyUSB0        # state, position, alarm, switches
    hil stage home                                      # $H (on HIL_STAGE_URL; needs $22=1)
    hil stage unlock                                    # $X
    hil stage jog -0.01 --speed 0.005                   # 10 mm towards -X at 5 mm/s
    hil stage move -0.2                                 # to machine X = -0.2 m
    hil stage settings --check experiment.toml          # the checks a tank run makes
    hil stage reset                                     # soft reset (after ALARM:1/2)

Positions are machine coordinates of the X axis in metres (GRBL's MPos: 0 at the homing
switch, negative inwards), speeds m/s, accelerations m/s^2. ``--url`` is any transport URL
(``serial:///dev/ttyUSB0?dtr=0``, a device path, ``spy://serial://...?file=log``);
without it, ``$HIL_STAGE_URL``, else the stage of ``--check``'s experiment, else
``sim://stage``: a simulated GRBL 1.1 started for the command with stock settings (homing
disabled, ``$22=0``: it powers up Idle, moves at once, and ``home`` is refused). With
``--check`` of an experiment on simulated devices (``sim://``, as the built-in one of
``hil tank-run --print-default``), ``sim://stage`` is the simulated tank's controller that
the run drives (a 10 m axis at 2.5 m/s, homing enabled). The serial port opens with DTR low,
so an Arduino GRBL is not reset. Exit status: 0 done, 1 the stage refused or failed (alarm,
timeout, a failed check), 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Callable
from typing import Any

from hil.devices.grbl_codes import alarm_text
from hil.devices.stage import StageState, StageStatus
from hil.devices.stage_errors import StageError
from hil.errors import TransportError, device_url

EXIT_OK = 0
EXIT_STAGE_FAILED = 1
DEFAULT_URL = "sim://stage"
URL_ENV = "HIL_STAGE_URL"
DEFAULT_SPEED_MPS = 0.005
#: More :class:`~hil.devices.grbl.GrblStage` keywords for every command: the seam through
#: which tests run the commands on an injected clock (``clock=``, ``transport_options=``).
STAGE_OPTIONS: dict[str, Any] = {}

# Internal field names -> the options that set them (hil.cli.main names them in errors).
OPTION_NAMES = {
    "v (axis X)": "--speed",
    "a (axis X)": "--accel",
    "x (axis X)": "X",
    "jog target x (axis X)": "DX",
    "response_timeout": "--timeout",
}


def register(sub: Any) -> None:
    """Add the ``stage`` sub-command and its actions."""
    p: argparse.ArgumentParser = sub.add_parser(
        "stage",
        help="GRBL stage at the bench: status, home, unlock, jog, move, settings, reset",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = p.add_subparsers(dest="action", metavar="ACTION")
    actions.required = True
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--url",
        default=None,
        help=f"stage URL (default: ${URL_ENV}, else the --check experiment's stage, else "
        f"{DEFAULT_URL}, a simulated GRBL)",
    )
    common.add_argument(
        "--timeout",
        type=float,
        default=10.0,
        help="seconds to wait for GRBL to answer a line (default 10; homing and moves wait "
        "as long as they need)",
    )
    common.add_argument("--json", action="store_true", help="print the result as JSON")

    def action(name: str, help_text: str, func: Callable[..., Any]) -> argparse.ArgumentParser:
        a: argparse.ArgumentParser = actions.add_parser(
            name, help=help_text, description=help_text, parents=[common]
        )
        a.set_defaults(func=run, do=func, check=None)
        return a

    action("status", "print the state, position, alarm and limit switches", _status)
    action(
        "home",
        "run the homing cycle $H (needs $22=1; Z, then X and Y on stock GRBL): clears an "
        "alarm and sets the machine origin at the switch",
        _home,
    )
    action(
        "unlock",
        "kill the alarm lock with $X (the position may be wrong: home when you can)",
        _unlock,
    )
    action(
        "reset",
        "soft reset (0x18), needed after a hard or soft limit alarm (ALARM:1/2); resent "
        "until GRBL's banner comes",
        _reset,
    )
    jog = action("jog", "jog X by DX with $J= and wait until it stops", _jog)
    jog.add_argument("dx", type=float, help="distance, m (negative: towards -X)")
    jog.add_argument(
        "--speed", type=float, default=DEFAULT_SPEED_MPS,
        help=f"speed, m/s (default {DEFAULT_SPEED_MPS}; at most the max rate $110)",
    )  # fmt: skip
    move = action("move", "move X to a machine position and wait until it arrives", _move)
    move.add_argument("x", type=float, help="target machine position, m (0 at the home switch)")
    move.add_argument(
        "--speed", type=float, default=DEFAULT_SPEED_MPS,
        help=f"speed, m/s (default {DEFAULT_SPEED_MPS}; at most the max rate $110)",
    )  # fmt: skip
    move.add_argument(
        "--accel", type=float, default=None,
        help="acceleration, m/s^2 (default: the controller's $120; restored on exit)",
    )  # fmt: skip
    settings = action(
        "settings",
        "print the controller's $ settings by name with units; with --check, the checks a "
        "tank run makes of them and of the experiment's tow",
        _settings,
    )
    settings.add_argument(
        "--check", default=None, metavar="EXPERIMENT",
        help="experiment TOML file whose [tow] is checked against the stage",
    )  # fmt: skip


def resolve_url(args: argparse.Namespace) -> str:
    """``--url``, else ``$HIL_STAGE_URL``, else the checked experiment's stage, else the
    simulated stage. An empty URL (either) is refused: it names no stage."""
    from hil.errors import ConfigError

    for source, url in (("--url", args.url), (URL_ENV, os.environ.get(URL_ENV))):
        if url is None:
            continue
        if not str(url).strip():
            raise ConfigError(
                source,
                str(url),
                "a stage URL such as sim://stage, /dev/ttyUSB0 or serial:///dev/ttyACM0",
                f"give the stage's URL, or leave {source} out for {DEFAULT_URL}"
                if source == "--url"
                else f"set it to the stage's URL, or unset it for {DEFAULT_URL}",
            )
        return str(url)
    if args.check:
        from pathlib import Path

        from hil.experiments.experiment import load_experiment

        return load_experiment(Path(args.check)).stage_url
    return DEFAULT_URL


def checked_tank_stage(args: argparse.Namespace, url: str) -> bool:
    """Whether ``url`` is the simulated stage of the simulated experiment given to
    ``--check``: then it is the simulated tank's controller, the one ``hil tank-run``
    drives (the stock simulated GRBL would fail every check of the tow)."""
    if not args.check or not url.startswith(DEFAULT_URL):
        return False
    from pathlib import Path

    from hil.experiments.experiment import load_experiment

    exp = load_experiment(Path(args.check))
    return exp.simulated and exp.stage_url == url


def run(args: argparse.Namespace) -> int:
    """Open the stage, run the action, close; 1 if the stage refused or failed."""
    from hil.devices.table import open_stage

    url = resolve_url(args)
    options = dict(STAGE_OPTIONS)
    options.setdefault("response_timeout", args.timeout)
    if checked_tank_stage(args, url):
        from hil.experiments.sim_tank import tank_stage_config

        transport = dict(options.get("transport_options") or {})
        transport.setdefault("config", tank_stage_config())
        options["transport_options"] = transport
    name = f"hil stage {args.action}"
    try:
        with open_stage(url, field="--url", **options) as stage:
            opened = len(stage.messages)
            result: StageStatus | int = args.do(stage, args)
            if isinstance(result, int):
                return result
            # status: what GRBL said since the port opened; the others: during the action.
            messages = stage.messages[0 if args.action == "status" else opened :]
            _print_status(stage, result, args, messages)
            return EXIT_OK
    except (StageError, TransportError) as exc:
        print(f"{name}: {device_url(exc, url)}", file=sys.stderr)  # the URL once
        return EXIT_STAGE_FAILED


def _progress(text: str) -> None:
    print(f"stage: {text}", file=sys.stderr, flush=True)


def status_fields(status: StageStatus) -> dict[str, Any]:
    """A status as plain values for JSON (positions m, speeds m/s)."""
    return {
        "state": status.state.value,
        "substate": status.substate,
        "position_m": None if math.isnan(status.position) else status.position,
        "velocity_mps": status.velocity,
        "alarm": status.alarm,
        "alarm_text": None if status.alarm is None else alarm_text(status.alarm),
        "limit_triggered": status.limit_triggered,
        "planner_blocks_free": status.planner_blocks_free,
        "rx_bytes_free": status.rx_bytes_free,
    }


def _print_status(
    stage: Any, status: StageStatus, args: argparse.Namespace, messages: list[str]
) -> None:
    if args.json:
        print(json.dumps({**status_fields(status), "messages": messages}))
        return
    state = status.state.value + (f":{status.substate}" if status.substate is not None else "")
    print(f"state      {state}")
    print(f"position   {status.position:.6f} m ({1000 * status.position:.3f} mm, machine X)")
    print(f"velocity   {status.velocity:.6f} m/s")
    if status.alarm is not None:
        alarm = f"ALARM:{status.alarm} {alarm_text(status.alarm)}"
    elif status.state is StageState.ALARM:
        alarm = "locked at power-up or reset: 'hil stage home' (or 'hil stage unlock')"
    else:
        alarm = "none"
    print(f"alarm      {alarm}")
    print(f"X switch   {'pressed' if status.limit_triggered else 'clear'}")
    if status.planner_blocks_free is not None:
        print(
            f"buffers    {status.planner_blocks_free} planner blocks, "
            f"{status.rx_bytes_free} rx bytes free"
        )
    if stage.critical:
        print("note       GRBL is locked by a critical alarm: run 'hil stage reset' first")
    for message in messages:
        print(f"message    {message}")


def _status(stage: Any, args: argparse.Namespace) -> StageStatus:
    status: StageStatus = stage.status()
    return status


def _home(stage: Any, args: argparse.Namespace) -> StageStatus:
    stage.check_home()  # refused before the progress line says it homes
    _progress(f"homing ($H, up to {stage.homing_timeout():.0f} s)")
    status: StageStatus = stage.home()
    return status


def _unlock(stage: Any, args: argparse.Namespace) -> StageStatus:
    status: StageStatus = stage.unlock()
    return status


def _reset(stage: Any, args: argparse.Namespace) -> StageStatus:
    status: StageStatus = stage.reset()
    return status


def _jog(stage: Any, args: argparse.Namespace) -> StageStatus:
    stage.check_jog(args.dx, args.speed)  # refused before the progress line
    _progress(f"jogging {1000 * args.dx:+.3f} mm at {1000 * args.speed:g} mm/s")
    status: StageStatus = stage.jog(args.dx, args.speed)
    return status


def _move(stage: Any, args: argparse.Namespace) -> StageStatus:
    stage.check_move(args.x, args.speed, args.accel)  # refused before the progress line
    _progress(f"moving to {1000 * args.x:.3f} mm at {1000 * args.speed:g} mm/s")
    status: StageStatus = stage.move_to(args.x, args.speed, args.accel)
    return status


def settings_rows(settings: Any) -> list[tuple[int, str, str, str]]:
    """``($ number, name, value as sent, unit)`` for every setting in the dump, by number;
    the ones this package has no name for are listed as ``$<n>``."""
    from hil.devices.grbl_settings import GrblSetting, GrblSettings

    named = {d.number: d for d in vars(GrblSettings).values() if isinstance(d, GrblSetting)}
    rows = []
    for number in sorted(settings.raw):
        desc = named.get(number)
        name, unit = (desc.name, desc.unit) if desc is not None else (f"${number}", "")
        rows.append((number, name, settings.raw[number], unit))
    return rows


def _settings(stage: Any, args: argparse.Namespace) -> int:
    from hil.experiments.stage_checks import settings_checks, tow_checks

    settings = stage.settings
    checks = settings_checks(settings)
    if args.check:
        from pathlib import Path

        from hil.experiments.experiment import load_experiment

        exp = load_experiment(Path(args.check))
        checks += tow_checks(exp.tow, settings, stage.limits)
    failed = [c for c in checks if c.required and not c.ok]
    if args.json:
        doc = {
            "settings": {name: value for _, name, value, _ in settings_rows(settings)},
            "checks": [
                {"field": c.field, "value": c.value, "allowed": c.allowed, "ok": c.ok,
                 "required": c.required}
                for c in checks
            ],
        }  # fmt: skip
        print(json.dumps(doc))
    else:
        for number, name, value, unit in settings_rows(settings):
            print(f"${number:<4} {name:<20} {value:>12} {unit}".rstrip())
        print(f"soft limits of X: [{stage.limits[0]:g}, {stage.limits[1]:g}] m")
        print(f"homing timeout:   {stage.homing_timeout():.1f} s")
        for check in checks:
            print(check.line())
    return EXIT_STAGE_FAILED if failed else EXIT_OK
