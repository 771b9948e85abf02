"""The ``hil`` command: one entry point, one sub-command per job.

Every sub-command module exposes ``register(subparsers)`` which adds its parser and sets
``func`` to a callable taking the parsed namespace and returning an exit status. Invalid input
(a :class:`~hil.errors.ConfigError`, a missing file) prints one line to stderr (one per
problem for a :class:`~hil.errors.ConfigErrors`) and exits with
status 2, never a traceback; argparse's own usage errors exit with 2 as well. A failure to
read or write while working (a full disk) prints one line and exits with status 1.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import sys
from collections.abc import Sequence
from typing import Any

from hil import __version__
from hil.errors import ConfigError, ConfigErrors

EXIT_OK = 0
EXIT_IO = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

#: Errors of a path as given (missing, a folder for a file, no permission, a symlink loop,
#: too long): the input is wrong, exit status 2.
_BAD_PATH_ERRNOS = frozenset(
    {
        errno.ENOENT,
        errno.EISDIR,
        errno.ENOTDIR,
        errno.EACCES,
        errno.EPERM,
        errno.ELOOP,
        errno.ENAMETOOLONG,
        errno.EROFS,
    }
)

COMMANDS: dict[str, tuple[str, str]] = {
    "tank-run": (
        "hil.cli.tank_run",
        "run a towed-target tank experiment (built-in simulated tank without a file)",
    ),
    "waveform": (
        "hil.cli.waveform",
        "synthesise a transmit waveform (WAV + schedule JSON + diagnostics)",
    ),
    "estimate": ("hil.cli.estimate", "estimate range and speed from a received WAV"),
    "simulate": (
        "hil.cli.simulate",
        "simulate the received signal of a scenario (WAV + schedule + truth + plots)",
    ),
    "sweep": ("hil.cli.sweep", "run a Monte Carlo sweep (grid x repetitions) and summarise it"),
    "reproduce": (
        "hil.cli.reproduce",
        "run the seed's chapter-6 evaluation and write figures, tables and report.md",
    ),
    "replay": ("hil.cli.replay", "re-run a receiver over a run recording"),
    "report": (
        "hil.cli.report",
        "rebuild a tank run's summary and figures from its recording",
    ),
    "calibrate": (
        "hil.cli.calibrate",
        "calibrate latency, response, level, sound speed or the stage",
    ),
    "stage": (
        "hil.cli.stage",
        "GRBL stage at the bench: status, home, unlock, jog, move, settings, reset",
    ),
    "sim-serve": ("hil.cli.sim_serve", "serve a simulated board or stage on a pty"),
    "devices": ("hil.cli.devices", "list serial ports, USB devices, PortAudio and JACK devices"),
    "watch": (
        "hil.cli.watch",
        "live view of a run recording in the browser (range, speed, alarms)",
    ),
    "docs": ("hil.cli.docs", "print the installed documentation (hil docs lists the topics)"),
    "schema": ("hil.cli.schema", "print the JSON Schema of a config file (for editor completion)"),
}
"""Sub-command name -> (module with ``register``, one-line summary for ``hil --help``).

A command's module is imported only when that command runs (or its ``--help`` is asked
for), so ``hil --help`` and every command start without the others' imports (SciPy,
Matplotlib, h5py, numba). The summary must equal the ``help=`` the module registers
(checked by tests/cli/test_cli_start.py).
"""

_VALUE_OPTIONS = ("--log-level", "--log-file")


class HelpFormatter(argparse.HelpFormatter):
    """Help with every default shown and hand-laid-out descriptions kept.

    An option's default is appended as ``(default: X)`` unless its help already says it (or
    it has none: a flag, a required option, an empty list). A description holding line
    breaks is printed as written; a one-line one is wrapped.
    """

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (
            "default" in text
            or action.required
            or any(default is none for none in (None, False, True, argparse.SUPPRESS))
            or (isinstance(default, list | tuple) and not default)
            or not action.option_strings
        ):
            return text
        return f"{text} (default: %(default)s)"


class HilParser(argparse.ArgumentParser):
    """The parser class of every ``hil`` command and sub-command (:class:`HelpFormatter`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)


def _command_name(argv: Sequence[str]) -> str | None:
    """The sub-command named in ``argv`` (first word that is not a top-level option).

    >>> _command_name(["--log-level", "debug", "simulate", "att"])
    'simulate'
    >>> _command_name(["--help"]) is None
    True
    """
    words = iter(argv)
    for word in words:
        if word in _VALUE_OPTIONS:
            next(words, None)
        elif not word.startswith("-"):
            return word
    return None


