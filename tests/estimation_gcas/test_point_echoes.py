"""PointEchoes: which detections a point echo confirmed lately in the still reverberation's
cells predicts (hil.estimation.gcas.point_echoes)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil.estimation.gcas.point_echoes import CONFIRM_PERIODS, PointEchoes

C = 1500.0
HOP_S = 0.01
PERIOD = 17
LOBE_S = 1.0 / 3300.0  # att's tones span 3.3 kHz
CELL = 0.265  # att's M = 10 Doppler resolution, m/s


def _alpha(speed: float) -> float:
    return (C + speed) / (C - speed)


def _echoes() -> PointEchoes:
    return PointEchoes(HOP_S, PERIOD, LOBE_S, CELL, C)


@given(
    speed=st.floats(-2.5, 2.5),
    hops=st.integers(0, CONFIRM_PERIODS * PERIOD),
    t0=st.floats(0.05, 10.0),
)
def test_a_confirmed_echo_predicts_its_own_later_boundaries(
    speed: float, hops: int, t0: float
) -> None:
    echoes = _echoes()
    a = _alpha(speed)
    echoes.note(100, t0, a, 0.3)
    assert echoes.predicts(100 + hops, t0 + hops * HOP_S / a, a)


def test_it_is_forgotten_after_two_code_periods() -> None:
    echoes = _echoes()
    echoes.note(100, 1.0, 1.0, 0.3)
    late = 100 + CONFIRM_PERIODS * PERIOD
    assert echoes.predicts(late, 1.0 + (late - 100) * HOP_S, 1.0)
    assert not echoes.predicts(late + 1, 1.0 + (late + 1 - 100) * HOP_S, 1.0)


@pytest.mark.parametrize(
    ("dt_s", "dv_mps", "predicted"),
    # One main lobe (1/B = 0.30 ms, 0.23 m of range) and two Doppler cells (0.53 m/s) away
    # at most; a grating lobe (1/1100 Hz, 0.68 m) or a moving echo's speed is another echo.
    [(0.0, 0.0, True), (2.9e-4, 0.0, True), (3.2e-4, 0.0, False), (-3.2e-4, 0.0, False),
     (1 / 1100, 0.0, False), (0.0, 0.5, True), (0.0, -0.55, False), (0.0, 3.0, False)],
)  # fmt: skip
def test_only_the_same_echo_is_predicted(dt_s: float, dv_mps: float, predicted: bool) -> None:
    echoes = _echoes()
    echoes.note(40, 0.5, 1.0, 0.3)
    a = _alpha(dv_mps)
    assert echoes.predicts(41, 0.5 + HOP_S + dt_s, a) is predicted


def test_a_detection_before_the_confirmation_is_not_predicted() -> None:
    echoes = _echoes()
    echoes.note(40, 0.5, 1.0, 0.3)
    assert not echoes.predicts(39, 0.49, 1.0)


def test_a_new_note_replaces_the_same_echos_and_reset_forgets() -> None:
    echoes = _echoes()
    echoes.note(40, 0.5, 1.0, 0.3)
    echoes.note(60, 0.7, 1.0, 0.3)  # the same echo, 20 hops on: its window restarts there
    late = 60 + CONFIRM_PERIODS * PERIOD
    assert echoes.predicts(late, 0.7 + (late - 60) * HOP_S, 1.0)
    echoes.note(45, 2.0, 1.0, 0.3)  # another echo, kept beside it
    assert echoes.predicts(46, 2.01, 1.0) and echoes.predicts(61, 0.71, 1.0)
    echoes.reset()
    assert not echoes.predicts(61, 0.71, 1.0) and not echoes.predicts(46, 2.01, 1.0)


def _field(
    echoes: PointEchoes, ranges_m: list[float], amplitude: float, speed: float = 0.0
) -> None:
    """Still (or ``speed``) echoes confirmed at hop 50 at ``ranges_m`` (transmit at 0)."""
    for r in ranges_m:
        echoes.note(50, 2.0 * r / C, _alpha(speed), amplitude)


@pytest.mark.parametrize(
    ("others_m", "amplitude", "crowded"),
    # Around a still echo at 7.0 m of amplitude 0.3: two others within 5 m make a field;
    # one, or others beyond 5 m, do not; twice the field's median stands out of it.
    [([5.8, 7.9], 0.3, True), ([7.9], 0.3, False), ([1.9, 12.1], 0.3, False),
     ([2.1, 11.9], 0.3, True), ([5.8, 7.9, 9.3], 0.59, True), ([5.8, 7.9, 9.3], 0.61, False),
     ([7.05, 7.9], 0.3, False)],  # 7.05 m is within its own main lobe: itself
)  # fmt: skip
def test_a_still_echo_in_a_field_of_still_echoes_is_crowded(
    others_m: list[float], amplitude: float, crowded: bool
) -> None:
    echoes = _echoes()
    _field(echoes, others_m, 0.3)
    assert echoes.crowded(52, 2.0 * 7.0 / C + 2 * HOP_S, 1.0, amplitude) is crowded


def test_moving_echoes_make_no_field_and_a_moving_echo_is_never_crowded() -> None:
    echoes = _echoes()
    _field(echoes, [5.8, 7.9], 0.3, speed=2.0)
    assert not echoes.crowded(50, 2.0 * 7.0 / C, 1.0, 0.3)
    _field(echoes, [6.0, 8.1], 0.3)
    assert echoes.crowded(50, 2.0 * 7.0 / C, 1.0, 0.3)
    assert not echoes.crowded(50, 2.0 * 7.0 / C, _alpha(2.0), 0.3)
