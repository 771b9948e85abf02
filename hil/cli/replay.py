"""``hil replay``: re-run a receiver over a run recording and print its estimates.

Example::

    hil replay run.h5                          # the live receiver, live settings
    hil replay run.h5 --receiver stft --json   # another receiver
    hil replay run.h5 --option m_hops=12 --csv est.csv

Output as ``hil estimate``: one JSON object per line (``--json``) or CSV (``--csv FILE``,
``-`` for stdout), else a summary line. With no ``--receiver`` (the live receiver) it also
says whether the replayed estimates equal the recorded live ones (on stderr when the
estimates go to stdout); exit status 1 when they differ. A recording whose writer was killed
holds the live estimates up to its last flush: equal as far as they go is not a difference.
Each estimate carries its ``track_id`` as live; a recording made before track ids were kept
(all −1) is compared without them. An echo seen beyond the Doppler span is said once per
side after the estimates, and what the receiver refused instead of reporting in a
``refused: …`` line, as ``hil estimate`` says them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from hil.cli.estimate import (
    COMMON_OPTIONS,
    _parse_option,
    _Sink,
    check_option_kinds,
    check_outputs,
)

# The numeric modules (numpy, numba, h5py through hil.recording) are imported where the
# command runs, so that building the parser for ``hil replay --help`` stays cheap.

# Internal field names -> the options that set them (hil.cli.main names them in errors).
OPTION_NAMES = {
    "receiver": "--receiver",
    "channel": "--channel",
    "recording": "RUN",
}

EXIT_DIFFERS = 1


def register(sub: Any) -> None:
    """Add the ``replay`` sub-command."""
    from hil.estimation.registry import RECEIVERS

    p: argparse.ArgumentParser = sub.add_parser(
        "replay",
        help="re-run a receiver over a run recording",
        description="Run a receiver over the samples of a run recording (HDF5) through the "
        "live path, gaps included, and print its estimates. Default: the receiver and "
        "settings used live, checked against the recorded live estimates.",
    )
    p.add_argument("run", type=Path, metavar="RUN", help="run recording (.h5)")
    p.add_argument(
        "--receiver",
        help=f"one of {', '.join(RECEIVERS)} (default: the receiver used live)",
    )
    p.add_argument("--channel", type=int, help="sample channel (default: the live one)")
    p.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="receiver setting overriding the recorded one (repeatable), e.g. --option m_hops=12",
    )
    out = p.add_mutually_exclusive_group()
    out.add_argument("--json", action="store_true", help="print one JSON object per estimate")
    out.add_argument(
        "--csv", type=Path, metavar="FILE", help="write estimates as CSV ('-': stdout)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``hil replay``; return the exit status."""
    from hil.estimation.base import refusal_text
    from hil.estimation.registry import check_receiver_options
    from hil.estimation.track_summary import track_figures, track_lines
    from hil.recording import RunRecording, compare_estimates, replay
    from hil.recording.reader import probe_structure

    check_outputs(args)
    overrides = dict(_parse_option(o) for o in args.option)
    if "sound_speed_mps" in overrides:
        _check_sound_speed(overrides["sound_speed_mps"])
    probe_structure(args.run)
    with RunRecording.open(args.run) as rec:
        live = rec.metadata.receiver
        name = args.receiver or (live.name if live is not None else None)
        if name is not None:
            # Named for the receiver replayed, with all its options (a staged GCAS's stage's
            # too); the common settings are every receiver's.
            own = {k: v for k, v in overrides.items() if k not in COMMON_OPTIONS}
            check_receiver_options(name, own)
        if live is not None and args.receiver in (None, live.name):
            check_option_kinds(overrides, dict(live.settings))
        notices: list[Any] = []
        refusals: dict[str, int] = {}
        estimates = replay(
            rec, args.receiver, channel=args.channel, notices=notices, refusals=refusals,
            **overrides,
        )  # fmt: skip
        recorded = rec.estimates(live.name) if live is not None else []
        track_ids = rec.has_track_ids
    sink = _Sink(args)
    try:
        sink.emit(estimates)
        sink.notices(notices)
    finally:
        sink.close()
    to_stdout = not args.json and args.csv is None
    report = (
        sys.stdout if to_stdout or (args.csv is not None and str(args.csv) != "-") else sys.stderr
    )
    if to_stdout:
        print(f"{len(estimates)} estimates from {args.run} ({name})")
        print("\n".join(track_lines(track_figures(estimates))))
    status = 0
    same_as_live = live is not None and args.receiver in (None, live.name)
    if same_as_live and not overrides and args.channel is None:
        agreement, text = compare_estimates(recorded, estimates, track_ids=track_ids)
        verdict = {"equal": "replay equals live", "prefix": "replay matches live"}
        print(f"{verdict.get(agreement, 'replay DIFFERS from live')}: {text}", file=report)
        status = EXIT_DIFFERS if agreement == "differ" else 0
    if text := refusal_text(refusals):
        print(text, file=sys.stdout if to_stdout else sys.stderr)
    return status


def _check_sound_speed(value: Any) -> None:
    """Refuse an ``--option sound_speed_mps`` that is not a sound speed of water, as
    ``hil estimate --sound-speed`` does (far above it the search's tables exhaust memory)."""
    from hil.errors import ConfigError
    from hil.signals.presets import WATER_SOUND_SPEED_MPS, check_water_sound_speed

    field, hint = "--option sound_speed_mps", "e.g. --option sound_speed_mps=1500"
    if isinstance(value, bool) or not isinstance(value, int | float):
        lo, hi = WATER_SOUND_SPEED_MPS
        raise ConfigError(field, value, f"a sound speed of water, {lo:g} .. {hi:g} m/s", hint)
    check_water_sound_speed(field, float(value), hint)
