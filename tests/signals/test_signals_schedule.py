"""HopSchedule: construction, periodic extension, evaluation, serialisation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.signals.schedule import TWO_PI, HopSchedule, tone_grid


def _demo() -> HopSchedule:
    return HopSchedule.from_segments("demo", [1000.0, 1500.0, 2250.0], [0, 2, 1], 0.002)


def test_tone_grid_golden() -> None:
    assert tone_grid(30000.0, 4400.0, 4).tolist() == [28350.0, 29450.0, 30550.0, 31650.0]
    np.testing.assert_allclose(tone_grid(30000.0, 4400.0, 3), [28533.3333333, 30000, 31466.6666667])


def test_continuous_phase_rule() -> None:
    s = _demo()
    # φ1 = 2π·1000·0.002 = 4π ≡ 0; φ2 = φ1 + 2π·2250·0.002 = 9π ≡ π.
    np.testing.assert_allclose(s.phase_rad, [0.0, 0.0, math.pi], atol=1e-12)
    # Period advance: 4π + 9π + 6π = 19π ≡ π (mod 2π).
    assert s.period_phase_rad == pytest.approx(math.pi, abs=1e-9)
    assert s.hops(3, 1).phase_rad[0] == pytest.approx(math.pi, abs=1e-9)
    assert s.period_s == pytest.approx(0.006)


def test_periodic_extension_matches_direct_construction() -> None:
    # Three periods built explicitly equal the periodic extension of one period.
    one = HopSchedule.from_segments("x", [1000.0, 1234.5], [0, 1], [0.0013, 0.0021])
    three = HopSchedule.from_segments("x", [1000.0, 1234.5], [0, 1] * 3, [0.0013, 0.0021] * 3)
    ext = one.hops(0, 6)
    np.testing.assert_allclose(ext.start_s, three.start_s, atol=1e-15)
    np.testing.assert_allclose(np.unwrap(ext.phase_rad), np.unwrap(three.phase_rad), atol=1e-9)
    t = np.linspace(0, three.period_s, 2001, endpoint=False)
    np.testing.assert_allclose(one.evaluate(t), three.evaluate(t), atol=1e-9)


def test_negative_hops_and_t0() -> None:
    s = _demo().shifted(1.0)
    h = s.hops(-1, 2)
    assert h.index.tolist() == [-1, 0]
    assert h.start_s.tolist() == pytest.approx([0.998, 1.0])
    assert h.tone_index.tolist() == [1, 0]
    assert s.locate([0.9985, 1.0, 1.0019999, 1.002]).tolist() == [-1, 0, 0, 1]


def test_evaluate_golden_values() -> None:
    s = HopSchedule.from_segments("demo", [1000.0, 2000.0], [0, 1], 0.001)
    np.testing.assert_allclose(
        s.evaluate([0.0, 0.00025, 0.0005, 0.001, 0.00125, 0.0015]), [1, 0, -1, 1, -1, 1], atol=1e-12
    )
    np.testing.assert_allclose(np.real(s.evaluate_analytic([0.0003])), s.evaluate([0.0003]))


def test_silent_gaps_and_pulsed_phase() -> None:
    s = HopSchedule.from_segments("p", [1000.0], [0, -1], [0.001, 0.004], continuous_phase=False)
    assert s.amplitude.tolist() == [1.0, 0.0]
    assert s.evaluate([0.0015, 0.0049]).tolist() == [0.0, 0.0]
    # Every pulse starts at phase 0.
    assert s.evaluate([0.0, 0.005, 0.010]).tolist() == pytest.approx([1.0, 1.0, 1.0])


def test_chirp_instantaneous_frequency() -> None:
    s = HopSchedule.from_segments("c", [1000.0], [0], 0.01, chirp_hz_per_s=[1e5])
    t = np.linspace(0.001, 0.009, 9)
    dt = 1e-7
    f_inst = (s.instantaneous_phase(t + dt) - s.instantaneous_phase(t - dt)) / (2 * dt) / TWO_PI
    np.testing.assert_allclose(f_inst, 1000.0 + 1e5 * t, rtol=1e-6)


def test_period_dict_round_trip() -> None:
    s = HopSchedule.from_segments("x", [1000.0, 1500.0], [1, 0, 1], [0.001, 0.002, 0.003], t0_s=0.5)
    back = HopSchedule.from_period_dict(s.period_dict())
    t = np.linspace(0.4, 0.7, 777)
    np.testing.assert_array_equal(back.evaluate(t), s.evaluate(t))
    assert back.family == "x" and back.t0_s == 0.5


@pytest.mark.parametrize(
    ("kwargs", "field", "fragment"),
    [
        ({"duration_s": -0.001}, "duration_s", "> 0 s"),
        ({"duration_s": 0.0}, "duration_s", "> 0 s"),
        ({"code": [0, 3]}, "code", "tone indices in 0..1"),
        ({"code": []}, "code", "at least one hop"),
        ({"tones_hz": [1000.0, float("nan")]}, "tones_hz", "finite"),
    ],
)
def test_bad_segments_are_refused(kwargs: dict, field: str, fragment: str) -> None:
    args = {"family": "x", "tones_hz": [1000.0, 2000.0], "code": [0, 1], "duration_s": 0.001}
    args.update(kwargs)
    with pytest.raises(ConfigError) as info:
        HopSchedule.from_segments(**args)
    assert info.value.field == field
    assert fragment in str(info.value)


def test_bad_period_dict() -> None:
    d = _demo().period_dict()
    d["start_s"] = [0.0, 0.003, 0.004]
    with pytest.raises(ConfigError, match="contiguous hops"):
        HopSchedule.from_period_dict(d)
    del d["code"]
    with pytest.raises(ConfigError, match=r"missing \['code'\]"):
        HopSchedule.from_period_dict(d)


def test_hop_s_needs_equal_hops() -> None:
    s = HopSchedule.from_segments("p", [1000.0], [0, -1], [0.001, 0.004])
    with pytest.raises(ConfigError, match="equal hop durations"):
        _ = s.hop_s
    assert _demo().hop_s == 0.002


def test_tone_grid_bad_input() -> None:
    with pytest.raises(ConfigError, match="n_tones = 0"):
        tone_grid(1000.0, 100.0, 0)
    with pytest.raises(ConfigError, match="bandwidth_hz"):
        tone_grid(1000.0, -1.0, 3)
    with pytest.raises(ConfigError, match="every tone is > 0 Hz"):
        tone_grid(1000.0, 5000.0, 3)


durations = st.lists(st.floats(1e-4, 1e-2), min_size=1, max_size=12)


@settings(max_examples=60, deadline=None)
@given(durations, st.integers(-50, 50), st.integers(1, 40), st.floats(0.0, 10.0))
def test_schedule_invariants(durs: list[float], first: int, count: int, t0: float) -> None:
    n = len(durs)
    code = [i % 3 for i in range(n)]
    s = HopSchedule.from_segments("h", [1100.0, 2300.0, 3700.0], code, durs, t0_s=t0)
    h = s.hops(first, count)
    # Contiguous, ordered hops whose phases follow the continuous-phase rule.
    np.testing.assert_allclose(h.start_s[1:], h.start_s[:-1] + h.duration_s[:-1], rtol=0, atol=1e-9)
    expected = np.mod(h.phase_rad[:-1] + TWO_PI * h.freq_hz[:-1] * h.duration_s[:-1], TWO_PI)
    diff = np.angle(np.exp(1j * (h.phase_rad[1:] - expected)))
    np.testing.assert_allclose(diff, 0.0, atol=1e-6)
    # Every hop's midpoint is located in that hop; the signal is continuous across boundaries.
    mid = h.start_s + h.duration_s / 2
    assert s.locate(mid).tolist() == h.index.tolist()
    eps = 1e-9
    left = s.evaluate(h.start_s[1:] - eps)
    right = s.evaluate(h.start_s[1:] + eps)
    np.testing.assert_allclose(left, right, atol=1e-4)


def test_derived_values_are_made_once_and_kept_with_the_schedule() -> None:
    """``derived`` makes a value on the first call with its key and returns the kept one
    after (``make`` not called again); another key makes its own. A pickle, a copy and
    :meth:`shifted` keep none of them (each makes its own again), and the original keeps
    its own after being pickled."""
    import copy
    import pickle

    s = HopSchedule.from_segments("demo", [1000.0, 2000.0], [0, 1, -1], 0.001)
    calls: list[str] = []

    def make(tag: str) -> list[str]:
        calls.append(tag)
        return [tag]

    first = s.derived(("k", 1), lambda: make("a"))
    assert s.derived(("k", 1), lambda: make("b")) is first
    assert s.derived(("k", 2), lambda: make("c")) == ["c"]
    assert calls == ["a", "c"]
    for other in (pickle.loads(pickle.dumps(s)), copy.copy(s), copy.deepcopy(s), s.shifted(0.5)):
        assert other.derived(("k", 1), lambda: make("d")) == ["d"]
        assert np.array_equal(other.phase_rad, s.phase_rad)
        assert other.period_phase_rad == s.period_phase_rad
    assert calls == ["a", "c", "d", "d", "d", "d"]
    assert s.derived(("k", 1), lambda: make("e")) is first
