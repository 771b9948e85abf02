"""The ``hil`` command: one entry point, one sub-command per job.

Every sub-command module exposes ``register(subparsers)`` which adds its parser and sets
``func`` to a callable taking the parsed namespace and returning an exit status. Invalid input
(a :class:`~hil.errors.ConfigError`, a missing file) prints one line to stderr and exits with
status 2, never a traceback; argparse's own usage errors exit with 2 as well.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from hil import __version__
from hil.cli import (
    calibrate,
    estimate,
    replay,
    report,
    reproduce,
    sim_serve,
    simulate,
    sweep,
    tank_run,
    waveform,
)
from hil.errors import ConfigError

EXIT_OK = 0
EXIT_USAGE = 2

_COMMANDS = (
    tank_run,
    waveform,
    estimate,
    simulate,
    sweep,
    reproduce,
    replay,
    report,
    calibrate,
    sim_serve,
)


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every sub-command registered."""
    parser = argparse.ArgumentParser(
        prog="hil",
        description="Continuous active sonar (HFC-CW / GCAS) hardware-in-the-loop testbench.",
    )
    parser.add_argument("--version", action="version", version=f"hil {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module in _COMMANDS:
        module.register(sub)
    return parser


def _name_option(args: argparse.Namespace, exc: ConfigError) -> ConfigError:
    """Name the command-line option in an error raised deep inside (``m_hops`` -> ``--M``).

    A command module may declare ``OPTION_NAMES``: internal field name -> option.
    """
    module = sys.modules.get(getattr(args.func, "__module__", ""), None)
    names: dict[str, str] = getattr(module, "OPTION_NAMES", {})
    option = names.get(exc.field)
    if option is None or exc.field.startswith("-"):
        return exc
    return ConfigError(f"{option} ({exc.field})", exc.value, exc.allowed, exc.hint)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``hil`` command; return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        status: int = args.func(args)
    except ConfigError as exc:
        print(f"hil {args.command}: error: {_name_option(args, exc)}", file=sys.stderr)
        return EXIT_USAGE
    except (FileNotFoundError, IsADirectoryError, PermissionError, NotADirectoryError) as exc:
        print(f"hil {args.command}: error: {exc.strerror}: {exc.filename}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:
        # Output piped into a command that stopped reading (e.g. `| head`): not an error.
        import os

        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    except KeyboardInterrupt:
        print(f"hil {args.command}: interrupted", file=sys.stderr)
        return 130
    return status


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
