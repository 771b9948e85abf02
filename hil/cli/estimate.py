"""``hil estimate``: run a receiver over a received WAV and print its estimates.

Example::

    hil estimate --schedule x.json --input rx.wav --receiver gcas --M 10 --json

Without ``--json`` or ``--csv``, a table of the estimates (time s, range m, speed m/s, SNR dB)
as they come, then their count. One JSON object per line (``--json``) or CSV (``--csv FILE``,
``-`` for stdout) with at least
``t_s`` (receive time of the detected hop boundary, s from the start of the input),
``range_m``, ``speed_mps`` (closing positive), ``hop_index`` and ``score``, and each estimate's
Cramér–Rao bounds at its own SNR, ``crlb_range_m`` and ``crlb_speed_mps`` (GCAS with its
default refinement; null in JSON, empty in CSV, where a receiver does not measure them:
``--option refine=false``), and ``track_id``, the confirmed track of the estimate (−1 for
none; :mod:`hil.estimation.tracking`, set with ``--option track_confirm_hits=4`` and the
other ``track_*`` settings). Without ``--json``/``--csv`` it prints the count and one line
per track. ``--map PNG`` draws the time–codeword map (receivers that keep one: GCAS).

GCAS searches the input a second time with the echoes it measured taken out, so a target
hidden in a stronger one's Doppler row (10 dB weaker at the same speed, a cell or two from
it, beside its ghost) is reported too (:mod:`hil.estimation.gcas.residual`);
``--option cancel=false`` searches once (a third less CPU with a target in view).

An echo faster than the Doppler span (``--max-speed``) is refused, not aliased; GCAS says so
once per side (closing, opening) when it first sees one
(:mod:`hil.estimation.gcas.beyond_span`): a line ``note: an echo beyond the ±30 m/s Doppler
span was seen (closing) at t = … s (hop …)`` in the table, a JSON line
``{"notice": "beyond_span", "t_s", "hop_index", "side", "max_speed_mps", "speed_mps"}`` with
``--json`` (no estimate line has a ``notice`` key), a warning on stderr with ``--csv``.
Clutter is said the same way (:mod:`hil.estimation.gcas.clutter_seen`; the reverberation
band off): ``note: diffuse reverberation (clutter) at 2.46 m at t = … s (hop …): counted as
clutter, not reported as a target``, or ``{"notice": "clutter", "t_s", "hop_index",
"range_m", "speed_mps"}``, the first time at each range (again only more than 1 m from every
range said).

What GCAS refused instead of reporting is said at the end, by reason
(:data:`hil.estimation.base.REFUSAL_REASONS`: not one echo of the schedule — ghosts and
noise —, diffuse reverberation as clutter, the reverberation band's edge, beyond the Doppler
span, beyond the maximum range, hops before the input's start, a second detection of an echo
already reported at that boundary, an echo that ended within the window, before its
boundary): a line ``refused: 3 not one
echo of the schedule (ghosts, sidelobes, noise), …`` after the table, on stderr with ``--json`` or
``--csv``.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import logging
import math
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from hil.errors import ConfigError

# The numeric modules (numpy; numba through the receivers and the tracker) are imported
# where the command runs, so that building the parser for ``hil estimate --help`` (and for
# ``hil replay``, which reuses this module) stays cheap. Nothing on this path imports h5py,
# matplotlib (only --map draws) or scipy (tests/cli/test_cli_estimate.py).
if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from hil.estimation.base import Estimate, Notice

_LOG = logging.getLogger(__name__)

#: The settings every receiver takes, each set by its own flag (checked there), never by
#: ``--option``.
COMMON_OPTIONS = {
    "sound_speed_mps": "--sound-speed",
    "max_speed_mps": "--max-speed",
    "max_range_m": "--max-range",
    "m_hops": "--m-hops",
}
# Internal field names -> the options that set them (hil.cli.main names them in errors).
OPTION_NAMES = {**COMMON_OPTIONS, "receiver": "--receiver"}

# Input samples per block: bounded memory for long recordings.
_READ_BLOCK = 1 << 16


def register(sub: Any) -> None:
    """Add the ``estimate`` sub-command."""
    from hil.estimation.registry import RECEIVERS

    p: argparse.ArgumentParser = sub.add_parser(
        "estimate",
        help="estimate range and speed from a received WAV",
        description="Run a receiver over a received WAV (PCM of 8 to 64 bits or 32/64-bit "
        "float, any number of channels) "
        "and print one estimate per detected hop boundary: time (s), range (m), speed (m/s), "
        "SNR (dB). The WAV's sample 0 is the schedule's t = 0. Warns when the WAV does not "
        "follow the schedule's hop code (a schedule of another seed) or is clipped. An echo "
        "faster than --max-speed is refused, never aliased, and said once per side (a note "
        "line; a JSON line with a 'notice' key with --json).",
    )
    p.add_argument("--schedule", type=Path, required=True, help="transmit schedule JSON")
    p.add_argument("--input", type=Path, required=True, help="received WAV file")
    p.add_argument(
        "--receiver", default="gcas", help=f"one of {', '.join(RECEIVERS)} (default gcas)"
    )
    p.add_argument("--channel", type=int, help="channel of a multi-channel WAV (0-based)")
    p.add_argument(
        "--m-hops", "--M", dest="m_hops", type=int, default=10,
        help="correlator length M, hops (as hil waveform --m-hops; --M is the same)",
    )  # fmt: skip
    p.add_argument("--sound-speed", type=float, help="c, m/s (default: the schedule's)")
    p.add_argument(
        "--max-speed", type=float, default=30.0, help="Doppler search span ±, m/s (default 30)"
    )
    p.add_argument(
        "--max-range", type=float, default=100.0, help="largest range reported, m (default 100)"
    )
    p.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="receiver-specific option (repeatable), e.g. --option n_doppler=64",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object per estimate")
    p.add_argument("--csv", type=Path, metavar="FILE", help="write estimates as CSV ('-': stdout)")
    p.add_argument("--map", type=Path, metavar="PNG", help="draw the time–codeword map")
    p.set_defaults(func=run)


def check_option_kinds(options: dict[str, Any], reference: dict[str, Any]) -> None:
    """Refuse an ``--option`` whose value is not of the kind the setting holds (a number
    where ``reference``, the settings in force, has a number; true/false for a flag)."""
    for key, value in options.items():
        known = reference.get(key)
        if isinstance(known, bool):
            ok, kind = isinstance(value, bool), "true or false"
        elif isinstance(known, int):
            ok, kind = isinstance(value, int) and not isinstance(value, bool), "an integer"
        elif isinstance(known, float):
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            kind = "a number"
        else:
            continue
        if not ok:
            raise ConfigError(
                "--option",
                f"{key}={json.dumps(value) if not isinstance(value, str) else value}",
                f"{kind} for {key} (it is {json.dumps(known)} now)",
                f"write --option {key}={json.dumps(known)}",
            )


def _refuse_common_options(extra: dict[str, Any]) -> None:
    """Refuse an ``--option`` of a common setting: it would override its own option's
    value unchecked (a sound speed of 1e12 m/s exhausts memory)."""
    for key, value in extra.items():
        if key in COMMON_OPTIONS:
            raise ConfigError(
                f"--option {key}", value, "a receiver-specific option",
                f"hil estimate sets it with {COMMON_OPTIONS[key]}: use that instead",
            )  # fmt: skip


def _parse_option(text: str) -> tuple[str, Any]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise ConfigError("--option", text, "KEY=VALUE")
    try:
        parsed: Any = json.loads(value)
    except json.JSONDecodeError:
        parsed = value
    return key.strip(), parsed


class ClipCount:
    """Samples of an integer WAV at its format's full scale (clipped), counted while read."""

    def __init__(self) -> None:
        self.count = 0
        self.first = -1

    def add(self, start: int, at_full_scale: NDArray[np.bool_]) -> None:
        """Count the flagged samples of the block starting at sample ``start``."""
        import numpy as np

        hits = int(np.count_nonzero(at_full_scale))
        if hits and self.first < 0:
            self.first = start + int(np.argmax(at_full_scale))
        self.count += hits


