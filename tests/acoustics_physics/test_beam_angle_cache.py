"""Ψ of the built-in beam pairs is computed once per process and kept; other patterns are
integrated every time (sim_devices.acoustics.beam)."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from sim_devices.acoustics import beam
from sim_devices.acoustics.beam import (
    BeamPattern,
    OmniBeam,
    PistonBeam,
    equivalent_two_way_beam_angle,
)


def counting(calls: list[BeamPattern], value: float) -> Callable[[BeamPattern, BeamPattern], float]:
    """A stand-in for the quadrature that records its calls and answers ``value``."""

    def integrate(tx: BeamPattern, rx: BeamPattern) -> float:
        calls.append(tx)
        return value

    return integrate


def test_a_kept_angle_is_the_integral_and_is_not_integrated_again(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(beam, "_BEAM_ANGLES", {})
    direct = beam._beam_angle(PistonBeam(31.4), OmniBeam())
    assert equivalent_two_way_beam_angle(PistonBeam(31.4), OmniBeam()) == direct
    calls: list[BeamPattern] = []
    monkeypatch.setattr(beam, "_beam_angle", counting(calls, 0.0))
    assert equivalent_two_way_beam_angle(PistonBeam(31.4), OmniBeam()) == direct  # a new object
    assert calls == []
    assert equivalent_two_way_beam_angle(PistonBeam(31.5), OmniBeam()) == 0.0  # another ka
    assert len(calls) == 1


def test_a_pattern_of_its_own_is_integrated_every_time(monkeypatch: pytest.MonkeyPatch) -> None:
    class Half(OmniBeam):  # a subclass may answer differently: never kept
        pass

    monkeypatch.setattr(beam, "_BEAM_ANGLES", {})
    calls: list[BeamPattern] = []
    monkeypatch.setattr(beam, "_beam_angle", counting(calls, 1.0))
    for _ in range(2):
        equivalent_two_way_beam_angle(Half(), OmniBeam())
    assert len(calls) == 2 and beam._BEAM_ANGLES == {}
