"""GRBL's G-code parser state (``gc_state`` in ``grbl/gcode.c``): modes, offsets, position.

What a block changes is applied here in ``gc_execute_line``'s order (feed, spindle, coolant,
units, coordinate system, distance mode, ``G10``, ``G92``/``G92.1``, then the target of a
motion). The coordinate systems ``G54``-``G59`` live in EEPROM and survive a soft reset;
the modes and the ``G92`` offset return to their defaults (``gc_init``).

Units: mm and mm/min inside; ``G20`` blocks are scaled by 25.4 on the way in.

>>> from sim_devices.stage.gcode import parse_block
>>> s = ParserState()
>>> s.reset([0.0, 0.0, 0.0])
>>> plan = s.execute(parse_block("G10 L20 P1 X5"))
>>> s.wco(), plan.wco_changed
([-5.0, 0.0, 0.0], True)
>>> s.execute(parse_block("G1 X0 F100")).target
[-5.0, 0.0, 0.0]
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sim_devices.stage.config import AXES
from sim_devices.stage.gcode import Block, GcodeError

COORD_NAMES = ("G54", "G55", "G56", "G57", "G58", "G59")
MM_PER_INCH = 25.4

__all__ = ["COORD_NAMES", "ExecutedBlock", "ParserState", "axes_text"]


@dataclass(frozen=True)
class ExecutedBlock:
    """What the controller must do for a block the parser accepted.

    ``target``: machine target (mm, 3 axes) of a G0/G1 motion, else ``None``; ``rapid``:
    the motion is G0; ``feed_mm_min``: G1's feed; ``dwell_s``: G4's dwell; ``sync``: the
    block waits for the planner to empty (G4, a spindle or coolant change, M0/M1/M2/M30);
    ``program``: the M0/M1/M2/M30 number; ``wco_changed``: the work offset changed.
    """

    target: list[float] | None = None
    rapid: bool = False
    feed_mm_min: float = 0.0
    dwell_s: float = 0.0
    sync: bool = False
    program: int | None = None
    wco_changed: bool = False


@dataclass
class ParserState:
    """The parser's modes (GRBL's codes x 10 for G, as in :mod:`.gcode`), offsets and the
    programmed position (machine mm)."""

    motion: int = 0
    distance: int = 900
    units: int = 210
    coord: int = 0
    feed: float | None = None
    spindle: int = 5
    spindle_speed: float = 0.0
    coolant: int = 9
    position: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    g92: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    coords: list[list[float]] = field(default_factory=lambda: [[0.0] * 3 for _ in COORD_NAMES])

    def reset(self, position: list[float]) -> None:
        """``gc_init`` after a reset: default modes, no G92 offset, position synced."""
        self.motion, self.distance, self.units, self.coord = 0, 900, 210, 0
        self.feed, self.spindle, self.spindle_speed, self.coolant = None, 5, 0.0, 9
        self.g92 = [0.0, 0.0, 0.0]
        self.position = list(position)

    def wco(self) -> list[float]:
        """Work coordinate offset (mm): the active system plus G92."""
        return [c + g for c, g in zip(self.coords[self.coord], self.g92, strict=True)]

    def jog_target(self, block: Block) -> tuple[list[float], float]:
        """Machine target (mm) and feed (mm/min) of a ``$J=`` block (its G20/G90/G91/G53
        apply to the jog alone)."""
        scale = MM_PER_INCH if block.g.get("units", self.units) == 200 else 1.0
        target = self._target(block, block.g.get("distance", self.distance), scale, self.coord)
        return target, block.words["F"] * scale

    def execute(self, block: Block, *, spindle_syncs: bool = True) -> ExecutedBlock | GcodeError:
        """Check ``block`` against the modes, apply it, and say what the machine must do.

        ``spindle_syncs=False`` in check mode (``$C``): nothing waits for the planner.
        Y and Z may not move: the simulated machine drives X only (``error:20``).
        """
        motion = block.g.get("motion", self.motion)
        non_modal = block.g.get("non_modal")
        scale = MM_PER_INCH if block.g.get("units", self.units) == 200 else 1.0
        feed = self.feed if "F" not in block.words else block.words["F"] * scale
        axis_command = bool(block.axis_words) and non_modal not in (100, 920)
        if non_modal == 530 and motion not in (0, 10):
            return GcodeError(30)
        if axis_command and motion == 800:
            return GcodeError(31)
        if axis_command and motion == 10 and not feed:
            return GcodeError(22)
        distance = block.g.get("distance", self.distance)
        coord = (block.g["coord"] - 540) // 10 if "coord" in block.g else self.coord
        target = self._target(block, distance, scale, coord) if axis_command else None
        if target is not None and any(abs(target[i] - self.position[i]) > 1e-9 for i in (1, 2)):
            return GcodeError(20)
        sync = self._accessories(block) and spindle_syncs
        self.feed, self.distance, self.motion = feed, distance, motion
        self.units = block.g.get("units", self.units)
        wco_changed = coord != self.coord
        self.coord = coord
        if non_modal == 100:
            wco_changed |= self._set_coordinate_system(block, scale)
        elif non_modal == 920:
            system = self.coords[self.coord]
            for i, letter in enumerate(AXES):
                if letter in block.words:
                    self.g92[i] = self.position[i] - system[i] - block.words[letter] * scale
            wco_changed = True
        elif non_modal == 921:
            self.g92, wco_changed = [0.0, 0.0, 0.0], True
        program = block.m.get("stopping")
        return ExecutedBlock(
            target=target if motion in (0, 10) else None,
            rapid=motion == 0,
            feed_mm_min=feed or 0.0,
            dwell_s=block.words.get("P", 0.0) if non_modal == 40 else 0.0,
            sync=non_modal == 40 or sync or program is not None,
            program=program,
            wco_changed=wco_changed,
        )

    def end_program(self) -> None:
        """M2/M30 (``gc_execute_line``, program end): G1, G54, G17, G90, G94, M5, M9."""
        self.motion, self.distance, self.coord = 10, 900, 0
        self.spindle, self.coolant = 5, 9

    def modes_report(self) -> str:
        """The ``$G`` line."""
        feed = 0 if self.feed is None else self.feed
        return (
            f"[GC:G{self.motion // 10} {COORD_NAMES[self.coord]} G17 G{self.units // 10} "
            f"G{self.distance // 10} G94 M{self.spindle} M{self.coolant} T0 F{feed:g} "
            f"S{self.spindle_speed:g}]"
        )

    def parameters_report(self) -> list[str]:
        """The ``$#`` lines (no probe, G28/G30 and tool length offset stay at 0)."""
        out = [f"[{n}:{axes_text(v)}]" for n, v in zip(COORD_NAMES, self.coords, strict=True)]
        zeros = "0.000,0.000,0.000"
        g92 = f"[G92:{axes_text(self.g92)}]"
        return [*out, f"[G28:{zeros}]", f"[G30:{zeros}]", g92, "[TLO:0.000]", f"[PRB:{zeros}:0]"]

    def _accessories(self, block: Block) -> bool:
        """Apply M3/M4/M5, M8/M9 and S; True if the spindle or coolant changed (GRBL then
        waits for the planner to empty: ``spindle_sync``, ``coolant_sync``)."""
        changed = False
        if "S" in block.words:
            self.spindle_speed = block.words["S"]
        if "spindle" in block.m and block.m["spindle"] != self.spindle:
            self.spindle, changed = block.m["spindle"], True
        if "coolant" in block.m and block.m["coolant"] != self.coolant:
            self.coolant, changed = block.m["coolant"], True
        return changed

    def _set_coordinate_system(self, block: Block, scale: float) -> bool:
        """``G10 L2 Pn`` (offsets given) or ``G10 L20 Pn`` (offsets that make the present
        position the values given); ``P0`` is the active system. True if it is active."""
        p = int(block.words["P"])
        index = self.coord if p == 0 else p - 1
        for i, letter in enumerate(AXES):
            if letter in block.words:
                value = block.words[letter] * scale
                if block.words["L"] == 20:
                    value = self.position[i] - self.g92[i] - value
                self.coords[index][i] = value
        return index == self.coord

    def _target(self, block: Block, distance: int, scale: float, coord: int) -> list[float]:
        system = self.coords[coord]
        target = list(self.position)
        for i, letter in enumerate(AXES):
            if letter not in block.words:
                continue
            value = block.words[letter] * scale
            if block.g.get("non_modal") == 530:
                target[i] = value
            elif distance == 900:
                target[i] = value + system[i] + self.g92[i]
            else:
                target[i] = self.position[i] + value
        return target


def axes_text(values: list[float]) -> str:
    """``x,y,z`` with 3 decimals, as GRBL prints positions."""
    return ",".join(f"{v:.3f}" for v in values)
