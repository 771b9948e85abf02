"""The simulated full-duplex backend: same contract, exact loopback, chunk invariance."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.devices.audio import (
    AudioSettings,
    BlockTime,
    CallbackStop,
    DigitalLoopbackWorld,
    SimulatedDuplex,
    StatusFlags,
    measure_loopback_latency,
    play_record,
)
from hil.devices.audio.contract import FloatArray
from hil.devices.clock import MonotonicClock
from hil.errors import ConfigError
from sim_devices.stage.clock import ManualClock

FS = 48000.0


def _noise(frames: int, channels: int, seed: int) -> FloatArray:
    rng = np.random.default_rng(seed)
    return (0.3 * rng.standard_normal((frames, channels))).clip(-1, 1).astype(np.float32)


@settings(max_examples=25, deadline=None)
@given(
    blocksize=st.sampled_from([16, 64, 100, 256]),
    extra_io=st.integers(0, 300),
    world_delay=st.integers(0, 700),
)
def test_measured_latency_is_io_delay_plus_world_delay(
    blocksize: int, extra_io: int, world_delay: int
) -> None:
    io_delay = blocksize + extra_io
    sim = SimulatedDuplex(
        AudioSettings(samplerate=FS, channels_in=2, channels_out=2, blocksize=blocksize),
        DigitalLoopbackWorld(world_delay),
        io_delay_samples=io_delay,
    )
    cal = measure_loopback_latency(sim, max_latency_frames=2048)
    assert [m.samples for m in cal.latencies] == [io_delay + world_delay] * 2
    assert [m.gain for m in cal.latencies] == pytest.approx([1.0, 1.0], abs=1e-6)
    assert cal.xruns == []


def test_recording_does_not_depend_on_the_block_size() -> None:
    signal = _noise(5000, 2, seed=7)
    recordings = []
    for blocksize in (16, 64, 100, 256, 512):
        sim = SimulatedDuplex(
            AudioSettings(samplerate=FS, channels_in=3, channels_out=2, blocksize=blocksize),
            DigitalLoopbackWorld(37, gain=0.5),
            io_delay_samples=512,
        )
        recordings.append(play_record(sim, signal, extra_frames=600).recording)
    for rec in recordings[1:]:
        assert np.array_equal(rec, recordings[0])
    expected = np.zeros_like(recordings[0])
    expected[549:5549, :2] = 0.5 * signal  # delay 512 + 37; input channel 2 has no output
    assert np.array_equal(recordings[0], expected)


def test_default_io_delay_is_two_blocks_like_the_jack_dummy_server() -> None:
    sim = SimulatedDuplex(AudioSettings(samplerate=FS, blocksize=256))
    assert sim.io_delay_samples == 512
    assert measure_loopback_latency(sim).latencies[0].samples == 512


def test_the_simulated_interface_describes_its_buffering_as_its_latency() -> None:
    sim = SimulatedDuplex(AudioSettings(samplerate=FS, blocksize=256), io_delay_samples=600)
    assert sim.describe() == {
        "device": "simulated audio interface",
        "host_api": "simulated",
        "io_delay_samples": 600,
        "input_latency_s": 600 / FS,
    }
    assert sim.abandoned is None


def test_callback_receives_the_contract_arguments() -> None:
    s = AudioSettings(samplerate=FS, channels_in=3, channels_out=2, blocksize=64)
    seen: list[tuple[tuple[int, ...], tuple[int, ...], np.dtype, int, BlockTime, StatusFlags]] = []

    def callback(
        indata: FloatArray, outdata: FloatArray, frames: int, time: BlockTime, status: StatusFlags
    ) -> None:
        outdata.fill(0.25)
        seen.append((indata.shape, outdata.shape, indata.dtype, frames, time.copy(), status))
        if len(seen) == 5:
            raise CallbackStop

    clock = ManualClock(100.0)
    with SimulatedDuplex(s, io_delay_samples=160, clock=clock) as sim:
        sim.open(callback)
        sim.start()
        assert sim.wait(5.0)
        assert sim.frames_processed == 5 * 64
        assert not sim.active
    assert [x[0] for x in seen] == [(64, 3)] * 5
    assert [x[1] for x in seen] == [(64, 2)] * 5
    assert {x[2] for x in seen} == {np.dtype(np.float32)}
    assert {x[3] for x in seen} == {64}
    assert {x[5] for x in seen} == {StatusFlags(0)}
    times = [x[4] for x in seen]
    assert [t.sample_index for t in times] == [0, 64, 128, 192, 256]
    for t in times:
        assert t.current_time_s == pytest.approx(100.0 + t.sample_index / FS)
        assert t.output_dac_time_s == pytest.approx(t.current_time_s + 64 / FS)
        # What leaves the DAC now comes back io_delay samples later in the input.
        assert t.output_dac_time_s - t.input_adc_time_s == pytest.approx(160 / FS)
    assert clock.now() == pytest.approx(100.0 + 256 / FS)


def test_exception_in_callback_stops_and_is_reraised_on_wait_once() -> None:
    calls: list[int] = []

    def callback(
        indata: FloatArray, outdata: FloatArray, frames: int, time: BlockTime, status: StatusFlags
    ) -> None:
        outdata.fill(1.0)
        calls.append(time.sample_index)
        if time.sample_index == 320:
            raise ValueError("boom at 320")

    world = DigitalLoopbackWorld(0)
    sim = SimulatedDuplex(AudioSettings(samplerate=FS, blocksize=64), world)
    sim.open(callback)
    sim.start()
    with pytest.raises(ValueError, match="boom at 320"):
        sim.wait(5.0)
    assert calls == [0, 64, 128, 192, 256, 320]
    assert not sim.active
    assert sim.frames_processed == 384
    sim.close()  # raised once already: closes quietly


def test_exception_is_reraised_on_close_when_not_waited() -> None:
    started = threading.Event()

    def callback(
        indata: FloatArray, outdata: FloatArray, frames: int, time: BlockTime, status: StatusFlags
    ) -> None:
        outdata.fill(0.0)
        started.set()
        raise KeyError("from the audio thread")

    sim = SimulatedDuplex(AudioSettings(samplerate=FS, blocksize=64))
    sim.open(callback)
    sim.start()
    assert started.wait(5.0)
    with pytest.raises(KeyError, match="from the audio thread"):
        sim.close()


def test_failing_world_is_reraised_like_a_callback_error() -> None:
    def broken_world(output: FloatArray, index: int, inp: FloatArray) -> None:
        raise RuntimeError(f"world failed at {index}")

    sim = SimulatedDuplex(AudioSettings(samplerate=FS, blocksize=64), broken_world)
    with pytest.raises(RuntimeError, match="world failed at 0"):
        play_record(sim, np.zeros(1000, dtype=np.float32))


def test_stop_ends_an_endless_stream() -> None:
    blocks = threading.Semaphore(0)

    def callback(
        indata: FloatArray, outdata: FloatArray, frames: int, time: BlockTime, status: StatusFlags
    ) -> None:
        outdata.fill(0.0)
        blocks.release()

    sim = SimulatedDuplex(AudioSettings(samplerate=FS, blocksize=64))
    sim.open(callback)
    sim.start()
    for _ in range(10):
        assert blocks.acquire(timeout=5.0)
    assert sim.active
    sim.stop()
    assert not sim.active
    assert sim.frames_processed >= 640
    assert sim.frames_processed % 64 == 0


def test_injected_xruns_are_logged_by_sample_index() -> None:
    seen: dict[int, StatusFlags] = {}

    def callback(
        indata: FloatArray, outdata: FloatArray, frames: int, time: BlockTime, status: StatusFlags
    ) -> None:
        outdata.fill(0.0)
        if status:
            seen[time.sample_index] = status
        if time.sample_index >= 1024:
            raise CallbackStop

    schedule = {256: StatusFlags.INPUT_OVERFLOW, 768: 6}
    sim = SimulatedDuplex(AudioSettings(samplerate=FS, blocksize=128), xrun_schedule=schedule)
    sim.open(callback)
    sim.start()
    assert sim.wait(5.0)
    expected = [
        (256, StatusFlags.INPUT_OVERFLOW),
        (768, StatusFlags.INPUT_OVERFLOW | StatusFlags.OUTPUT_UNDERFLOW),
    ]
    assert sim.xruns == expected
    assert sorted(seen.items()) == expected


def test_play_record_returns_the_xrun_log() -> None:
    sim = SimulatedDuplex(
        AudioSettings(samplerate=FS, blocksize=64), xrun_schedule={128: StatusFlags.PRIMING_OUTPUT}
    )
    run = play_record(sim, np.zeros(500, dtype=np.float32))
    assert run.xruns == [(128, StatusFlags.PRIMING_OUTPUT)]
    assert run.recording.shape == (500, 1)
    assert run.samplerate == FS


def test_realtime_clock_runs_the_same_data_path() -> None:
    signal = _noise(480, 1, seed=3)
    sim = SimulatedDuplex(
        AudioSettings(samplerate=FS, blocksize=48), io_delay_samples=96, clock=MonotonicClock()
    )
    run = play_record(sim, signal, extra_frames=96)
    assert np.array_equal(run.recording[96:], signal)
    assert not run.recording[:96].any()


def test_a_simulated_stream_can_be_reopened() -> None:
    sim = SimulatedDuplex(AudioSettings(samplerate=FS, blocksize=64), DigitalLoopbackWorld(10))
    first = play_record(sim, _noise(300, 1, seed=1), extra_frames=200).recording
    again = play_record(sim, _noise(300, 1, seed=1), extra_frames=200).recording
    assert np.array_equal(first, again)  # the world's delay line is reset on open


def test_io_delay_shorter_than_a_block_is_refused() -> None:
    with pytest.raises(ConfigError) as err:
        SimulatedDuplex(AudioSettings(blocksize=256), io_delay_samples=100)
    assert str(err.value) == (
        "io_delay_samples = 100 is not allowed: must be an integer >= blocksize (256) samples; "
        "a block's input can only hold samples captured before its callback runs"
    )


def test_xrun_schedule_off_block_boundary_is_refused() -> None:
    with pytest.raises(ConfigError) as err:
        SimulatedDuplex(AudioSettings(blocksize=64), xrun_schedule={100: 2})
    assert str(err.value).startswith(
        "xrun_schedule = 100 is not allowed: must be sample indices >= 0 that are multiples of "
        "blocksize (64)"
    )


def test_negative_world_delay_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"delay_samples = -1 is not allowed: must be an integer"):
        DigitalLoopbackWorld(-1)


def test_start_before_open_says_what_to_do() -> None:
    with pytest.raises(RuntimeError, match=r"open\(callback\) the stream before start\(\)"):
        SimulatedDuplex(AudioSettings()).start()


def test_non_callable_callback_is_refused() -> None:
    with pytest.raises(ConfigError, match="callback = 42 is not allowed: must be a callable"):
        SimulatedDuplex(AudioSettings()).open(42)  # type: ignore[arg-type]


@settings(max_examples=30, deadline=None)
@given(
    delay=st.integers(0, 300),
    cuts=st.lists(st.integers(1, 200), min_size=1, max_size=20),
    seed=st.integers(0, 2**32 - 1),
)
def test_loopback_world_chunks_equal_whole(delay: int, cuts: list[int], seed: int) -> None:
    total = sum(cuts)
    signal = _noise(total, 2, seed)
    whole_in = np.empty((total, 2), dtype=np.float32)
    DigitalLoopbackWorld(delay)(signal, 0, whole_in)
    world = DigitalLoopbackWorld(delay)
    chunked = np.empty_like(whole_in)
    start = 0
    for n in cuts:  # growing and shrinking blocks, like a world fed by several streams
        world(signal[start : start + n], start, chunked[start : start + n])
        start += n
    assert np.array_equal(chunked, whole_in)
    expected = np.zeros_like(signal)
    expected[delay:] = signal[: max(total - delay, 0)]
    assert np.array_equal(whole_in, expected)


def test_on_virtual_time_the_blocks_run_only_while_the_clock_passes_time() -> None:
    from hil.devices.clock import VirtualClock

    clock = VirtualClock(tick_s=0.001, start_s=5.0)
    settings_ = AudioSettings(samplerate=FS, channels_in=1, channels_out=1, blocksize=64)
    sim = SimulatedDuplex(settings_, DigitalLoopbackWorld(5), virtual_time=clock)
    pulse_at = 100
    seen: list[tuple[int, float]] = []
    captured = np.zeros(4800, dtype=np.float32)

    def callback(
        indata: FloatArray, outdata: FloatArray, frames: int, time: BlockTime, status: int
    ) -> None:
        j = time.sample_index
        seen.append((j, time.current_time_s))
        outdata.fill(0.0)
        if j <= pulse_at < j + frames:
            outdata[pulse_at - j, 0] = 1.0
        captured[j : j + frames] = indata[:, 0]

    sim.open(callback)
    sim.start()
    assert sim.active and sim.start_time_s == 5.0 and seen == []  # nothing runs by itself
    clock.sleep(0.01)  # 480 samples: the blocks at 0, 64, ..., 448
    assert [j for j, _ in seen] == list(range(0, 449, 64))
    # Each block ran at the first tick at or after its callback time 5.0 + j / fs.
    assert all(t >= 5.0 + j / FS - 1e-12 and t - (5.0 + j / FS) <= 0.001 + 1e-9 for j, t in seen)
    clock.sleep(0.05)
    sim.stop()
    assert not sim.active and sim.wait(0.0)
    # Default io delay (two blocks) plus the 5-sample cable.
    assert int(np.argmax(captured)) == pulse_at + 128 + 5
    n = len(seen)
    clock.sleep(0.01)
    assert len(seen) == n  # detached: stopped means stopped


def test_virtual_time_and_a_clock_are_not_both_given() -> None:
    from hil.devices.clock import VirtualClock

    with pytest.raises(ConfigError, match=r"clock = .* is not allowed: must be None with virtual"):
        SimulatedDuplex(
            AudioSettings(samplerate=FS), clock=ManualClock(), virtual_time=VirtualClock()
        )
