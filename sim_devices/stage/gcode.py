"""The small G-code subset the simulated GRBL understands, with GRBL's error codes.

Supported: ``G0 G1 G4 G21 G53 G90 G91 G94``, words ``X F P N``, ``M5 M9`` (no-ops),
comments in ``()`` and after ``;``. Y and Z words and everything else give ``error:20``
(the simulated machine has one axis). Errors follow GRBL 1.1's numbering.

Examples
--------
>>> parse_block("G1 X-10.5 F600")
Block(motion=1, distance=None, machine_coords=False, dwell=None, x=-10.5, feed=600.0)
>>> parse_block("G1 X1 X2")
GcodeError(code=25)
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_WORD = re.compile(r"([A-Z])([-+]?[0-9]*\.?[0-9]*)")


@dataclass(frozen=True)
class GcodeError:
    """A block rejected with GRBL ``error:<code>``."""

    code: int


@dataclass(frozen=True)
class Block:
    """A parsed block: motion mode (0/1 or None), distance mode (90/91 or None), G53,
    dwell seconds (G4), X target word (mm) and feed (mm/min), ``None`` when absent."""

    motion: int | None
    distance: int | None
    machine_coords: bool
    dwell: float | None
    x: float | None
    feed: float | None


def clean(line: str) -> str:
    """Upper-case ``line`` without spaces and comments (GRBL's pre-parser)."""
    line = re.sub(r"\([^)]*\)", "", line.split(";", 1)[0])
    return line.replace(" ", "").replace("\t", "").upper()


def parse_words(text: str) -> list[tuple[str, float]] | GcodeError:
    """Split cleaned text into (letter, value) words or a GRBL error."""
    words: list[tuple[str, float]] = []
    pos = 0
    while pos < len(text):
        if not text[pos].isalpha():
            return GcodeError(1)
        match = _WORD.match(text, pos)
        if match is None or match.group(2) in ("", "-", "+", ".", "-.", "+."):
            return GcodeError(2)
        words.append((match.group(1), float(match.group(2))))
        pos = match.end()
    return words


def parse_block(line: str, *, jog: bool = False) -> Block | GcodeError:
    """Parse one G-code block; ``jog`` applies the ``$J=`` rules (error 16 on others)."""
    words = parse_words(clean(line))
    if isinstance(words, GcodeError):
        return words
    motion: int | None = None
    distance: int | None = None
    machine = False
    dwell_mode = False
    values: dict[str, float] = {}
    for letter, value in words:
        if letter == "G":
            if value != int(value):
                return GcodeError(16 if jog else 20)
            g = int(value)
            if jog and g not in (20, 21, 53, 90, 91):
                return GcodeError(16)
            if g in (0, 1):
                if motion is not None or dwell_mode:
                    return GcodeError(21)
                motion = g
            elif g in (90, 91):
                if distance is not None:
                    return GcodeError(21)
                distance = g
            elif g == 53:
                machine = True
            elif g == 4:
                if motion is not None or dwell_mode:
                    return GcodeError(21)
                dwell_mode = True
            elif g in (21, 94):
                pass
            else:
                return GcodeError(20)
        elif letter == "M" and not jog:
            if value not in (5.0, 9.0):
                return GcodeError(20)
        elif letter in ("X", "F", "P", "N") and not (jog and letter in "PN"):
            if letter in values:
                return GcodeError(25)
            values[letter] = value
        else:
            return GcodeError(16 if jog else 20)
    if "P" in values and not dwell_mode:
        return GcodeError(36)
    if dwell_mode and "P" not in values:
        return GcodeError(28)
    if dwell_mode and "X" in values:
        return GcodeError(31)
    if machine and motion is None and not jog:
        return GcodeError(30)
    if "F" in values and values["F"] <= 0.0:
        return GcodeError(4 if values["F"] < 0 else 22)
    if jog and "X" not in values:
        return GcodeError(26)
    if jog and "F" not in values:
        return GcodeError(22)
    return Block(
        motion=motion,
        distance=distance,
        machine_coords=machine,
        dwell=values.get("P") if dwell_mode else None,
        x=values.get("X"),
        feed=values.get("F"),
    )
