"""Echo synthesis: analytic vs interpolated, Doppler as time scaling, streaming, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import hilbert

from hil.errors import ConfigError
from sim_devices.acoustics.delay import OneWayPath, PathSolution, TwoWayPath, closed_form_monostatic
from sim_devices.acoustics.echo import (
    AnalyticEcho,
    SampledEcho,
    SphericalSpreading,
    TransmitHistory,
    history_capacity,
    sample_times,
    sampled_echo,
)
from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed, Live, Piecewise

FS = 100_000.0  # the `att` preset: f_c = 30 kHz, B_w = 4.4 kHz, 3 tones, T_h = 15 ms
TONES_HZ = 30_000.0 + np.array([-1.0, 0.0, 1.0]) * 4_400.0 / 3


class Tone:
    """s(t) = cos(2π f t + φ), endless."""

    def __init__(self, freq_hz: float, phase: float = 0.0) -> None:
        self.freq_hz, self.phase = freq_hz, phase

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        return np.cos(2 * np.pi * self.freq_hz * np.asarray(t) + self.phase)


class CpFskHops:
    """Endless continuous-phase FSK: hop n (on [n T, (n+1) T)) plays freqs[pattern[n mod P]].

    The phase at each hop start is the running sum of 2π f T over the earlier hops, reduced
    mod 2π, so the waveform is continuous at every boundary (SPEC §2, CP-FSK).
    """

    def __init__(self, freqs_hz: np.ndarray, pattern: list[int], hop_s: float) -> None:
        self.hop_s = hop_s
        self.f = np.asarray(freqs_hz)[pattern]
        step = 2 * np.pi * self.f * hop_s
        self.start = np.mod(np.concatenate(([0.0], np.cumsum(step)[:-1])), 2 * np.pi)
        self.per_period = float(np.mod(np.sum(step), 2 * np.pi))

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        n = np.floor(t / self.hop_s).astype(np.int64)
        q, r = np.divmod(n, self.f.size)
        phase = np.mod(q * self.per_period, 2 * np.pi) + self.start[r]
        return np.cos(phase + 2 * np.pi * self.f[r] * (t - n * self.hop_s))


def _hops() -> CpFskHops:
    # Three-state hopping (never the same tone twice), hop 15 ms.
    return CpFskHops(TONES_HZ, [0, 2, 1, 0, 1, 2, 0, 2], 0.015)


def _error_db(test: np.ndarray, ref: np.ndarray) -> float:
    return float(10 * np.log10(np.sum((test - ref) ** 2) / np.sum(ref**2)))


def test_cp_fsk_test_waveform_is_phase_continuous() -> None:
    hops = _hops()
    edges = np.arange(1, 40) * hops.hop_s
    eps = 1e-9
    jump = hops.evaluate(edges + eps) - hops.evaluate(edges - eps)
    assert np.max(np.abs(jump)) < 2 * 2 * np.pi * TONES_HZ.max() * eps


def test_echo_of_a_stationary_target_is_the_delayed_signal() -> None:
    path = TwoWayPath.monostatic(Fixed((0, 0, 0)), Fixed((0, 45.0, 0)), 1500.0)
    echo = AnalyticEcho(_hops(), path, FS)
    t = sample_times(5000, 3000, FS)
    np.testing.assert_allclose(echo.block(5000, 3000), _hops().evaluate(t - 0.06), atol=1e-9)


@pytest.mark.parametrize("speed_mps", [10.0, -10.0, 25.72])
def test_tone_echo_has_frequency_alpha_f(speed_mps: float) -> None:
    f, fs = 30_000.0, 200_000.0
    sonar = Fixed((0, 0, 0))
    target = ConstantVelocity((100.0, 0, 0), (-speed_mps, 0, 0))
    echo = AnalyticEcho(Tone(f, 0.3), TwoWayPath.monostatic(sonar, target, 1500.0), fs)
    x = echo.block(40_000, 80_000)  # 0.2 s … 0.6 s
    t = sample_times(40_000, 80_000, fs)
    alpha, _ = closed_form_monostatic(100.0, speed_mps, 1500.0)

    # Phase slope of the analytic signal, away from the Hilbert transform's edge effects.
    phase = np.unwrap(np.angle(hilbert(x)))[8000:-8000]
    slope_hz = np.polyfit(t[8000:-8000], phase, 1)[0] / (2 * np.pi)
    assert slope_hz == pytest.approx(alpha * f, abs=0.01)

    # FFT peak with 8x zero padding and parabolic refinement.
    spec = np.abs(np.fft.rfft(x * np.hanning(x.size), 8 * x.size))
    k = int(np.argmax(spec))
    a, b, c = np.log(spec[k - 1 : k + 2])
    peak_hz = (k + 0.5 * (a - c) / (a - 2 * b + c)) * fs / (8 * x.size)
    assert peak_hz == pytest.approx(alpha * f, abs=0.5)
    assert abs(peak_hz - f) > 0.9 * abs(alpha - 1) * f


def _transmit(waveform: CpFskHops | Tone, n: int, fs: float) -> np.ndarray:
    return waveform.evaluate(np.arange(n) / fs)


@pytest.mark.parametrize(
    "target",
    [
        ConstantVelocity((50.0, 5.0, -2.0), (-25.72, 0.0, 0.0)),
        Piecewise([(60, 0, 0), (30, 10, 0), (45, 10, -3)], [20.0, 8.0], t_start_s=0.15),
    ],
    ids=["constant-velocity", "piecewise"],
)
def test_cp_fsk_echo_interpolated_matches_analytic_below_minus_60_db(
    target: ConstantVelocity | Piecewise,
) -> None:
    path = TwoWayPath.monostatic(Fixed((0, 0, 0)), target, 1500.0)
    x = _transmit(_hops(), int(0.7 * FS), FS)
    t = sample_times(10_000, 50_000, FS)  # 0.1 s … 0.6 s: emissions well inside x
    analytic = AnalyticEcho(_hops(), path, FS).at_times(t)
    interpolated = sampled_echo(x, FS, path, t)
    assert _error_db(interpolated, analytic) < -60.0


@pytest.mark.parametrize("freq_per_fs", [0.05, 0.2, 0.3, 0.4])
def test_tone_under_time_varying_delay_interpolated_matches_analytic(freq_per_fs: float) -> None:
    fs = 48_000.0
    swing = Live(
        lambda t: np.stack([20 + 0.5 * np.sin(2 * np.pi * 0.7 * t), 0 * t, 0 * t], axis=-1),
        max_speed_mps=2.3,
    )
    path = TwoWayPath.monostatic(Fixed((0, 0, 0)), swing, 1480.0)
    tone = Tone(freq_per_fs * fs, 1.1)
    x = _transmit(tone, int(1.1 * fs), fs)
    t = sample_times(4_800, 43_200, fs)
    err = _error_db(sampled_echo(x, fs, path, t), AnalyticEcho(tone, path, fs).at_times(t))
    assert err < -60.0


@settings(max_examples=25, deadline=None)
@given(sizes=st.lists(st.integers(0, 700), min_size=1, max_size=12), n0=st.integers(-500, 9000))
def test_analytic_echo_chunks_equal_whole(sizes: list[int], n0: int) -> None:
    target = Piecewise([(60, 0, 0), (30, 10, 0)], [20.0], t_start_s=0.02, hold_at_end=False)
    echo = AnalyticEcho(_hops(), TwoWayPath.monostatic(Fixed((0, 0, 0)), target, 1500.0), FS)
    starts = n0 + np.concatenate(([0], np.cumsum(sizes)[:-1]))
    parts = [echo.block(int(s), n) for s, n in zip(starts, sizes, strict=True)]
    assert np.array_equal(np.concatenate(parts), echo.block(n0, sum(sizes)))


def test_sampled_echo_streamed_through_a_bounded_ring_equals_whole_array() -> None:
    target = ConstantVelocity((50.0, 0.0, 0.0), (-25.72, 0.0, 0.0))
    path = TwoWayPath.monostatic(Fixed((0, 0, 0)), target, 1500.0)
    total = 40_000
    x = _transmit(_hops(), total, FS)
    whole = sampled_echo(x, FS, path, sample_times(0, total, FS), amplitude=0.5)

    rng = np.random.default_rng(2024)
    sizes = rng.integers(1, 1200, size=200)
    sizes = sizes[np.cumsum(sizes) <= total]
    sizes = np.append(sizes, total - sizes.sum())
    # Delays here stay below 0.07 s; blocks are at most 1200 samples.
    capacity = history_capacity(0.07, 1200 / FS, FS)
    history = TransmitHistory(FS, capacity)
    echo = SampledEcho(history, path, FS, amplitude=0.5)
    out, n0 = [], 0
    for n in sizes:
        history.push(x[n0 : n0 + n])  # the transmitter runs up to the end of this block
        out.append(echo.block(n0, int(n)))
        n0 += int(n)
    assert np.array_equal(np.concatenate(out), whole)
    assert history.pushed == total and history.oldest == total - capacity
    assert capacity < total // 4  # memory bounded by the delay, not by the run length


def test_spherical_spreading_and_custom_gain_hook() -> None:
    sonar, target = Fixed((0, 0, 0)), Fixed((0, 0, -20.0))
    path = TwoWayPath.monostatic(sonar, target, 1500.0)
    plain = AnalyticEcho(Tone(1000.0), path, FS)
    spread = AnalyticEcho(Tone(1000.0), path, FS, gain=SphericalSpreading(), amplitude=2.0)
    np.testing.assert_allclose(spread.block(0, 500), 2.0 / 400.0 * plain.block(0, 500), rtol=1e-14)

    def tl_gain(solution: PathSolution) -> np.ndarray:
        r = solution.leg_lengths_m[0] + solution.leg_lengths_m[1]
        return 10 ** (-(20 * np.log10(r) + 0.01 * r) / 20)

    hooked = AnalyticEcho(Tone(1000.0), path, FS, gain=tl_gain)
    expected = 10 ** (-(20 * np.log10(40.0) + 0.4) / 20) * plain.block(0, 500)
    np.testing.assert_allclose(hooked.block(0, 500), expected, rtol=1e-12)


def test_direct_blast_is_the_one_way_delayed_signal() -> None:
    path = OneWayPath(Fixed((0, 0, 0)), Fixed((3.0, 0, 4.0)), 1500.0)
    blast = AnalyticEcho(_hops(), path, FS, gain=SphericalSpreading())
    t = sample_times(100, 400, FS)
    np.testing.assert_allclose(
        blast.block(100, 400), _hops().evaluate(t - 5.0 / 1500) / 5.0, atol=1e-12
    )


def test_bad_rates_and_settings_are_refused() -> None:
    path = TwoWayPath.monostatic(Fixed((0, 0, 0)), Fixed((10, 0, 0)), 1500.0)
    for fs in (0.0, -48000.0):
        with pytest.raises(ConfigError, match=r"fs_hz = -?[0-9.]+ is not allowed: must be > 0 Hz"):
            AnalyticEcho(Tone(1e3), path, fs)
    with pytest.raises(ConfigError, match=r"fs_hz = 0 is not allowed: must be > 0 Hz and finite"):
        TransmitHistory(0, 100)
    with pytest.raises(ConfigError, match=r"fs_tx_hz = -1\.0 is not allowed: must be > 0 Hz"):
        sampled_echo(np.ones(10), -1.0, path, np.array([0.1]))
    with pytest.raises(
        ConfigError, match=r"waveform = 3 is not allowed: must be an object with evaluate"
    ):
        AnalyticEcho(3, path, FS)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"count = -1 is not allowed: must be an integer >= 0"):
        AnalyticEcho(Tone(1e3), path, FS).block(0, -1)
    with pytest.raises(ConfigError, match=r"capacity = 0 is not allowed: must be an integer >= 1"):
        TransmitHistory(FS, 0)
    with pytest.raises(ConfigError, match=r"reference_m = -1\.0 is not allowed: must be > 0 m"):
        SphericalSpreading(-1.0)
    with pytest.raises(ConfigError, match=r"max_delay_s = -0\.1 is not allowed: must be >= 0 s"):
        history_capacity(-0.1, 0.01, FS)


def test_zero_leg_length_is_refused_by_spherical_spreading() -> None:
    on_top = TwoWayPath.monostatic(Fixed((1, 1, 1)), Fixed((1, 1, 1)), 1500.0)
    echo = AnalyticEcho(Tone(1e3), on_top, FS, gain=SphericalSpreading())
    with pytest.raises(
        ConfigError, match=r"leg_lengths_m\[0\] = 0\.0 is not allowed: must be > 0 m"
    ):
        echo.block(0, 4)


def test_ring_refuses_samples_not_pushed_or_overwritten() -> None:
    path = TwoWayPath.monostatic(Fixed((0, 0, 0)), Fixed((15.0, 0, 0)), 1500.0)  # delay 20 ms
    history = TransmitHistory(FS, capacity=500)
    echo = SampledEcho(history, path, FS)
    history.push(np.ones(500))
    # Receive samples 2000 … 2999 need transmit samples -15 … 1015 (32 taps, 2000-sample delay).
    with pytest.raises(
        ConfigError,
        match=r"transmit sample index = 1015 is not allowed: must be < samples pushed so far = 500",
    ):
        echo.block(2000, 1000)
    history.push(np.ones(4500))
    with pytest.raises(
        ConfigError,
        match=r"TransmitHistory\.capacity = 500 is not allowed: must be >= 401[56] samples to "
        r"still hold sample 98[45]; size the ring with history_capacity",
    ):
        echo.block(3000, 10)