def read_wav_blocks(
    path: Path, channel: int | None, block: int = _READ_BLOCK, clip: ClipCount | None = None
) -> tuple[float, int, Iterator[NDArray[np.float64]]]:
    """Open a WAV for block-wise reading: (fs, n_frames, iterator of float64 blocks).

    Any format :mod:`hil.signals.wav_read` reads (PCM of 8 to 64 bits, 32- or 64-bit float,
    plain or WAVE_FORMAT_EXTENSIBLE, RIFF, RIFX or RF64). Integer formats are scaled to
    [-1, 1). Multi-channel files need ``channel``. ``clip`` counts the integer samples at
    the format's full scale (either sign).
    """
    import numpy as np

    from hil.signals.wav_read import read_wav_layout, wav_blocks

    layout = read_wav_layout(path, "--input")
    n_channels = layout.n_channels
    if n_channels > 1 and channel is None:
        raise ConfigError(
            "--channel",
            None,
            f"one of 0..{n_channels - 1}: the input has {n_channels} channels",
            "choose the hydrophone channel with --channel",
        )
    if channel is not None and not 0 <= channel < n_channels:
        raise ConfigError("--channel", channel, f"0..{n_channels - 1} ({n_channels} channels)")
    fs = float(layout.fs_hz)
    dtype = layout.dtype
    integer = not layout.is_float
    unsigned = dtype == np.uint8  # 8 bits or fewer: offset binary, 128 is zero
    scale = 1.0 / (128.0 if unsigned else float(2 ** (8 * dtype.itemsize - 1)))
    # Full scale of the stored bits, left-justified as read: -32767 clips as -32768 does.
    step = 1 << 8 * (dtype.itemsize - layout.container_bytes)
    high = 255 if unsigned else ((1 << 8 * layout.container_bytes - 1) - 1) * step
    low = 0 if unsigned else -high

    def blocks() -> Iterator[NDArray[np.float64]]:
        start = 0
        for raw in wav_blocks(path, layout, block):
            col: NDArray[Any] = raw if raw.ndim == 1 else raw[:, channel]
            if clip is not None and integer:
                clip.add(start, (col <= low) | (col >= high))
            x = np.asarray(col, dtype=np.float64)
            if unsigned:
                x = x - 128.0
            x = x * scale
            bad = ~np.isfinite(x)
            if bad.any():
                first = start + int(np.argmax(bad))
                raise ConfigError(
                    "--input",
                    str(path),
                    f"finite samples; sample {first} (t = {first / fs:.6f} s) is {x[bad][0]}",
                    "repair or trim the recording",
                )
            start += len(x)
            yield x

    return fs, layout.n_frames, blocks()


