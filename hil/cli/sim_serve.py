"""``hil sim-serve board|stage``: expose a simulated device on a pty for other programs.

Prints the pty path on the first line of stdout (open it like a serial port), then serves in
real time until Ctrl-C (or SIGTERM). The board is a loopback cable (``--delay`` samples,
``--gain``; the DAC monitor input tapped too) behind the Python simulated board, or with
``--impl c`` behind the C reference firmware of ``firmware_protocol/c`` (built with ``cc``
and ``make`` if needed); the stage is
the simulated GRBL 1.1h controller with stock settings, or the simulated tank's with
``--tank`` (``docs/simulated-grbl.md``).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Any

from hil.errors import ConfigError

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

then write the built-in experiment to a file, put the printed paths in it and run it:

  $ hil tank-run --print-default > my-experiment.toml

  [devices]
  board = "/dev/pts/5"
  stage = "/dev/pts/6"

  $ hil tank-run my-experiment.toml --out runs/served

The run treats them as real devices: no simulated tank (the ADC hears the loopback, not an
echo: expect no detection), and the rules of real runs apply (calibrations measured on the
simulated bench are refused). For a run with the simulated tank in between, use devices
sim://board and sim://stage (the default of 'hil tank-run')."""


def register(subparsers: Any) -> None:
    """Add the ``sim-serve`` sub-command."""
    parser = subparsers.add_parser(
        "sim-serve",
        help="serve a simulated board or stage on a pty",
        description=DESCRIPTION,
    )
    parser.add_argument("device", choices=("board", "stage"), help="what to simulate")
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
    parser.set_defaults(func=run)


def _serve(port_name: str, stop: threading.Event) -> None:
    print(port_name, flush=True)
    main_thread = threading.current_thread() is threading.main_thread()
    # Signal handlers can only be installed from the main thread (tests serve from others).
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set()) if main_thread else None
    try:
        while not stop.wait(0.2):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    """Serve until Ctrl-C / SIGTERM (or ``stop`` is set, for tests); exit status 0."""
    stop = stop or threading.Event()
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
