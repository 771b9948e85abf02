"""The audio interface as the run's DAC/ADC (:class:`AudioDaq`): against the simulated duplex
(exact loopback, sample indices, sync fit, xruns, URL refusals) and on a JACK dummy server."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.acquisition.annotations import ADC_CLIPPING_TEXT, AnnotationKind
from hil.devices.audio import (
    AudioSettings,
    CallbackStop,
    DigitalLoopbackWorld,
    SimulatedDuplex,
    StatusFlags,
    portaudio_available,
)
from hil.devices.audio.daq import AudioDaq, parse_audio_url
from hil.devices.audio.jack_ports import wire_portaudio_loopback
from hil.errors import ConfigError
from hil.experiments.live.latency import measure_latency
from sim_devices.stage.clock import ManualClock

FS = 48000
T0 = 100.0


def _counts(x: npt.NDArray[Any]) -> npt.NDArray[np.int16]:
    """What the ADC path gives for float full-scale samples: round(x * 32768), clipped."""
    scaled = np.rint(np.asarray(x, dtype=np.float32) * np.float32(32768.0))
    return np.clip(scaled, -32768, 32767).astype(np.int16)


class _Source:
    """DAC source: a seeded noise signal, then silence; ends the stream after ``stop_at``."""

    def __init__(self, n: int, stop_at: int, seed: int = 7) -> None:
        self.signal = 0.4 * np.random.default_rng(seed).standard_normal(n).clip(-2.4, 2.4)
        self.stop_at = stop_at
        self.calls: list[tuple[int, int]] = []

    def __call__(self, first: int, n: int) -> npt.NDArray[np.float64]:
        if first >= self.stop_at:
            raise CallbackStop
        self.calls.append((first, n))
        out = np.zeros(n)
        part = self.signal[first : first + n]
        out[: part.shape[0]] = part
        return out


def _sim_daq(
    *, block: int = 64, io_delay: int = 128, cable: int = 5, **kw: Any
) -> tuple[AudioDaq, ManualClock]:
    clock = ManualClock(T0)
    backend = SimulatedDuplex(
        AudioSettings(samplerate=FS, channels_in=2, channels_out=2, blocksize=block),
        DigitalLoopbackWorld(cable),
        io_delay_samples=io_delay,
        clock=clock,
        xrun_schedule=kw.pop("xrun_schedule", None),
    )
    return AudioDaq(backend, host_clock=clock.now, **kw), clock


def test_start_plays_the_source_and_read_returns_the_loopback_exactly() -> None:
    n = 4096
    source = _Source(n, stop_at=n + 512)
    daq, _ = _sim_daq()
    with daq:
        daq.configure()
        assert daq.start(source) == 0
        assert daq.wait_for_samples(n + 512, timeout_s=5.0)
        got = daq.read(0, n + 512)
        # The stream ends by itself at the block whose source call ends it (stop() before
        # then would end it after the current block instead).
        assert daq.backend.wait(timeout_s=5.0)
    # The source was asked for consecutive blocks from stream index 0.
    assert source.calls == [(k, 64) for k in range(0, n + 512, 64)]
    latency = 128 + 5  # io delay + cable
    expected = np.zeros(n + 512, dtype=np.int16)
    expected[latency : latency + n] = _counts(source.signal)[: n + 512 - latency]
    assert got.dtype == np.int16 and got.shape == (n + 512, 2)
    np.testing.assert_array_equal(got[:, 0], expected)
    np.testing.assert_array_equal(got[:, 1], expected)
    # The runner's latency measurement on the monitor channel finds the same delay.
    assert measure_latency(got[:, 1] / 32768.0, source.signal[: n + 512]) == latency
    assert daq.ring is not None and daq.ring.missing == 0
    # The block whose source call ended the stream was handed to the callback, not captured.
    assert daq.ring.end_index == n + 512 and daq.last_status.frames == n + 512 + 64
    assert not daq.backend.active


@settings(max_examples=15, deadline=None)
@given(
    block=st.sampled_from([16, 64, 100, 256]),
    extra_io=st.integers(0, 300),
    cable=st.integers(0, 500),
    chunk=st.integers(1, 700),
)
def test_block_reads_equal_the_whole_capture(
    block: int, extra_io: int, cable: int, chunk: int
) -> None:
    n = 3000
    daq, _ = _sim_daq(block=block, io_delay=block + extra_io, cable=cable)
    source = _Source(n, stop_at=n)
    with daq:
        daq.start(source)
        assert daq.wait_for_samples(n, timeout_s=5.0)
        whole = daq.read(0, n)
        parts = [daq.read(k, min(chunk, n - k)) for k in range(0, n, chunk)]
    np.testing.assert_array_equal(np.concatenate(parts), whole)
    lat = block + extra_io + cable
    np.testing.assert_array_equal(whole[lat:, 0], _counts(source.signal[: n - lat]))
    assert not whole[:lat].any()


def test_full_scale_clips_to_int16_range() -> None:
    daq, _ = _sim_daq(io_delay=64, cable=0)

    def source(first: int, n: int) -> npt.NDArray[np.float64]:
        if first >= 256:
            raise CallbackStop
        return np.array([1.0, -1.0, 0.5, 2.0] * (n // 4))

    with daq:
        daq.start(source)
        assert daq.wait_for_samples(256, timeout_s=5.0)
        got = daq.read(64, 8)[:, 0].tolist()
        alarms = [a for a in daq.annotations.all() if a.detail.startswith(ADC_CLIPPING_TEXT)]
    # The simulated converter clips 2.0 to full scale, as an interface delivers it.
    assert got == [32767, -32768, 16384, 32767, 32767, -32768, 16384, 32767]
    # Counted, not silent: the converter's 2.0s (64 per input, 2 inputs), and on the host
    # every value at a rail (+1.0, -1.0 and the clipped 2.0: 3 of 4 values) in the 256 - 64
    # captured samples after the 64-sample io delay.
    assert isinstance(daq.backend, SimulatedDuplex)
    assert daq.backend.adc_clipped_samples == 2 * 64
    assert daq.adc_clipped_samples == 2 * 3 * (256 - 64) // 4
    assert alarms and all(a.kind is AnnotationKind.ALARM for a in alarms)


def test_sync_pairs_map_host_time_to_the_index_the_dac_plays() -> None:
    daq, _ = _sim_daq(sync_interval_s=0.0)
    with daq:
        daq.start(_Source(1000, stop_at=6400))
        assert daq.wait_for_samples(6400, timeout_s=5.0)
    fit = daq.clock_fit
    pairs = list(fit._pairs)
    # One pair per block, stamped with the time the block's first output sample leaves the
    # DAC: one block (64 samples) of output buffering after its callback.
    assert [j for j, _ in pairs] == list(range(6400 - 64 * 100, 6400, 64))
    np.testing.assert_allclose([t for _, t in pairs], [T0 + (j + 64) / FS for j, _ in pairs])
    assert fit.rate_hz == pytest.approx(FS, rel=1e-9)
    assert fit.sample_index(T0 + 0.1) == 4800 - 64
    assert fit.sample_index(fit.host_time(5000)) == 5000


def test_sync_pairs_stay_exact_when_the_callbacks_run_late() -> None:
    # Each callback runs 3 blocks after its time (a thread behind, catching up): its output
    # is already due, the lead negative, and the pair still dates the DAC time exactly.
    late_s = 3 * 64 / FS

    class LateClock(ManualClock):
        def sleep_until(self, t_s: float) -> None:
            super().sleep_until(t_s + late_s)

    clock = LateClock(T0)
    backend = SimulatedDuplex(
        AudioSettings(samplerate=FS, channels_in=2, channels_out=2, blocksize=64),
        io_delay_samples=128,
        clock=clock,
    )
    daq = AudioDaq(backend, host_clock=clock.now, sync_interval_s=0.0)
    with daq:
        daq.start(_Source(100, stop_at=3200))
        assert daq.wait_for_samples(3200, timeout_s=5.0)
    pairs = list(daq.clock_fit._pairs)
    assert [j for j, _ in pairs] == list(range(0, 3200, 64))
    np.testing.assert_allclose([t for _, t in pairs], [T0 + (j + 64) / FS for j, _ in pairs])


def test_sync_pairs_are_decimated_to_the_least_delayed_stamp_per_interval() -> None:
    clock_calls: list[float] = []

    def jittery_clock() -> float:
        # Host stamps: block k arrives 2 ms late except every 5th, which is on time.
        k = len(clock_calls)
        t = T0 + k * 64 / FS + (0.0 if k % 5 == 0 else 0.002)
        clock_calls.append(t)
        return t

    clock = ManualClock(T0)
    backend = SimulatedDuplex(
        AudioSettings(samplerate=FS, channels_in=2, channels_out=2, blocksize=64),
        io_delay_samples=64,
        clock=clock,
    )
    daq = AudioDaq(backend, host_clock=jittery_clock, sync_interval_s=320 / FS)
    with daq:
        daq.start(_Source(100, stop_at=3200))
        assert daq.wait_for_samples(3200, timeout_s=5.0)
    pairs = list(daq.clock_fit._pairs)
    # 50 blocks, 5 per interval: one pair each, the on-time block (k % 5 == 0).
    assert [j for j, _ in pairs] == list(range(0, 3200, 320))
    # Stamped with the output lead: one block (64 samples) after the on-time callback.
    np.testing.assert_allclose([t for _, t in pairs], [T0 + (j + 64) / FS for j, _ in pairs])


def test_xruns_become_annotations_and_status_counts() -> None:
    schedule = {
        256: int(StatusFlags.INPUT_OVERFLOW),
        512: int(StatusFlags.INPUT_OVERFLOW | StatusFlags.OUTPUT_UNDERFLOW),
        1024: int(StatusFlags.PRIMING_OUTPUT),
    }
    daq, _ = _sim_daq(xrun_schedule=schedule)
    with daq:
        daq.start(_Source(100, stop_at=2048))
        assert daq.wait_for_samples(2048, timeout_s=5.0)
    events = [(a.sample_index, a.kind) for a in daq.annotations.all()]
    assert events == [
        (256, AnnotationKind.ADC_OVERRUN),
        (512, AnnotationKind.ADC_OVERRUN),
        (512, AnnotationKind.DAC_UNDERRUN),
    ]
    assert daq.annotations.count(AnnotationKind.ADC_OVERRUN) == 2
    status = daq.last_status
    assert (status.overruns, status.underruns, status.frames) == (2, 1, 2048 + 64)
    assert len(daq.annotations.all()) == 3  # reading again adds nothing


def test_a_stream_that_ended_early_is_reported_by_wait_for_samples() -> None:
    daq, _ = _sim_daq()
    with daq:
        daq.start(_Source(100, stop_at=640))
        with pytest.raises(RuntimeError, match="audio stream ended at sample 640, before 10000"):
            daq.wait_for_samples(10_000, timeout_s=0.5)


@pytest.mark.slow
def test_a_source_error_is_raised_in_the_host_thread() -> None:
    daq, _ = _sim_daq()

    def broken(first: int, n: int) -> npt.NDArray[np.float64]:
        if first >= 128:
            raise ValueError("schedule exhausted")
        return np.zeros(n)

    daq.open()
    daq.start(broken)
    with pytest.raises(ValueError, match="schedule exhausted"):
        daq.wait_for_samples(10_000, timeout_s=2.0)
    daq.stop()
    daq.close()
    assert daq.read(0, 128).shape == (128, 2)


def test_wait_for_samples_times_out_on_a_running_stream_and_stop_ends_it() -> None:
    daq = AudioDaq.from_url("sim://audio?rate=48000&blocksize=256&delay=7", sample_rate_hz=48000)
    daq.open()
    source = _Source(4800, stop_at=10**12)
    daq.start(source)
    assert not daq.wait_for_samples(10**9, timeout_s=0.01)
    assert daq.backend.active
    assert daq.wait_for_samples(4800, timeout_s=5.0)  # real-time pacing: 0.1 s
    daq.stop()
    assert not daq.backend.active
    frames = daq.last_status.frames
    daq.close()
    daq.close()
    assert daq.last_status.frames == frames
    got = daq.read(0, 4800)
    # Default io delay of the simulated interface: two blocks (512), plus the 7-sample cable.
    assert measure_latency(got[:, 1] / 32768.0, source.signal) == 512 + 7
    np.testing.assert_array_equal(got[519:, 1], _counts(source.signal[: 4800 - 519]))
    assert daq.clock_fit.pairs >= 1


def test_read_and_wait_refuse_before_start() -> None:
    daq, _ = _sim_daq()
    with pytest.raises(RuntimeError, match=r"open\(\) the audio DAQ before start"):
        daq.start(_Source(10, 10))
    with pytest.raises(RuntimeError, match=r"start\(\) the audio DAQ before reading"):
        daq.read(0, 1)
    with pytest.raises(RuntimeError, match=r"start\(\) the audio DAQ before waiting"):
        daq.wait_for_samples(1, 0.0)


def test_parse_audio_url_golden() -> None:
    url = parse_audio_url("sim://audio?rate=192000&blocksize=512&delay=64&latency=high")
    assert (url.device, url.samplerate_hz, url.blocksize, url.delay_samples, url.latency) == (
        "sim",
        192000,
        512,
        64,
        "high",
    )
    assert url.simulated
    assert parse_audio_url("audio://?latency=0.02").device is None
    assert parse_audio_url("audio://?latency=0.02").latency == 0.02
    assert parse_audio_url("audio://JACK").samplerate_hz is None


@pytest.mark.parametrize(
    ("url", "rate", "fragment"),
    [
        ("serial:///dev/ttyACM0", 48000, "devices.board = 'serial:///dev/ttyACM0' is not allowed"),
        ("sim://audio/extra", 48000, "must be audio://DEVICE?rate=192000&blocksize=256"),
        ("sim://audio?rate=48k", 48000, "devices.board rate = '48k' is not allowed"),
        ("sim://audio?rate=48000&bloksize=64", 48000, "devices.board query key = 'bloksize'"),
        ("sim://audio?blocksize=-4", 48000, "devices.board blocksize = '-4'"),
        ("sim://audio?blocksize=8", 48000, "blocksize = 8 is not allowed: must be an integer in"),
        ("audio://JACK?delay=3", 48000, "devices.board delay = '3' is not allowed: must be only"),
        ("sim://audio?latency=fast", 48000, "devices.board latency = 'fast'"),
        ("sim://audio?rate=44100", 48000, "rate = 44100 is not allowed: must be the waveform's"),
        ("sim://audio", None, "devices.board rate = None is not allowed"),
        ("sim://audio?rate=1000000", 1000000, "samplerate = 1000000 is not allowed"),
    ],
)
def test_bad_urls_are_refused_with_the_field(url: str, rate: int | None, fragment: str) -> None:
    with pytest.raises(ConfigError) as err:
        AudioDaq.from_url(url, sample_rate_hz=rate)
    assert fragment in str(err.value)


def test_backend_with_the_wrong_channel_count_is_refused() -> None:
    backend = SimulatedDuplex(AudioSettings(samplerate=FS, channels_in=1, channels_out=2))
    with pytest.raises(ConfigError, match="channels_in = 1 is not allowed: must be 2 "):
        AudioDaq(backend)


def test_unknown_device_is_refused_on_open(require_system: Callable[[bool, str], None]) -> None:
    ok, why = portaudio_available()
    require_system(ok, f"PortAudio is not available: {why}")
    daq = AudioDaq.from_url("audio://NoSuchInterface-7f3?rate=48000", sample_rate_hz=48000)
    with pytest.raises(ConfigError, match="device = 'NoSuchInterface-7f3' is not allowed"):
        daq.open()


# --- the real PortAudio backend on the JACK dummy server (fixture in conftest.py) ---


def test_jack_loopback_monitor_is_the_dac_delayed_by_a_constant_latency(jack_server: Any) -> None:
    fs, period = jack_server.samplerate, jack_server.period
    daq = AudioDaq.from_url(f"audio://JACK?rate={fs}&blocksize={period}", sample_rate_hz=fs)
    n = 16384
    source = _Source(n, stop_at=n + 8 * period, seed=11)
    with daq:
        wire_portaudio_loopback(2)
        assert daq.start(source) == 0
        assert daq.wait_for_samples(n + 4 * period, timeout_s=10.0)
        got = daq.read(0, n + 4 * period)
    monitor = got[:, 1]
    latency = measure_latency(monitor / 32768.0, source.signal)
    print("JACK AudioDaq loopback latency (samples):", latency, "xruns:", daq.last_status)
    # Exact digital loopback: the monitor is the DAC, delayed by a whole number of samples
    # (two periods on the dummy server), bit for bit; the hydrophone input sees the same cable.
    assert latency == 2 * period
    np.testing.assert_array_equal(monitor[latency : latency + n], _counts(source.signal))
    np.testing.assert_array_equal(got[latency : latency + n, 0], _counts(source.signal))
    assert not monitor[:latency].any()
    assert daq.clock_fit.pairs >= 1


def test_jack_refuses_a_rate_the_server_does_not_run(jack_server: Any) -> None:
    daq = AudioDaq.from_url("audio://JACK?rate=48000&blocksize=256", sample_rate_hz=48000)
    with pytest.raises(ConfigError, match="samplerate = 48000 is not allowed: must be a rate"):
        daq.open()