def _check_schedule(
    args: argparse.Namespace,
    blocks: Iterator[NDArray[np.float64]],
    schedule: Any,
    fs: float,
    c: float,
) -> Iterator[NDArray[np.float64]]:
    """Warn when the input's first hops do not follow the schedule's code; the blocks again."""
    import numpy as np

    from hil.signals.schedule_match import match_schedule

    head: list[NDArray[np.float64]] = []
    wanted = int(fs * float(np.sum(schedule.duration_s)) * 8)
    for x in blocks:
        head.append(x)
        if sum(len(h) for h in head) >= wanted:
            break
    if head:
        verdict = match_schedule(
            np.concatenate(head), fs, schedule, sound_speed_mps=c, max_speed_mps=args.max_speed
        )
        if verdict is not None and not verdict.matched:
            _LOG.warning(
                "%s does not follow the hop code of %s: over its first %d hops the code's "
                "tones hold %.0f %% of the tone energy, random codes reach %.0f %% (chance "
                "%.0f %%); is the schedule from another seed or run? Estimates would be wrong",
                args.input, args.schedule, verdict.n_hops, 100 * verdict.score,
                100 * verdict.null, 100 * verdict.chance,
            )  # fmt: skip
    return itertools.chain(head, blocks)


def check_outputs(args: argparse.Namespace) -> None:
    """Refuse an unwritable ``--csv`` (or ``--map``) before any work
    (:mod:`hil.outputs`)."""
    from hil.outputs import writable_file

    for option in ("csv", "map"):
        path = getattr(args, option, None)
        if path is not None:
            writable_file(path, f"--{option}")


def _check_numbers(args: argparse.Namespace) -> None:
    """Refuse a speed, range or sound speed that is not a finite number in its range."""
    for option, value, allowed in (
        ("--max-speed", args.max_speed, (0.0, "a finite speed >= 0 m/s")),
        ("--max-range", args.max_range, (0.0, "a finite range > 0 m")),
    ):
        low, words = allowed
        if value is None:
            continue
        strict = option != "--max-speed"
        if not math.isfinite(value) or value < low or (strict and value == low):
            raise ConfigError(option, value, words, "give a number such as the default")
    if args.sound_speed is not None:
        from hil.signals.presets import check_water_sound_speed

        check_water_sound_speed("--sound-speed", args.sound_speed, "e.g. --sound-speed 1500")


