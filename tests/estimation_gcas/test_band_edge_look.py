"""The refinement's look at a detection it is not to remember
(:meth:`hil.estimation.refine.CoherentRefiner.refine` with ``remember=False``, used on the
reverberation band's edge by :meth:`hil.estimation.gcas.beyond_span.BeyondSpanCheck.
in_band_ghost`), and whether a window is known to hold no still water
(:meth:`~hil.estimation.refine.CoherentRefiner.in_open_water`)."""

from __future__ import annotations

from hil.estimation.refine import CoherentRefiner

from .conftest import FS, C, att_schedule, echo_samples

HOP_S = 0.01


def _refiner_and_boundary(wall: bool = False) -> tuple[CoherentRefiner, float, float]:
    """A refiner fed 1.5 s of one echo at 50 m closing 8 m/s (+ a 20 dB wall at rest at 30 m
    with ``wall``), and the echo's boundary ending hop 90 (s) and time scale."""
    schedule = att_schedule()
    x = echo_samples(schedule, 50.0, 8.0, 1.5, snr_db=0.0, seed=3)
    if wall:
        x = x + echo_samples(schedule, 30.0, 0.0, 1.5, amplitude=10.0)
    refiner = CoherentRefiner(schedule, FS, 10, C, 0.5, 30.0)
    refiner.push(x, 0)
    t_tx = 91 * HOP_S
    return refiner, t_tx + 2.0 * (50.0 - 8.0 * t_tx) / (C + 8.0), (C + 8.0) / (C - 8.0)


def test_a_fit_not_remembered_leaves_no_echo_behind() -> None:
    refiner, t_rx, alpha = _refiner_and_boundary()
    look = refiner.refine(t_rx, alpha, 90, partners=False, remember=False)
    assert look is not None and look.is_echo(refiner.echo_test)
    assert abs(look.speed_mps(C) - 8.0) < 0.05
    assert refiner.known_echoes(t_rx + 2 * HOP_S) == []
    kept = refiner.refine(t_rx, alpha, 90, partners=False)
    assert kept is not None and (kept.t_s, kept.alpha) == (look.t_s, look.alpha)
    assert len(refiner.known_echoes(t_rx + 2 * HOP_S)) == 1


def test_open_water_is_known_only_where_the_still_water_is_measured_and_weak() -> None:
    refiner, t_rx, alpha = _refiner_and_boundary()
    walled, _, _ = _refiner_and_boundary(wall=True)
    assert refiner.in_open_water(t_rx, alpha)
    assert not walled.in_open_water(t_rx, alpha) and walled.in_still_water(t_rx, alpha)
    # Before the still-water streams cover the window (its first code period): not known.
    assert not refiner.in_open_water(0.12, alpha) and not refiner.in_still_water(0.12, alpha)
