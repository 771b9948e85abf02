"""The channel's fast paths: transmit evaluation, grid-interpolated echoes, batched path solves,
and the reverberation cull, each against its exact reference."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.data import scenario_path
from hil.errors import ConfigError
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule import HopSchedule
from sim_devices.acoustics.beam import PistonBeam, TwoWayAmplitudeTable
from sim_devices.acoustics.channel import Channel, source_amplitude
from sim_devices.acoustics.delay import OneWayPath, TwoWayPath, solve_paths
from sim_devices.acoustics.echo import AnalyticEcho, sample_times
from sim_devices.acoustics.grid_echo import EchoBank, GridEcho, grid_samples_for
from sim_devices.acoustics.reverberation import (
    ReverberationSettings,
    VolumeReverberation,
    scatterer_geometry,
)
from sim_devices.acoustics.scenario import build_channel, load_scenario
from sim_devices.acoustics.tank import Offset
from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed, Live, Piecewise
from sim_devices.acoustics.transmit_eval import FLOAT32_TRANSMIT_ERROR, TransmitEvaluator

ATT = check_design(get_preset("att").spec("random-cyclic"))
BOARD = check_design(get_preset("tank-board").spec("random-cyclic"))
FS_BOARD = 1_000_000.0


def _tank_board_channel() -> Channel:
    return build_channel(load_scenario(scenario_path("tank-board")))


# ------------------------------------------------------------------ transmit evaluation
CHIRP = HopSchedule.from_segments(
    "fmcw", [20_000.0, 20_000.0], [0, 1], [0.004, 0.003], chirp_hz_per_s=[2e6, -1e6]
)
PULSES = HopSchedule.from_segments(
    "cw-pulse", [30_000.0], [0, -1], [0.001, 0.004], amplitude=[0.5, 0.0],
    continuous_phase=False, t0_s=0.0123,
)  # fmt: skip


@pytest.mark.parametrize(
    "schedule", [ATT, BOARD, CHIRP, PULSES], ids=["att", "board", "chirp", "pulses"]
)
def test_transmit_evaluator_matches_the_exact_evaluation(schedule: HopSchedule) -> None:
    rng = np.random.default_rng(11)
    t = np.sort(rng.uniform(-0.3, 2.0 * schedule.period_s + 0.1, 40_000))
    fast = TransmitEvaluator(schedule).at_sorted_times(t)
    exact = schedule.evaluate(t)
    assert fast.dtype == np.float32
    err = np.abs(fast - exact)
    # Samples within float rounding of a hop start may go to either hop; none here.
    assert np.max(err) <= FLOAT32_TRANSMIT_ERROR * np.max(schedule.amplitude)


@settings(max_examples=40, deadline=None)
@given(
    start=st.floats(-100.0, 1e4, allow_nan=False),
    step=st.floats(1e-7, 2e-3),
    n=st.integers(0, 3000),
)
def test_transmit_evaluator_property(start: float, step: float, n: int) -> None:
    t = np.asarray(start + step * np.arange(n), dtype=np.float64)
    fast = TransmitEvaluator(BOARD).at_sorted_times(t)
    # float32 phase resolution plus the rounding of t itself (ulp(t) × 2π f)
    tol = FLOAT32_TRANSMIT_ERROR + 2 * np.pi * 160e3 * 4 * np.spacing(abs(start) + step * n)
    assert fast.shape == (n,)
    if n:
        assert np.max(np.abs(fast - BOARD.evaluate(t))) <= tol


def test_transmit_evaluator_falls_back_to_evaluate_for_other_waveforms() -> None:
    class Tone:
        def evaluate(self, t: np.ndarray) -> np.ndarray:
            return np.cos(2 * np.pi * 1000.0 * t)

    t = np.linspace(0.0, 0.01, 101)
    out = TransmitEvaluator(Tone()).at_sorted_times(t)
    assert out.dtype == np.float64 and np.array_equal(out, Tone().evaluate(t))


# ------------------------------------------------------------------ grid echo
def test_grid_samples_are_powers_of_two_near_the_grid_time() -> None:
    assert [grid_samples_for(fs) for fs in (1e6, 100e3, 192e3, 8e3)] == [4096, 512, 1024, 32]
    assert grid_samples_for(100.0, 1e-3) == 4


def test_grid_delay_error_is_below_the_bound_through_the_tow_corners() -> None:
    """Tank-board's target starts, stops (3 s) and turns back (3.5 s): every path's
    interpolated delay is within 1e-11 s of the exact solve, corners included."""
    ch = _tank_board_channel()
    starts = [0, 1_500_000, 2_996_000, 3_497_000]
    worst, exact_intervals = 0.0, 0
    for e in ch._echoes:
        for n0 in starts:
            d, g = e.delay_and_gain(n0, 12_000)
            sol = e.path.solve(sample_times(n0, 12_000, FS_BOARD))
            worst = max(worst, float(np.max(np.abs(d - sol.delay_s))))
            assert np.max(np.abs(g / e.gain(sol) - 1.0)) < 1e-6
        exact_intervals += e.exact_intervals
    assert worst < 1e-11
    assert exact_intervals > 0  # the corners were caught and solved per sample


def test_grid_echo_is_smooth_without_corners() -> None:
    path = TwoWayPath.monostatic(
        Fixed((0.5, 2.0, -1.0)), ConstantVelocity((6.0, 2.3, -1.2), (-2.0, 0.3, 0.0)), 1480.0
    )
    echo = GridEcho(BOARD, path, FS_BOARD, t_start_s=0.25)
    d, _ = echo.delay_and_gain(10_000, 200_000)
    exact = path.solve(sample_times(10_000, 200_000, FS_BOARD, 0.25)).delay_s
    assert np.max(np.abs(d - exact)) < 1e-13
    assert echo.exact_intervals == 0


@pytest.mark.slow
def test_grid_echo_follows_a_live_trajectory_with_acceleration_steps() -> None:
    """Constant-acceleration pieces (as the simulated stage moves): α has kinks in slope."""

    def pos(t: np.ndarray) -> np.ndarray:
        # accelerate 0.5 m/s² for 0.2 s, cruise, decelerate from 0.6 s
        x = np.where(t < 0.2, 0.25 * t**2, 0.01 + 0.1 * (t - 0.2))
        x = np.where(t > 0.6, 0.05 + 0.1 * (t - 0.6) - 0.25 * (t - 0.6) ** 2, x)
        return np.stack([4.0 + x, 0 * t + 2.0, 0 * t - 1.0], axis=-1)

    sonar = Fixed((0.5, 2.0, -1.0))
    path = TwoWayPath.monostatic(sonar, Live(pos, max_speed_mps=1.0), 1480.0)
    echo = GridEcho(BOARD, path, FS_BOARD, grid_samples=16384)
    d, _ = echo.delay_and_gain(0, 800_000)
    exact = path.solve(sample_times(0, 800_000, FS_BOARD)).delay_s
    assert np.max(np.abs(d - exact)) < 1e-11


def test_grid_echo_matches_the_analytic_echo() -> None:
    ch = _tank_board_channel()
    for e in ch._echoes[::3]:
        exact = AnalyticEcho(e.waveform, e.path, FS_BOARD, amplitude=e.amplitude, gain=e.gain)
        fast = e.block(2_000_000, 30_000)
        ref = exact.block(2_000_000, 30_000)
        # float32 transmit (3e-7) and the gain tolerance (1e-6), relative to the peak
        assert np.max(np.abs(fast - ref)) <= 1.3e-6 * np.max(np.abs(ref))


@settings(max_examples=15, deadline=None)
@given(st.lists(st.integers(0, 30_000), min_size=1, max_size=6))
def test_grid_echo_any_chunking_gives_the_same_samples(cuts: list[int]) -> None:
    target = Piecewise([(3.0, 2.0, -1.0), (3.02, 2.0, -1.0), (3.0, 2.1, -1.0)], [2.0, 1.0])
    path = TwoWayPath.monostatic(Fixed((0.5, 2.0, -1.0)), target, 1480.0)
    whole = GridEcho(BOARD, path, FS_BOARD, prefetch_intervals=2).block(1000, sum(cuts))
    echo = GridEcho(BOARD, path, FS_BOARD, prefetch_intervals=2)
    parts, n0 = [], 1000
    for c in cuts:
        parts.append(echo.block(n0, c))
        n0 += c
    assert np.array_equal(np.concatenate(parts), whole)


def test_echo_bank_is_the_sum_of_its_echoes() -> None:
    ch = _tank_board_channel()
    bank = EchoBank(ch._echoes).block(123_456, 40_000)
    expected = np.zeros(40_000)
    fresh = _tank_board_channel()._echoes
    for e in fresh:
        expected += e.block(123_456, 40_000)
    assert np.array_equal(bank, expected)


def test_tank_channel_chunks_equal_whole() -> None:
    whole = _tank_board_channel().read_components(50_000)
    ch = _tank_board_channel()
    parts = [ch.read_components(k) for k in (1, 4095, 17, 20_000, 25_887)]
    for key in ("echo", "received"):
        assert np.array_equal(np.concatenate([p[key] for p in parts]), whole[key])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"grid_samples": 1000}, r"grid_samples = 1000 is not allowed: must be a power of two"),
        ({"grid_samples": 2}, r"grid_samples = 2 .*power of two >= 4"),
        ({"tolerance_s": 0.0}, r"tolerance_s = 0.0 .*> 0 s"),
        ({"gain_tolerance": -1.0}, r"gain_tolerance = -1.0 .*> 0"),
        ({"prefetch_intervals": 0}, r"prefetch_intervals = 0 .*integer >= 1"),
    ],
)
def test_grid_echo_refuses_bad_settings(kwargs: dict, message: str) -> None:
    path = TwoWayPath.monostatic(Fixed((0, 0, 0)), Fixed((3.0, 0, 0)), 1480.0)
    with pytest.raises(ConfigError, match=message):
        GridEcho(BOARD, path, FS_BOARD, **kwargs)


def test_echo_bank_refuses_echoes_on_different_grids() -> None:
    path = TwoWayPath.monostatic(Fixed((0, 0, 0)), Fixed((3.0, 0, 0)), 1480.0)
    a = GridEcho(BOARD, path, FS_BOARD)
    b = GridEcho(BOARD, path, FS_BOARD, grid_samples=1024)
    with pytest.raises(ConfigError, match=r"EchoBank echoes = 'different grids'"):
        EchoBank([a, b])


# ------------------------------------------------------------------ batched solve
def test_solve_paths_equals_solving_each_path() -> None:
    ch = _tank_board_channel()
    sonar = ch.sonar
    blast = OneWayPath(Offset(sonar, (0, 0, 0.1)), sonar, 1480.0)
    blast2 = OneWayPath(Offset(sonar, (0, 0.2, 0)), sonar, 1480.0)
    other_c = TwoWayPath.monostatic(sonar, Fixed((5.0, 1.0, -1.0)), 1500.0)
    paths = [e.path for e in ch._echoes] + [blast, other_c, blast2]
    t = np.linspace(2.9, 3.6, 301)
    together = solve_paths(paths, t)
    for path, sol in zip(paths, together, strict=True):
        ref = path.solve(t)
        for a, b in [
            (sol.t_emit_s, ref.t_emit_s), (sol.delay_s, ref.delay_s), (sol.alpha, ref.alpha),
            *zip(sol.leg_lengths_m, ref.leg_lengths_m, strict=True),
        ]:  # fmt: skip
            assert np.array_equal(a, b)
        assert (sol.t_bounce_s is None) == (ref.t_bounce_s is None)
        if ref.t_bounce_s is not None and sol.t_bounce_s is not None:
            assert np.array_equal(sol.t_bounce_s, ref.t_bounce_s)


# ------------------------------------------------------------------ reverberation cull
def test_cull_keeps_every_scatterer_in_the_shell_and_cone() -> None:
    """The (coarse, then fine) cull is conservative: at many times across several cull spans,
    the synthesised set equals a brute-force selection from the whole neighbourhood."""
    beam = PistonBeam(ka=8.0)
    table = TwoWayAmplitudeTable(beam, beam)
    st_ = ReverberationSettings(0.05, -70.0, 20.0, 2.0, seed=4)
    rev = VolumeReverberation(
        ATT, 100_000.0, source_amplitude_upa=source_amplitude(200.0), reference_hz=30e3,
        sonar_position_m=(0.0, 0.0, -30.0), sonar_velocity_mps=(4.0, 1.0, 0.0), beam=table,
        beam_axis=(1.0, 0.3, 0.0), sound_speed_mps=1500.0, settings=st_,
    )  # fmt: skip
    for t in np.linspace(0.0, 3.0, 41):
        x, y, z = rev.scatterers_at(float(t))
        centre = rev.sonar_position(float(t))
        bx, by, bz = rev.field.near(centre, 25.0, rev.axis, -1.0, 0.0)
        g = scatterer_geometry(float(t), bx, by, bz, rev.p0, rev.v, rev.axis, rev.c)
        inside = (g.r_back_m >= 2.0) & (g.r_back_m <= 20.0) & (g.cos_theta >= rev.cos_cut)
        assert x.size == int(np.count_nonzero(inside)) > 50
        assert set(zip(x.tolist(), y.tolist(), z.tolist(), strict=True)) == set(
            zip(bx[inside].tolist(), by[inside].tolist(), bz[inside].tolist(), strict=True)
        )


@pytest.mark.parametrize(("speed", "bound_db"), [(0.0, -30.0), (10.0, -22.5)])
def test_reverberation_error_stays_at_its_documented_level(speed: float, bound_db: float) -> None:
    """The fast paths keep the cell synthesis's error (−30.5 dB still, −22.9 dB moving)."""
    from sim_devices.acoustics.beam import OmniBeam
    from sim_devices.acoustics.reverberation import exact_reverberation

    st_ = ReverberationSettings(
        density_per_m3=0.002, scattering_strength_db=-60.0, max_range_m=14.0, min_range_m=2.0,
        seed=5, frame_samples=2048,
    )  # fmt: skip
    omni = TwoWayAmplitudeTable(OmniBeam(), OmniBeam())
    rev = VolumeReverberation(
        ATT, 100_000.0, source_amplitude_upa=source_amplitude(200.0), reference_hz=30e3,
        sonar_position_m=(0.0, 0.0, -50.0), sonar_velocity_mps=(speed, 0.0, 0.0), beam=omni,
        beam_axis=(1.0, 0.0, 0.0), sound_speed_mps=1500.0, settings=st_,
    )  # fmt: skip
    approx = rev.generate(6000)
    x, y, z = rev.scatterers_at(0.03)
    exact = exact_reverberation(rev, x, y, z, np.arange(6000) / 100_000.0)
    assert 10 * np.log10(np.sum((approx - exact) ** 2) / np.sum(exact**2)) < bound_db


def test_scatterer_field_keeps_only_the_cubes_in_use() -> None:
    beam = PistonBeam(ka=8.0)
    st_ = ReverberationSettings(0.02, -70.0, 12.0, 1.0, seed=2, frame_samples=4096)
    rev = VolumeReverberation(
        ATT, 100_000.0, source_amplitude_upa=1.0, reference_hz=30e3,
        sonar_position_m=(0.0, 0.0, -30.0), sonar_velocity_mps=(8.0, 0.0, 0.0),
        beam=TwoWayAmplitudeTable(beam, beam), beam_axis=(1.0, 0.0, 0.0),
        sound_speed_mps=1500.0, settings=st_,
    )  # fmt: skip
    sizes = []
    for _ in range(20):
        rev.generate(20_000)  # 0.2 s: the sonar crosses a cube (3 m) every ~0.4 s
        sizes.append(len(rev.field._cache))
        assert len(rev.field._cache) == len(rev.field._set_key)
    assert max(sizes) <= 1.05 * min(sizes)  # level: only the cube grid moves past