def _check_length(path: Path, n_frames: int, fs: float, schedule: Any) -> None:
    """Refuse a WAV shorter than one hop of the schedule: no hop boundary, no estimate."""
    import numpy as np

    try:
        hop_s = float(schedule.hop_s)
    except ConfigError:  # unequal hops: the shortest one
        hop_s = float(np.min(schedule.hops(0, 1).duration_s))
    need = int(math.ceil(hop_s * fs))
    if n_frames < need:
        raise ConfigError(
            "--input",
            str(path),
            f"at least one hop of signal ({hop_s:.4g} s = {need} samples at {fs:g} Hz)",
            f"it holds {n_frames} sample{'s' * (n_frames != 1)}; record a longer input",
        )


def run(args: argparse.Namespace) -> int:
    """Execute ``hil estimate``; return the exit status."""
    from hil.estimation.numba_start import start_numba

    # Before any kernel runs: numba would import scipy, scipy.linalg, cffi and yaml, which no
    # kernel here needs (hil.estimation.numba_start).
    start_numba()
    from hil.estimation.base import CountsRefusals, SaysNotices
    from hil.estimation.registry import check_receiver_options
    from hil.estimation.track_summary import track_figures, track_lines
    from hil.recording.records import ReceiverSetup
    from hil.recording.replay import build_receiver
    from hil.signals.presets import check_water_sound_speed
    from hil.signals.schedule_file import read_schedule_file

    check_outputs(args)
    _check_numbers(args)
    schedule, doc = read_schedule_file(args.schedule)
    clip = ClipCount()
    fs, n_frames, blocks = read_wav_blocks(args.input, args.channel, clip=clip)
    _check_length(args.input, n_frames, fs, schedule)
    if not math.isclose(fs, float(doc["fs"]), rel_tol=0, abs_tol=0.5):
        raise ConfigError(
            "--input",
            f"{args.input} at {fs:g} Hz",
            f"the schedule's sample rate {float(doc['fs']):g} Hz",
            "resample the recording or write the schedule at the recording's rate",
        )
    c = (
        float(args.sound_speed)
        if args.sound_speed is not None
        else check_water_sound_speed(
            "schedule.sound_speed_mps", float(doc["sound_speed_mps"]), "give --sound-speed"
        )
    )
    extra = dict(_parse_option(o) for o in args.option)
    _refuse_common_options(extra)
    # Named for the receiver chosen, with all its options (a staged GCAS's stage's too).
    check_receiver_options(args.receiver, extra)
    collector = _MapCollector() if args.map is not None else None
    if collector is not None:
        if args.receiver != "gcas":
            raise ConfigError(
                "--map", str(args.map), "used with --receiver gcas (it keeps the map)"
            )
        extra["on_map"] = collector
    hooks = {"on_map": extra.pop("on_map")} if "on_map" in extra else {}
    base = {
        "sound_speed_mps": c,
        "max_speed_mps": args.max_speed,
        "max_range_m": args.max_range,
        "m_hops": args.m_hops,
    }
    check_option_kinds(extra, base)
    settings = {**base, **extra}
    receiver = build_receiver(ReceiverSetup(args.receiver, settings), schedule, fs, **hooks)
    blocks = _check_schedule(args, blocks, schedule, fs, c)
    sink = _Sink(args)
    says = receiver if isinstance(receiver, SaysNotices) else None
    try:
        for x in blocks:
            sink.emit(receiver.process(x))
            if says is not None:
                sink.notices(says.notices())
        sink.emit(receiver.flush())
        if says is not None:
            sink.notices(says.notices())
    finally:
        sink.close()
    if clip.count:
        _LOG.warning(
            "%s is clipped: %d samples at the integer format's full scale, the first at "
            "t = %.6f s; lower the input gain and record again (estimates there are unreliable)",
            args.input, clip.count, clip.first / fs,
        )  # fmt: skip
    if collector is not None:
        collector.draw(args.map)
    if not args.json and args.csv is None:
        print(f"{sink.count} estimates from {args.input} ({args.receiver})")
        print("\n".join(track_lines(track_figures(sink.kept))))
    if isinstance(receiver, CountsRefusals):
        sink.refusals(receiver.refusals())
    return 0