def build_parser(load: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The top-level parser; ``load``: the sub-commands registered in full (None: all).

    The others get a placeholder parser carrying only their summary, enough for
    ``hil --help`` and for argparse's "invalid choice" message.
    """
    from hil.logs import LEVELS

    parser = HilParser(
        prog="hil",
        description="Continuous active sonar (HFC-CW / GCAS) hardware-in-the-loop testbench. "
        "'hil COMMAND --help' describes a command, its options, defaults and units.",
        epilog="Environment: HIL_CALIBRATION_DIR (calibration store, default ./calibration), "
        "HIL_RUNS_DIR (where tank runs and simulations go without --out, default ./runs; "
        "sweep and reproduce, which --resume, require --out). Documentation: "
        "'hil docs' lists the installed documents, 'hil docs TOPIC' prints one.",
    )
    parser.add_argument("--version", action="version", version=f"hil {__version__}")
    parser.add_argument(
        "--log-level",
        type=str.lower,
        choices=LEVELS,
        default="warning",
        help="messages shown on stderr and written to --log-file (default: warning)",
    )
    parser.add_argument(
        "--log-file", metavar="FILE", help="also append every log message at --log-level here"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (module_name, summary) in COMMANDS.items():
        if load is None or name in load:
            importlib.import_module(module_name).register(sub)
        else:
            sub.add_parser(name, help=summary, add_help=False)
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


#: Commands that SIGTERM and SIGHUP stop as Ctrl-C does from their first instruction (a run
#: that must end with its stop recorded, a sweep that saves where it stands). The others keep
#: the signals' default action, which also ends a process stuck inside a C library.
STOPPED_SAFELY = frozenset({"tank-run", "sweep"})


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``hil`` command; return the exit status. For :data:`STOPPED_SAFELY`
    commands SIGTERM and SIGHUP stop it as Ctrl-C does from its first instruction
    (:mod:`hil.interrupts`)."""
    from hil.interrupts import interruption, raise_on_stop_signals

    words = sys.argv[1:] if argv is None else list(argv)
    restore = raise_on_stop_signals() if _command_name(words) in STOPPED_SAFELY else (lambda: None)
    try:
        return _main(argv)
    except KeyboardInterrupt as exc:  # before the command started (parsing, its imports)
        print(f"hil: interrupted ({interruption(exc)})", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        restore()


def _main(argv: Sequence[str] | None) -> int:
    words = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(load=[name] if (name := _command_name(words)) in COMMANDS else [])
    args = parser.parse_args(words)
    from hil.logs import configure_logging, reset_logging

    try:
        if args.log_file is not None:
            from pathlib import Path

            from hil.outputs import writable_file

            writable_file(Path(args.log_file), "--log-file", make_folder=False)
        configure_logging(args.log_level, args.log_file)
        status: int = args.func(args)
    except ConfigError as exc:
        # Every problem of an input at once (a config file's), one line each.
        for one in exc.errors if isinstance(exc, ConfigErrors) else (exc,):
            print(f"hil {args.command}: error: {_name_option(args, one)}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:
        # Output piped into a command that stopped reading (e.g. `| head`): not an error.
        import os

        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    except OSError as exc:
        # A path the user gave that cannot be used is bad input (2); any other failure to
        # read or write while working (a full disk, a device gone) is an I/O failure (1).
        bad_input = exc.errno in _BAD_PATH_ERRNOS
        what = exc.strerror or str(exc)
        where = f": {exc.filename}" if exc.filename is not None else ""
        print(f"hil {args.command}: error: {what}{where}", file=sys.stderr)
        return EXIT_USAGE if bad_input else EXIT_IO
    except KeyboardInterrupt as exc:
        from hil.interrupts import interruption

        print(f"hil {args.command}: interrupted ({interruption(exc)})", file=sys.stderr)
        return EXIT_INTERRUPTED
    except SystemError as exc:
        # Ctrl-C or a stop signal raised while a compiled kernel ran comes out of that call
        # as its SystemError, caused by the interruption: an interruption all the same.
        from hil.interrupts import interruption, interruption_behind

        stopped = interruption_behind(exc)
        if stopped is None:
            raise
        print(f"hil {args.command}: interrupted ({interruption(stopped)})", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        reset_logging()
    return status


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
