"""``hil waveform``: synthesise a transmit waveform to a float32 WAV with its schedule file.

Example::

    hil waveform --preset att --family random-cyclic --duration 2 --fs 100000 \\
        --out x.wav --schedule x.json --plot diag/
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from hil.errors import ConfigError
from hil.signals.presets import PRESETS, check_design, check_water_sound_speed, get_preset
from hil.signals.schedule_file import schedule_document, write_schedule_file
from hil.signals.synthesis import BlockSynthesizer
from hil.signals.waveforms import FAMILIES, check_family_fields, design_summary

# Samples synthesised per block when writing the WAV: bounded memory for long files.
_WRITE_BLOCK = 1 << 20

# Command-line option -> WaveformSpec field.
_OVERRIDES: dict[str, str] = {
    "fs": "fs_hz",
    "center": "center_hz",
    "bandwidth": "bandwidth_hz",
    "tones": "n_tones",
    "hop": "hop_s",
    "code_length": "code_length",
    "window": "window",
    "order": "order",
    "sequence": "sequence",
    "seed": "seed",
    "candidates": "candidates",
    "m_hops": "m_hops",
    "sweep": "sweep_s",
    "costas_prime": "costas_prime",
    "subchirp_bandwidth": "subchirp_bandwidth_hz",
    "pulse": "pulse_s",
    "pri": "pri_s",
    "sound_speed": "sound_speed_mps",
    "max_speed": "max_speed_mps",
    "min_speed": "min_speed_mps",
    "max_range": "max_range_m",
}

# Internal field names -> the options that set them (hil.cli.main names them in errors).
OPTION_NAMES = {
    **{field: "--" + opt.replace("_", "-") for opt, field in _OVERRIDES.items()},
    "family": "--family",
    "preset": "--preset",
    "n_tones": "--tones",
    "prime": "--costas-prime",
    "M": "--m-hops",
}


def register(sub: Any) -> None:
    """Add the ``waveform`` sub-command."""
    p: argparse.ArgumentParser = sub.add_parser(
        "waveform",
        help="synthesise a transmit waveform (WAV + schedule JSON + diagnostics)",
        description="Synthesise a transmit waveform to a float32 WAV and write its hop "
        "schedule as JSON (format: hil docs schedule-format). Options override the preset.",
    )
    p.add_argument("--preset", default="att", help=f"one of {', '.join(PRESETS)} (default att)")
    p.add_argument(
        "--family",
        default="random-cyclic",
        help=f"one of {', '.join(FAMILIES)} (default random-cyclic)",
    )
    p.add_argument("--duration", type=float, default=2.0, help="seconds to synthesise (default 2)")
    p.add_argument("--out", type=Path, help="float32 WAV file to write")
    p.add_argument(
        "--max-size", type=float, default=4.0, metavar="GB",
        help="refuse a WAV larger than this, GB (default 4; above 4 GiB the file is RF64)",
    )  # fmt: skip
    p.add_argument("--schedule", type=Path, help="schedule JSON file to write")
    p.add_argument("--plot", type=Path, metavar="DIR", help="write diagnostic PNGs into DIR")
    p.add_argument(
        "--amplitude",
        type=float,
        default=0.9,
        help="peak amplitude in the WAV, 0 < a <= 1 (default 0.9)",
    )
    g = p.add_argument_group("design overrides (default: the preset's value)")
    g.add_argument("--fs", type=float, help="sample rate, Hz")
    g.add_argument("--center", type=float, help="carrier f_c, Hz")
    g.add_argument("--bandwidth", type=float, help="occupied bandwidth B_w, Hz")
    g.add_argument("--tones", type=int, help="number of tones N_F")
    g.add_argument("--hop", type=float, help="hop duration T_h, s")
    g.add_argument("--code-length", type=int, help="random-cyclic code length L")
    g.add_argument("--window", type=int, help="random-cyclic unique-window length W")
    g.add_argument("--order", type=int, help="three-state codeword length L_c")
    g.add_argument("--sequence", choices=("debruijn", "mseq"), help="three-state bit source")
    g.add_argument("--seed", type=int, help="random-cyclic code search seed")
    g.add_argument("--candidates", type=int, help="random-cyclic codes drawn (best d_min kept)")
    g.add_argument("--m-hops", type=int, help="correlator length M used for d_min")
    g.add_argument("--sweep", type=float, help="FMCW sweep duration, s")
    g.add_argument("--costas-prime", type=int, help="prime p of the Welch Costas array")
    g.add_argument("--subchirp-bandwidth", type=float, help="costas-lfm sub-chirp sweep, Hz")
    g.add_argument("--pulse", type=float, help="pulse duration, s")
    g.add_argument("--pri", type=float, help="pulse repetition interval, s")
    g.add_argument("--sound-speed", type=float, help="sound speed c, m/s")
    g.add_argument("--max-speed", type=float, help="fastest target of interest, m/s")
    g.add_argument("--min-speed", type=float, help="slowest target of interest, m/s")
    g.add_argument("--max-range", type=float, help="largest range of interest, m")
    p.add_argument("--json", action="store_true", help="print the design summary as JSON")
    p.set_defaults(func=run)


def _validate_io(args: argparse.Namespace) -> None:
    if args.seed is not None and args.seed < 0:
        raise ConfigError("--seed", args.seed, "an integer >= 0", "e.g. --seed 1")
    if not (math.isfinite(args.duration) and args.duration > 0):
        raise ConfigError("--duration", args.duration, "> 0 s")
    if not (math.isfinite(args.amplitude) and 0 < args.amplitude <= 1):
        raise ConfigError("--amplitude", args.amplitude, "in (0, 1] (full scale is 1)")
    if not (math.isfinite(args.max_size) and args.max_size > 0):
        raise ConfigError("--max-size", args.max_size, "> 0 GB")
    from hil.outputs import writable_file, writable_folder

    for opt in ("out", "schedule"):
        path = getattr(args, opt)
        if path is not None:
            writable_file(path, f"--{opt}")
    if args.plot is not None:
        writable_folder(args.plot, "--plot")


def _write_wav(path: Path, synth: BlockSynthesizer, n_samples: int, fs: float) -> None:
    """Stream a float32 WAV (IEEE float, mono) block by block (RF64 above 4 GiB)."""
    from hil.signals.wav_stream import write_float_wav

    def render(start: int, count: int) -> np.ndarray:
        return synth.render(start, count, np.float32)

    with path.open("wb") as fh:
        write_float_wav(fh, render, n_samples, int(round(fs)), block=_WRITE_BLOCK)


def _check_size(args: argparse.Namespace, n_samples: int, fs: float) -> None:
    """Refuse a WAV larger than ``--max-size`` or than the free space of its folder."""
    import shutil

    from hil.signals.wav_stream import wav_bytes

    size = wav_bytes(n_samples)
    what = f"{args.duration:g} s at {fs:g} Hz is {size / 1e9:.3g} GB of float32 WAV"
    if size > args.max_size * 1e9:
        raise ConfigError(
            "--duration", args.duration, f"a WAV of at most --max-size {args.max_size:g} GB",
            f"{what}; shorten --duration or raise --max-size (above 4 GiB the file is RF64)",
        )  # fmt: skip
    free = shutil.disk_usage(args.out.resolve().parent).free
    if size > free:
        raise ConfigError(
            "--duration", args.duration, f"a WAV that fits the {free / 1e9:.3g} GB free",
            f"{what}; shorten --duration or write --out elsewhere",
        )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    """Execute ``hil waveform``; return the exit status."""
    _validate_io(args)
    overrides = {field: getattr(args, opt) for opt, field in _OVERRIDES.items()}
    check_family_fields(args.family, overrides)
    if args.sound_speed is not None:
        check_water_sound_speed("--sound-speed", args.sound_speed, "e.g. --sound-speed 1500")
    preset = get_preset(args.preset)
    spec = preset.spec(args.family, **overrides)
    schedule = check_design(spec)
    fs = spec.fs_hz
    n = int(round(args.duration * fs))
    summary = design_summary(schedule, spec.sound_speed_mps)
    summary.update(preset=preset.name, fs=fs, duration_s=args.duration, samples=n)
    if args.family == "random-cyclic":
        summary["d_min"] = schedule.params.get("d_min")
        summary["m_hops"] = spec.m_hops
    synth = BlockSynthesizer(schedule, fs, amplitude=args.amplitude)
    if args.out is not None:
        _check_size(args, n, fs)
        _write_wav(args.out, synth, n, fs)
        summary["wav"] = str(args.out)
    if args.schedule is not None:
        doc = schedule_document(
            schedule,
            fs,
            args.duration,
            sound_speed_mps=spec.sound_speed_mps,
            amplitude=args.amplitude,
            spec=spec.to_dict(),
        )
        write_schedule_file(args.schedule, doc)
        summary["schedule"] = str(args.schedule)
    if args.plot is not None:
        from hil.signals.plots import write_diagnostics

        paths = write_diagnostics(
            schedule,
            fs,
            args.plot,
            max_speed_mps=spec.max_speed_mps,
            sound_speed_mps=spec.sound_speed_mps,
            duration_s=args.duration,
        )
        summary["plots"] = [str(p) for p in paths]
    if args.json:
        print(json.dumps(summary))
    else:
        _print_summary(summary, schedule.code.tolist())
    return 0


def _print_summary(summary: dict[str, Any], code: list[int]) -> None:
    lines = [
        f"preset {summary['preset']}, family {summary['family']}: "
        f"{summary['samples']} samples at {summary['fs']:g} Hz ({summary['duration_s']:g} s)",
        "tones (Hz): " + ", ".join(f"{f:.3f}" for f in summary["tones_hz"]),
        f"code ({summary['period_hops']} hops/period): {code[:64]}"
        + (" ..." if len(code) > 64 else ""),
        f"period {summary['period_s']:.6g} s, unambiguous range "
        f"{summary['unambiguous_range_m']:.2f} m",
    ]
    if "hop_s" in summary:
        lines.append(
            f"hop {summary['hop_s'] * 1e3:.4g} ms"
            + (
                f", tone spacing {summary['tone_spacing_hz']:.6g} Hz, "
                f"Δf·T_h = {summary['df_times_hop']:.6g}"
                if "tone_spacing_hz" in summary
                else ""
            )
        )
    if summary.get("d_min") is not None:
        lines.append(f"d_min = {summary['d_min']} at M = {summary['m_hops']}")
    for key in ("wav", "schedule"):
        if key in summary:
            lines.append(f"wrote {summary[key]}")
    if "plots" in summary:
        lines.append(f"wrote {len(summary['plots'])} plots: " + ", ".join(summary["plots"]))
    print("\n".join(lines))