def _json_value(value: Any) -> Any:
    """``value`` for strict JSON: None for a NaN or an infinity."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


#: The table printed without --json or --csv: (header, width, format) per column.
TABLE_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("t (s)", "t_s", "{:10.4f}"),
    ("range (m)", "range_m", "{:10.3f}"),
    ("speed (m/s)", "speed_mps", "{:+12.3f}"),
    ("SNR (dB)", "snr_db", "{:9.1f}"),
)


def table_header() -> str:
    """The header line of the estimate table (right-aligned over its columns).

    >>> table_header()
    '     t (s)  range (m)  speed (m/s)  SNR (dB)'
    """
    widths = [len(fmt.format(0.0)) for _, _, fmt in TABLE_COLUMNS]
    return " ".join(h.rjust(w) for (h, _, _), w in zip(TABLE_COLUMNS, widths, strict=True))


def table_row(row: dict[str, Any]) -> str:
    """One estimate (``Estimate.to_dict()``) as a line of the table.

    >>> table_row({"t_s": 0.25, "range_m": 40.0, "speed_mps": 9.0, "snr_db": float("nan")})
    '    0.2500     40.000       +9.000       nan'
    """
    return " ".join(fmt.format(float(row[key])) for _, key, fmt in TABLE_COLUMNS)


class _Sink:
    """Writes estimates as they arrive: JSON lines (``--json``), CSV (``--csv``), else a
    table on stdout (time, range, speed, SNR)."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.json = bool(args.json)
        self.table = not args.json and args.csv is None
        self.count = 0
        self._said = 0  # notices said so far
        self.kept: list[Estimate] = []  # for the per-track lines of the plain listing
        self._keep = not self.json and args.csv is None
        self._csv_file: TextIO | None = None
        self._writer: Any = None
        if args.csv is not None:
            if str(args.csv) == "-":
                self._csv_file = sys.stdout
            else:
                self._csv_file = args.csv.open("w", newline="", encoding="utf-8")
            from hil.estimation.base import ESTIMATE_FIELDS

            self._writer = csv.DictWriter(self._csv_file, fieldnames=list(ESTIMATE_FIELDS))
            self._writer.writeheader()

    def emit(self, estimates: list[Estimate]) -> None:
        for e in estimates:
            row = e.to_dict()
            if self.json:
                # Strict JSON: a NaN (no bound, no SNR) is null.
                finite = {k: _json_value(v) for k, v in row.items()}
                print(json.dumps(finite, allow_nan=False), flush=False)
            if self._writer is not None:
                self._writer.writerow(row)
            if self.table:
                if self.count == 0:
                    print(table_header())
                print(table_row(row))
            self.count += 1
        if self._keep:
            self.kept.extend(estimates)
        if self.json or self.table:
            sys.stdout.flush()

    def notices(self, sightings: Sequence[Notice]) -> None:
        """Say once each notice of the receiver (``sightings``, all so far,
        :class:`~hil.estimation.base.SaysNotices`: an echo beyond the Doppler span, clutter):
        a JSON line ``{"notice": "beyond_span" | "clutter", ...}`` with ``--json``, a
        ``note:`` line in the table, a warning on stderr with ``--csv``."""
        for sighting in sightings[self._said :]:
            self._said += 1
            if self.json:
                print(json.dumps(sighting.to_dict(), allow_nan=False), flush=True)
            elif self.table:
                print(f"note: {sighting.text()}", flush=True)
            else:
                _LOG.warning("%s", sighting.text())

    def refusals(self, counts: dict[str, int]) -> None:
        """Say what the receiver refused instead of reporting (``counts`` by reason,
        :class:`~hil.estimation.base.CountsRefusals`) in one ``refused: …`` line, none where
        nothing was refused: after the table, on stderr with ``--json`` or ``--csv`` (their
        stdout holds estimates)."""
        from hil.estimation.base import refusal_text

        text = refusal_text(counts)
        if text:
            print(text, file=sys.stdout if self.table else sys.stderr, flush=True)

    def close(self) -> None:
        if self._csv_file is not None and self._csv_file is not sys.stdout:
            self._csv_file.close()


class _MapCollector:
    """Keeps the time–codeword map handed out by GCAS (``on_map``), thinned to a plottable
    number of time columns (every ``stride``-th baseband sample)."""

    def __init__(self, max_columns: int = 200_000) -> None:
        self.max_columns = max_columns
        self.times: list[NDArray[np.float64]] = []
        self.power: list[NDArray[np.floating]] = []
        self.kept = 0

    def __call__(self, t_s: NDArray[np.float64], p: NDArray[np.floating], speed: Any) -> None:
        import numpy as np

        if self.kept >= self.max_columns or len(t_s) == 0:
            return
        self.times.append(np.asarray(t_s, dtype=float).copy())
        self.power.append(np.asarray(p).copy())
        self.kept += len(t_s)

    def draw(self, path: Path) -> None:
        """Draw the map (seed Fig 5.17 style) as a PNG: codeword against receive time."""
        if not self.times:
            raise ConfigError("--map", str(path), "an input long enough to produce a map")
        from hil.experiments.codeword_map import save_time_codeword_map

        save_time_codeword_map(path, self.times, self.power)
