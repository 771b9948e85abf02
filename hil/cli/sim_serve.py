"""``hil sim-serve board|stage|tank``: expose a simulated device for other programs.

Prints the pty path on the first line of stdout (open it like a serial port), then serves in
real time until Ctrl-C (or SIGTERM); ``tank --jack`` prints the experiment file of a run
instead (:mod:`hil.experiments.jack_tank`). The board is a loopback cable (``--delay`` samples,
``--gain``; the DAC monitor input tapped too) behind the Python simulated board, or with
``--impl c`` behind the C reference firmware of ``firmware_protocol/c`` (built with ``cc``
and ``make`` if needed); the stage is
the simulated GRBL 1.1h controller with stock settings, or the simulated tank's with
``--tank`` (``docs/simulated-grbl.md``).
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hil.errors import ConfigError

#: JACK frames per period of ``sim-serve tank --jack`` (hil.experiments.jack_tank's default).
DEFAULT_PERIOD = 1024

DESCRIPTION = """\
Serve a simulated device on a pseudo-terminal (pty) for other programs. The pty path is
printed alone on the first line of stdout; open it like a serial port (115200 baud). Serves
in real time until Ctrl-C or SIGTERM.

  board  the transducer board (firmware_protocol/SPEC.md) wired as a loopback cable:
         DAC out -> ADC in 1 after --delay samples, times --gain, and -> ADC in 2 (the
         DAC monitor a tank run measures its loopback latency on) after the same delay
  stage  the simulated GRBL 1.1 controller (homing, jogging, status reports): stock
         settings (a 200 mm axis at 500 mm/min), or with --tank the built-in simulated
         tank's (a 10 m axis at 2.5 m/s, homing on, powered up in alarm)

Point a tank run at them: start both, each in its own terminal,

  $ hil sim-serve board --delay 64      # prints e.g. /dev/pts/5
  $ hil sim-serve stage --tank          # prints e.g. /dev/pts/6

then write the built-in experiment to a file, put the printed paths in it, give it a
receiver that needs no empty-tank capture, and run it:

  $ hil tank-run --print-default > my-experiment.toml

  [devices]
  board = "/dev/pts/5"
  stage = "/dev/pts/6"

  [receiver]
  name = "gcas-mti"      # in place of gcas-bg and its options line

  $ hil tank-run my-experiment.toml --out runs/served

The run treats them as real devices: no simulated tank (the ADC hears the loopback, not an
echo: expect no detection), and the rules of real runs apply (calibrations measured on the
simulated bench are refused, and so is the built-in receiver's simulated empty-tank
background: a real tank's is captured, hil docs tank-run). For a run with the simulated
tank in between, use devices sim://board and sim://stage (the default of 'hil tank-run').

  tank   with --jack: the whole simulated tank behind a real audio stack. Starts a JACK
         server on the dummy driver at the waveform's rate (named by JACK_DEFAULT_SERVER,
         else 'default'), the tank's GRBL controller on a pty, and the tank as a JACK client
         (transmitter in, hydrophone and DAC monitor out), wired to each run that opens its
         stream; prints the path of the experiment file to run (board = audio://JACK?...,
         stage = the pty). The server runs in real time and synchronously: a late tank
         slows the stream instead of losing samples:

  $ hil sim-serve tank --jack                 # prints e.g. /tmp/hil-jack-tank-x1/experiment.toml
  $ hil tank-run /tmp/hil-jack-tank-x1/experiment.toml --out runs/jack
  $ hil report runs/jack/run.h5 --exact-truth /tmp/hil-jack-tank-x1/truth-run-1.csv

The run captures through PortAudio's JACK host API, as with a USB audio interface; its
summary counts the xruns (dac_underruns, adc_overruns) and scores it against the stage
telemetry. The tank writes each run's exact truth beside the experiment file when the run
ends (truth-run-N.csv: range and closing speed against the run's time); hil report scores
the run against it too (range_rmse_vs_exact_m), telling the telemetry's error from the
receiver's."""


def register(subparsers: Any) -> None:
    """Add the ``sim-serve`` sub-command."""
    parser = subparsers.add_parser(
        "sim-serve",
        help="serve a simulated board or stage on a pty",
        description=DESCRIPTION,
    )
    parser.add_argument("device", choices=("board", "stage", "tank"), help="what to simulate")
    parser.add_argument(
        "--delay", type=int, default=0, help="board loopback delay, samples (default 0)"
    )
    parser.add_argument(
        "--gain", type=float, default=1.0, help="board loopback gain, linear (default 1)"
    )
    parser.add_argument(
        "--tank",
        action="store_true",
        help="stage: the simulated tank's controller settings instead of stock GRBL's",
    )
    parser.add_argument(
        "--impl",
        choices=("python", "c"),
        default="python",
        help="board implementation: the Python simulation (default) or the C reference firmware",
    )
    parser.add_argument(
        "--jack",
        action="store_true",
        help="tank: serve it as a client of a JACK server this command starts (required)",
    )
    parser.add_argument(
        "--experiment",
        type=Path,
        default=None,
        help="tank: the experiment whose tank, waveform and tow to serve (default built-in)",
    )
    parser.add_argument(
        "--period",
        type=int,
        default=DEFAULT_PERIOD,
        help=f"tank: JACK frames per period, the run's block size (default {DEFAULT_PERIOD})",
    )
    parser.add_argument(
        "--write",
        type=Path,
        default=None,
        help="tank: where to write the run's experiment file (default: a new temporary folder)",
    )
    parser.set_defaults(func=run)


def _serve(port_name: str, stop: threading.Event, check: Callable[[], None] | None = None) -> None:
    """Print ``port_name`` and serve until stopped; ``check()`` raises when the served
    device failed (called every 0.2 s)."""
    print(port_name, flush=True)
    main_thread = threading.current_thread() is threading.main_thread()
    # Signal handlers can only be installed from the main thread (tests serve from others).
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set()) if main_thread else None
    try:
        while not stop.wait(0.2):
            if check is not None:
                check()
    except KeyboardInterrupt:
        pass
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)


