"""The DAC-driven acoustic world: echoes of what the DAC emits, causal, chunk-invariant,
usable behind the simulated board and the simulated audio interface."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import hilbert, resample
from scipy.special import j1

from hil.devices.audio.latency import measure_loopback_latency
from hil.devices.audio.playrec import play_record
from hil.devices.audio.settings import AudioSettings
from hil.devices.audio.simulated import SimulatedDuplex
from hil.errors import ConfigError
from hil.signals.presets import check_design, get_preset
from hil.signals.synthesis import BlockSynthesizer
from sim_devices.acoustics.beam import PistonBeam
from sim_devices.acoustics.channel import Channel, DirectBlast, Receiver, Target
from sim_devices.acoustics.dac_world import AcousticWorld, InPlaceWorld, StreamConvolver
from sim_devices.acoustics.directivity import Transducer
from sim_devices.acoustics.tank import Tank
from sim_devices.acoustics.tank_response import KERNEL_HALF, TankEchoSettings
from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed, Live

FS = 192_000.0
C = 1482.3
SONAR = Fixed([0.5, 1.0, -1.0])
RX = Receiver(sensitivity_db=-190.0, gain_db=20.0, full_scale_v=1.0)


def _world(targets: list[Target], **kw: object) -> AcousticWorld:
    return AcousticWorld(
        FS, SONAR, targets, sound_speed_mps=C, source_level_db=180.0, receiver=RX,
        max_range_m=10.0, **kw,  # type: ignore[arg-type]
    )  # fmt: skip


def _schedule():  # type: ignore[no-untyped-def]
    return check_design(get_preset("tank-audio").spec("random-cyclic"))


def test_echo_of_played_schedule_matches_the_analytic_channel() -> None:
    sch = _schedule()
    target = Target(ConstantVelocity([4.0, 1.0, -1.0], [-1.2, 0.0, 0.0]), -10.0)
    world = _world([target])
    n = int(0.3 * FS)
    dac = BlockSynthesizer(sch, FS).read(n)
    adc = np.concatenate([world(dac[i : i + 4096], i) for i in range(0, n, 4096)])
    channel = Channel(sch, FS, SONAR, 180.0, C, targets=[target], receiver=RX)
    ref = channel.read(n)
    d = world.converter_delay
    got, want = adc[d:, 0], ref[: n - d]
    # Skip the first 20 ms (before the first echo arrives the DAC history is silence, while the
    # analytic channel assumes an endless transmission) and compare the rest.
    start = int(0.02 * FS)
    err = np.sum((got[start:] - want[start:]) ** 2) / np.sum(want[start:] ** 2)
    assert 10 * np.log10(err) < -55.0


@settings(max_examples=15, deadline=None)
@given(st.lists(st.integers(1, 3000), min_size=1, max_size=6))
def test_any_block_split_gives_the_same_adc_samples(cuts: list[int]) -> None:
    sch = _schedule()
    target = Target(Fixed([3.0, 1.0, -1.0]), 0.0)
    total = sum(cuts)
    dac = BlockSynthesizer(sch, FS).read(total)
    whole = _world([target], direct_blast=DirectBlast(-20.0, 0.05))(dac, 0)
    world = _world([target], direct_blast=DirectBlast(-20.0, 0.05))
    parts, first = [], 0
    for c in cuts:
        parts.append(world(dac[first : first + c], first))
        first += c
    np.testing.assert_array_equal(np.concatenate(parts), whole)


def test_live_target_equals_the_same_motion_given_analytically() -> None:
    sch = _schedule()
    p0, v = np.array([5.0, 1.0, -1.0]), np.array([-1.5, 0.0, 0.0])
    live = Live(lambda t: p0 + np.multiply.outer(t, v), max_speed_mps=2.0)
    n = int(0.1 * FS)
    dac = BlockSynthesizer(sch, FS).read(n)
    a = _world([Target(live, 0.0)])(dac, 0)
    b = _world([Target(ConstantVelocity(p0, v), 0.0)])(dac, 0)
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_monitor_channel_and_audio_loopback_latency() -> None:
    """Through the simulated audio interface: the DAC monitor channel measures the latency
    (I/O delay + converter delay) exactly, and the hydrophone hears the target 2R/c later."""
    world = _world([Target(Fixed([3.0, 1.0, -1.0]), 20.0)], adc_channels=2)
    settings_ = AudioSettings(samplerate=FS, blocksize=256, channels_in=2, channels_out=1)
    backend = SimulatedDuplex(settings_, InPlaceWorld(world))
    res = measure_loopback_latency(backend, input_channels=[1])
    assert res.latencies[0].samples == 2 * 256 + world.converter_delay
    # The echo on the hydrophone channel: a chirp played once comes back 2R/c later.
    chirp = np.zeros(int(0.05 * FS), dtype=np.float32)
    t = np.arange(2048) / FS
    chirp[:2048] = 0.5 * np.sin(2 * np.pi * (55_000 * t + 0.5 * 5e6 * t * t))
    fresh = _world([Target(Fixed([3.0, 1.0, -1.0]), 20.0)], adc_channels=2)
    rec = play_record(SimulatedDuplex(settings_, InPlaceWorld(fresh)), chirp)
    hydro = rec.recording[:, 0].astype(float)
    # Envelope of the correlation (a real band-pass correlation ripples at the carrier), read
    # off a 16x band-limited interpolation so the peak position is not biased by a fit.
    xc = hilbert(np.correlate(hydro, chirp[:2048].astype(float), mode="valid"))
    k = int(np.argmax(np.abs(xc)))
    fine = np.abs(resample(xc[k - 64 : k + 64], 128 * 16))
    lag = k - 64 + int(np.argmax(fine)) / 16
    expected = 2 * 256 + world.converter_delay + 2 * 2.5 / C * FS
    assert lag == pytest.approx(expected, abs=0.3)


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"converter_delay_samples": 8}, "converter_delay_samples = 8"),
        ({"adc_channels": 0}, "adc_channels = 0"),
        ({"max_block_samples": 0}, "max_block_samples = 0"),
    ],
)
def test_bad_settings(kwargs: dict, fragment: str) -> None:
    with pytest.raises(ConfigError, match=fragment):
        _world([], **kwargs)


def test_blocks_must_arrive_in_order_and_fit() -> None:
    world = _world([], max_block_samples=100)
    world(np.zeros(50), 0)
    with pytest.raises(ConfigError, match="first_sample = 70 is not allowed: must be 50"):
        world(np.zeros(10), 70)
    with pytest.raises(ConfigError, match="max_block_samples = 100"):
        world(np.zeros(101), 50)
    world.reset()
    assert world(np.zeros(10), 1_000_000).shape == (10, 1)  # a new stream starts anywhere


def test_stream_starting_at_any_index_gives_the_same_samples() -> None:
    sch = _schedule()
    target = Target(Fixed([3.0, 1.0, -1.0]), 0.0)
    dac = BlockSynthesizer(sch, FS).read(5000)
    a = _world([target], adc_channels=2)(dac, 0)
    b = _world([target], adc_channels=2)(dac, 7_654_321)
    # Same physics; only the float rounding of absolute sample times differs.
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-12)


def test_the_sampled_world_applies_the_projector_and_hydrophone_directivity() -> None:
    piston = Transducer(PistonBeam(ka=4.0), (1.0, 0.0, 0.0))
    dac = 0.5 * np.cos(2 * np.pi * 60e3 * np.arange(8192) / FS)
    on_axis = [Target(Fixed([4.5, 1.0, -1.0]), 0.0)]
    off_axis = [Target(Fixed([0.5 + 4.0 * np.cos(0.6), 1.0 + 4.0 * np.sin(0.6), -1.0]), 0.0)]
    responses = {}
    for name, targets in (("on", on_axis), ("off", off_axis)):
        omni = _world(targets)(dac, 0)[:, 0]
        beamed = _world(targets, tx_beam=piston, rx_beam=piston)(dac, 0)[:, 0]
        responses[name] = float(np.max(np.abs(beamed)) / np.max(np.abs(omni)))
    # on the axis unchanged; 0.6 rad off it the two-way response of the piston, (2 J1(x)/x)²
    x = 4.0 * np.sin(0.6)
    assert responses["on"] == pytest.approx(1.0, abs=1e-12)
    assert responses["off"] == pytest.approx((2 * j1(x) / x) ** 2, rel=1e-3)


TANK = Tank(12.0, 4.0, 2.5, wall_reflection=0.8, bottom_reflection=0.7)
#: Own echoes of two reflections and a 20 ms stretch of the late tail (a short response).
OWN = TankEchoSettings(order=2, tail=True, tail_s=0.02, seed=3)


def test_the_audio_interfaces_sampled_world_has_the_tanks_own_echoes_as_the_boards() -> None:
    """Through the simulated audio interface, the sampled world echoes the played schedule
    off the tank's boundaries exactly as the board's analytic channel does (once the silence
    before the first block has left the response's length)."""
    sch = _schedule()
    level = 150.0  # dB re 1 µPa at 1 m: the omni near wall stays below full scale
    world = AcousticWorld(
        FS, SONAR, [], sound_speed_mps=C, source_level_db=level, receiver=RX, tank=TANK,
        tank_echoes=OWN,
    )  # fmt: skip
    settings_ = AudioSettings(samplerate=FS, blocksize=256, channels_in=1, channels_out=1)
    n = int(0.06 * FS)
    played = BlockSynthesizer(sch, FS).read(n).astype(np.float32)
    rec = play_record(SimulatedDuplex(settings_, InPlaceWorld(world)), played)
    heard = rec.recording[:, 0].astype(float)
    board = Channel(sch, FS, SONAR, level, C, receiver=RX, tank=TANK, tank_echoes=OWN)
    assert board._tank is not None
    want = RX.to_full_scale(board.read_components(n)["tank"])
    latency = 2 * 256 + world.converter_delay  # the interface's buffering and the converters
    steady = board._tank.h.size  # the sampled world's DAC was silent before its first block
    got = heard[latency + steady : n]
    ref = want[steady : n - latency]
    assert np.max(np.abs(ref)) > 0.05  # the walls are heard
    # float32 samples on both sides of the interface: agreement to their precision
    np.testing.assert_allclose(got, ref, rtol=0, atol=2e-6 * np.max(np.abs(ref)))
    # nothing before the shortest boundary path (the near wall 0.5 m behind, 1 m both ways)
    # but the band-limited interpolator's leading taps (KERNEL_HALF = 16 samples)
    first = int(np.flatnonzero(np.abs(heard) > 1e-6 * np.max(np.abs(heard)))[0]) - latency
    assert 1.0 / C * FS - KERNEL_HALF <= first <= 1.0 / C * FS


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 3000), min_size=1, max_size=6))
def test_stream_convolution_is_the_same_for_any_block_split(cuts: list[int]) -> None:
    rng = np.random.default_rng(5)
    h, x = rng.standard_normal(700), rng.standard_normal(6000)
    conv = StreamConvolver(h)
    edges = np.unique(np.clip(np.cumsum(cuts), 0, x.size))
    parts = [conv.push(p) for p in np.split(x, edges)]
    np.testing.assert_allclose(np.concatenate(parts), np.convolve(x, h)[: x.size], atol=1e-10)


def test_own_echoes_need_a_tank_and_a_sonar_at_rest() -> None:
    with pytest.raises(ConfigError, match=r"tank_echoes = .* must be a tank to echo in"):
        _world([], tank_echoes=OWN)
    with pytest.raises(ConfigError, match="a sonar at rest"):
        AcousticWorld(
            FS, ConstantVelocity([0.5, 1.0, -1.0], [0.1, 0.0, 0.0]), [], sound_speed_mps=C,
            source_level_db=180.0, tank=TANK, tank_echoes=OWN,
        )  # fmt: skip
    with pytest.raises(ConfigError, match="h = \\(0,\\) is not allowed: must be at least one"):
        StreamConvolver(np.zeros(0))
