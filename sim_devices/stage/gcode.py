"""The G-code the simulated GRBL 1.1h parses, with GRBL's error codes (``grbl/gcode.c``).

Accepted as GRBL does (modal groups, one command per group, ``error:21`` otherwise):
``G0 G1 G4 G10 L2/L20 G17 G18 G19 G20 G21 G40 G49 G53 G54..G59 G61 G80 G90 G91 G91.1 G92
G92.1 G94``, ``M0 M1 M2 M30 M3 M4 M5 M8 M9``, words ``X Y Z F P L S T N``, comments in
``()`` and after ``;``. Not simulated, answered ``error:20``: arcs (``G2 G3``), probing,
``G28/G30``, ``G93``, ``G43.1``, ``M7`` (not compiled in stock 1.1h), ``M6``.

Negative ``F N P S T`` give ``error:4`` (GRBL checks them while reading words), a repeated
word ``error:25``, a value word no command uses ``error:36``, axis words with no command to
use them ``error:31``.

Examples
--------
>>> parse_block("G1 X-10.5 F600").words
{'X': -10.5, 'F': 600.0}
>>> parse_block("G1 X1 X2")
GcodeError(code=25)
>>> parse_block("G4 P-1")
GcodeError(code=4)
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

_WORD = re.compile(r"([A-Z])([-+]?[0-9]*\.?[0-9]*)")
AXIS_LETTERS = ("X", "Y", "Z")
_VALUE_LETTERS = frozenset("XYZFPLSTN")
_NON_NEGATIVE = frozenset("FNPST")

#: G codes by modal group (gcode.h); the value is the code times 10 (G92.1 is 921).
_G_GROUPS: dict[int, str] = {
    0: "motion", 10: "motion", 800: "motion",
    40: "non_modal", 100: "non_modal", 530: "non_modal", 920: "non_modal", 921: "non_modal",
    170: "plane", 180: "plane", 190: "plane",
    900: "distance", 910: "distance", 911: "arc_distance", 940: "feed_mode",
    200: "units", 210: "units", 400: "cutter", 490: "tool_length", 610: "control",
    540: "coord", 550: "coord", 560: "coord", 570: "coord", 580: "coord", 590: "coord",
}  # fmt: skip
_M_GROUPS: dict[int, str] = {
    0: "stopping", 1: "stopping", 2: "stopping", 30: "stopping",
    3: "spindle", 4: "spindle", 5: "spindle", 8: "coolant", 9: "coolant",
}  # fmt: skip


@dataclass(frozen=True)
class GcodeError:
    """A block rejected with GRBL ``error:<code>``."""

    code: int


@dataclass(frozen=True)
class Block:
    """A parsed block: ``g`` maps modal group to the code x 10 (``{"motion": 10}`` is G1),
    ``m`` maps group to the M number, ``words`` the value words (as written, mm or inch)."""

    g: dict[str, int] = field(default_factory=dict)
    m: dict[str, int] = field(default_factory=dict)
    words: dict[str, float] = field(default_factory=dict)

    @property
    def axis_words(self) -> dict[str, float]:
        """The X, Y, Z words of the block."""
        return {k: v for k, v in self.words.items() if k in AXIS_LETTERS}


def clean(line: str) -> str:
    """Upper-case ``line`` without spaces, control characters and comments (GRBL's
    pre-parser in ``protocol_main_loop``)."""
    line = re.sub(r"\([^)]*\)?", "", line.split(";", 1)[0])
    return "".join(c for c in line if c > " ").upper()


def parse_words(text: str) -> list[tuple[str, float]] | GcodeError:
    """Split cleaned text into (letter, value) words or a GRBL error (1: no letter,
    2: bad number)."""
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
    """Parse one block; ``jog`` applies the ``$J=`` rules (only G20/G21/G90/G91/G53 and
    X Y Z F N words, ``error:16`` otherwise; F required, ``error:22``)."""
    words = parse_words(clean(line))
    if isinstance(words, GcodeError):
        return words
    g: dict[str, int] = {}
    m: dict[str, int] = {}
    values: dict[str, float] = {}
    for letter, value in words:
        if letter == "G":
            code = round(value * 10)
            group = _G_GROUPS.get(code)
            if group is None or abs(value * 10 - code) > 1e-6:
                return GcodeError(16 if jog else 20)
            if jog and code not in (200, 210, 530, 900, 910):
                return GcodeError(16)
            if group in g:
                return GcodeError(21)
            g[group] = code
        elif letter == "M":
            mgroup = _M_GROUPS.get(int(value)) if value == int(value) else None
            if jog or mgroup is None:
                return GcodeError(16 if jog else 20)
            if mgroup in m:
                return GcodeError(21)
            m[mgroup] = int(value)
        elif letter in _VALUE_LETTERS:
            if jog and letter not in "XYZFN":
                return GcodeError(16)
            if letter in values:
                return GcodeError(25)
            if letter in _NON_NEGATIVE and value < 0:
                return GcodeError(4)
            values[letter] = value
        else:
            return GcodeError(16 if jog else 20)
    block = Block(g, m, values)
    error = _check_jog(block) if jog else _check(block)
    return error if error is not None else block


def _check_jog(block: Block) -> GcodeError | None:
    if "F" not in block.words:
        return GcodeError(22)
    if not block.axis_words:
        return GcodeError(26)
    return None


def _check(block: Block) -> GcodeError | None:
    """GRBL's error checks that need the whole block (gcode.c, step 3)."""
    non_modal = block.g.get("non_modal")
    words = block.words
    if "N" in words and words["N"] > 9999999:
        return GcodeError(27)
    if non_modal == 40 and "P" not in words:
        return GcodeError(28)
    if non_modal == 100:
        if "L" not in words or "P" not in words:
            return GcodeError(28)
        if words["L"] not in (2.0, 20.0):
            return GcodeError(20)
        if words["P"] != int(words["P"]) or not 0 <= words["P"] <= 6:
            return GcodeError(29)
        if not block.axis_words:
            return GcodeError(26)
    if non_modal == 920 and not block.axis_words:
        return GcodeError(26)
    if "L" in words and non_modal != 100:
        return GcodeError(36)
    if "P" in words and non_modal not in (40, 100):
        return GcodeError(36)
    uses_axes = non_modal in (100, 920) or block.g.get("motion") != 800
    if block.axis_words and non_modal == 40:
        return GcodeError(31)
    if block.axis_words and not uses_axes:
        return GcodeError(31)
    if "F" in words and words["F"] == 0.0 and block.g.get("motion") == 10:
        return GcodeError(22)
    return None