#: The options each device reads (argparse's destinations) and their defaults: an option
#: of another device given a value of its own is refused, not ignored.
_DEVICE_OPTIONS: dict[str, dict[str, object]] = {
    "board": {"delay": 0, "gain": 1.0, "impl": "python"},
    "stage": {"tank": False},
    "tank": {"jack": False, "experiment": None, "period": DEFAULT_PERIOD, "write": None},
}


def _check_device_options(args: argparse.Namespace) -> None:
    """Refuse an option given for another device than ``args.device``."""
    for owner, options in _DEVICE_OPTIONS.items():
        if owner == args.device:
            continue
        for dest, default in options.items():
            value = getattr(args, dest)
            if value != default:
                raise ConfigError(
                    f"--{dest}",
                    str(value) if isinstance(value, Path) else value,
                    f"an option of sim-serve {owner}",
                    f"sim-serve {args.device} does not read it: drop it",
                )


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    """Serve until Ctrl-C / SIGTERM (or ``stop`` is set, for tests); exit status 0."""
    stop = stop or threading.Event()
    _check_device_options(args)
    if args.device == "board" and not math.isfinite(args.gain):
        raise ConfigError("--gain", args.gain, "a finite number (linear)", "e.g. --gain 0.5")
    if args.device == "tank":
        return _serve_tank(args, stop)
    if args.device == "board" and args.impl == "c":
        from sim_devices.board.c_firmware import CFirmwareOnPty, CFirmwareUnavailable

        if not 0 <= args.delay <= 4096:
            raise ConfigError("--delay", args.delay, "0 .. 4096 samples with --impl c")
        try:
            firmware = CFirmwareOnPty(delay_samples=args.delay, gain=args.gain)
        except CFirmwareUnavailable as error:
            raise ConfigError("--impl", "c", "a C firmware that builds here", str(error)) from None
        with firmware:
            _serve(firmware.port_name, stop)
    elif args.device == "board":
        from sim_devices.board import LoopbackWorld, SimulatedBoardOnPty

        if args.delay < 0:
            raise ConfigError("--delay", args.delay, ">= 0 samples")
        world = LoopbackWorld(args.delay, args.gain, monitor=True)
        with SimulatedBoardOnPty(world=world) as board:
            _serve(board.port_name, stop)
    else:
        from sim_devices.stage import SimulatedGrblOnPty

        config = None
        if args.tank:
            from hil.experiments.sim_tank import tank_stage_config

            config = tank_stage_config()
        with SimulatedGrblOnPty(config) as stage:
            _serve(stage.port_name, stop)
    print(f"hil sim-serve {args.device}: stopped", file=sys.stderr)
    return 0


def _serve_tank(args: argparse.Namespace, stop: threading.Event) -> int:
    from hil.experiments.experiment import DEFAULT_EXPERIMENT, load_experiment, parse_experiment
    from hil.experiments.jack_tank import JackTankServer

    if not args.jack:
        raise ConfigError(
            "sim-serve tank", "without --jack", "--jack", "the tank is served on JACK only"
        )
    if args.experiment is not None:
        exp = load_experiment(args.experiment)
    else:
        exp = parse_experiment(DEFAULT_EXPERIMENT, "<built-in>")
    path = args.write or Path(tempfile.mkdtemp(prefix="hil-jack-tank-")) / "experiment.toml"
    with JackTankServer(exp, args.period) as served:
        served.write(path)
        assert served.server is not None and served.tank is not None
        print(
            f"hil sim-serve tank: JACK server {served.server.name!r}, stage {served.stage_port}; "
            f"each run's exact truth: {path.parent / 'truth-run-N.csv'} (hil report RUN.h5 "
            "--exact-truth FILE)",
            file=sys.stderr,
        )
        _serve(str(path), stop, served.tank.check)
        tank = served.tank
    for truth in tank.truth_files:
        print(f"hil sim-serve tank: exact truth written: {truth}", file=sys.stderr)
    print(
        f"hil sim-serve tank: {tank.runs_started} run(s) served, {tank.xruns} xrun(s) "
        f"reported to the tank, blocks the world rendered late: {tank.late_blocks} waited "
        f"for, {tank.lost_blocks} lost",
        file=sys.stderr,
    )
    return 0
