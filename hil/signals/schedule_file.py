"""The JSON schedule file written next to a waveform WAV (format in docs/schedule-format.md).

Top level: ``format`` (``"cas-hil-schedule"``), ``version`` (1), ``fs``, ``family``,
``tones_hz``, ``code``, ``period_hops``, ``period_s``, ``sound_speed_mps``,
``unambiguous_delay_s``, ``unambiguous_range_m``, ``duration_s``, ``amplitude``, ``spec``
(every design parameter), ``period`` (the one-period definition that rebuilds the endless
schedule exactly) and ``hops``: every hop overlapping the WAV, each with ``index``,
``start_s``, ``duration_s``, ``tone_index``, ``freq_hz``, ``chirp_hz_per_s``, ``phase_rad``
and ``amplitude``. Sample ``n`` of the WAV (t = n/fs) inside a hop is
``A · a · cos(φ + 2π (f (t − t_s) + ½ k (t − t_s)²))`` with ``A`` the file's ``amplitude``,
``a``, ``φ``, ``f``, ``k``, ``t_s`` the hop's ``amplitude``, ``phase_rad``, ``freq_hz``,
``chirp_hz_per_s`` and ``start_s``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from hil.errors import ConfigError
from hil.signals.schedule import HopSchedule
from hil.signals.waveforms import design_summary

FORMAT_NAME = "cas-hil-schedule"
FORMAT_VERSION = 1


def schedule_document(
    schedule: HopSchedule,
    fs_hz: float,
    duration_s: float,
    *,
    sound_speed_mps: float,
    amplitude: float = 1.0,
    spec: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The schedule file's content for a WAV of ``duration_s`` seconds at ``fs_hz``."""
    summary = design_summary(schedule, sound_speed_mps)
    hops = schedule.hops_in_span(0.0, duration_s) if duration_s > 0 else schedule.hops(0, 0)
    return {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "fs": float(fs_hz),
        "family": schedule.family,
        "tones_hz": schedule.tones_hz.tolist(),
        "code": schedule.code.tolist(),
        "period_hops": schedule.period_hops,
        "period_s": schedule.period_s,
        "sound_speed_mps": float(sound_speed_mps),
        "unambiguous_delay_s": summary["unambiguous_delay_s"],
        "unambiguous_range_m": summary["unambiguous_range_m"],
        "duration_s": float(duration_s),
        "amplitude": float(amplitude),
        "spec": dict(spec or schedule.params),
        "period": schedule.period_dict(),
        "hops": hops.to_records(),
    }


def write_schedule_file(path: Path, document: dict[str, Any]) -> Path:
    """Write the document as indented JSON."""
    path.write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")
    return path


def read_schedule_file(path: Path) -> tuple[HopSchedule, dict[str, Any]]:
    """Load a schedule file: the endless schedule and the whole document.

    Raises :class:`ConfigError` naming the problem for a file that is not a schedule file.
    """
    from hil.toml_table import read_text_file

    try:
        doc = json.loads(read_text_file(path, "schedule"))
    except FileNotFoundError:
        raise ConfigError("schedule", str(path), "an existing schedule JSON file") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(
            "schedule", str(path), f"valid JSON ({exc.msg} at line {exc.lineno})"
        ) from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT_NAME:
        raise ConfigError(
            "schedule",
            str(path),
            f'a file with "format": "{FORMAT_NAME}"',
            "write one with `hil waveform --schedule FILE`",
        )
    if doc.get("version") != FORMAT_VERSION:
        raise ConfigError("schedule.version", doc.get("version"), f"{FORMAT_VERSION}")
    if "period" not in doc or "fs" not in doc:
        raise ConfigError("schedule", str(path), "a document with 'period' and 'fs'")
    for key, unit in (("fs", "Hz"), ("sound_speed_mps", "m/s")):
        value = doc.get(key, 1.0)
        if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
            raise ConfigError(
                f"schedule.{key}", value, f"a number > 0 ({unit})",
                f"{path} is damaged: write it again with `hil waveform --schedule FILE`",
            )  # fmt: skip
    if not isinstance(doc["period"], dict):
        raise ConfigError("schedule.period", doc["period"], "an object (the hop period)")
    try:
        schedule = HopSchedule.from_period_dict(doc["period"])
    except ConfigError as exc:
        raise ConfigError(f"schedule.{exc.field}", exc.value, exc.allowed, exc.hint) from None
    return schedule, doc
