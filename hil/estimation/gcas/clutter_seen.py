"""Clutter, labelled: where diffuse reverberation was refused instead of reported.

With the reverberation band off, a detection whose fit is short of one point echo's
coherence while each tone holds its own (:func:`~hil.estimation.reverb_band.is_diffuse`) is
diffuse reverberation: it is refused and counted as clutter
(:attr:`hil.estimation.gcas.GcasReceiver.clutter_count`). So that a user sees *where* the
clutter is, and that it was not taken for a target, the receiver also says it: a
:class:`ClutterSeen` notice the first time clutter is refused at a range, and again only at a
range more than :data:`CLUTTER_NOTICE_M` from every one said before (a patch of near water
refused at every hop is said a few times, not at every hop). ``hil estimate`` prints them as
``note:`` lines or ``{"notice": "clutter", ...}`` JSON lines, as it does an echo beyond the
Doppler span (:mod:`hil.estimation.gcas.beyond_span`).
"""

from __future__ import annotations

from dataclasses import dataclass

#: Range (m) past which clutter is said again: more than any one scatterer patch's
#: resolution cell (``c/(2 B)``, 0.23 m on att) and the fit's range scatter.
CLUTTER_NOTICE_M = 1.0

#: How every notice of clutter begins (:meth:`ClutterSeen.text`).
CLUTTER_TEXT = "diffuse reverberation (clutter) at "


@dataclass(frozen=True)
class ClutterSeen:
    """Clutter refused at ``range_m`` (m): the boundary time ``t_s`` (s, input time) and
    ``hop_index`` of the detection, and the speed its fit read (m/s, closing positive; not an
    estimate: a diffuse patch has no one speed)."""

    t_s: float
    hop_index: int
    range_m: float
    speed_mps: float

    def text(self) -> str:
        """One line for a person: what was seen, where, and what was done with it."""
        return (
            f"{CLUTTER_TEXT}{self.range_m:.2f} m at t = {self.t_s:.4f} s (hop {self.hop_index}): "
            "counted as clutter, not reported as a target"
        )

    def to_dict(self) -> dict[str, object]:
        """JSON-ready fields, with ``"notice": "clutter"``."""
        return {
            "notice": "clutter",
            "t_s": self.t_s,
            "hop_index": self.hop_index,
            "range_m": self.range_m,
            "speed_mps": self.speed_mps,
        }


class ClutterLog:
    """The clutter notices of one receiver (module docstring), in the order seen."""

    def __init__(self) -> None:
        self.sightings: list[ClutterSeen] = []

    def reset(self) -> None:
        """Forget the notices."""
        self.sightings = []

    def add(self, seen: ClutterSeen) -> bool:
        """Keep ``seen`` where no notice said so far is within :data:`CLUTTER_NOTICE_M` of its
        range; whether it was kept."""
        if any(abs(s.range_m - seen.range_m) <= CLUTTER_NOTICE_M for s in self.sightings):
            return False
        self.sightings.append(seen)
        return True
