"""The real PortAudio backend on a JACK dummy server, wired as an exact digital loopback."""

from __future__ import annotations

import time as wallclock
from typing import Any

import numpy as np
import pytest

from hil.devices.audio import (
    AudioSettings,
    BlockTime,
    CallbackStop,
    LatencyMeasurementError,
    SoundDeviceDuplex,
    StatusFlags,
    measure_loopback_latency,
    play_record,
    play_record_calibrated,
)
from hil.devices.audio.contract import FloatArray
from hil.devices.audio.jack_ports import jack_ports, portaudio_ports, wire_portaudio_loopback
from hil.errors import ConfigError

N_RUNS = 3


def _settings(server: Any, **overrides: Any) -> AudioSettings:
    base: dict[str, Any] = {
        "samplerate": server.samplerate,
        "channels_in": 2,
        "channels_out": 2,
        "blocksize": server.period,
        "device": "JACK",
    }
    base.update(overrides)
    return AudioSettings(**base)


def _silent(
    indata: FloatArray, outdata: FloatArray, frames: int, time: BlockTime, status: StatusFlags
) -> None:
    outdata.fill(0.0)


def _wire() -> None:
    wire_portaudio_loopback(2)


def test_loopback_latency_is_the_same_to_the_sample_across_runs(jack_server: Any) -> None:
    settings = _settings(jack_server)
    runs = [
        measure_loopback_latency(SoundDeviceDuplex(settings), after_open=_wire)
        for _ in range(N_RUNS)
    ]
    latencies = {m.samples for run in runs for m in run.latencies}
    print(
        "JACK loopback latency (samples) per run:", [[m.samples for m in r.latencies] for r in runs]
    )
    print("xruns per run:", [r.xruns for r in runs])
    assert len(latencies) == 1, f"latency changed between runs: {latencies}"
    (latency,) = latencies
    # What the JACK dummy server gives with PortAudio: two periods (512 at 256, DESIGN.md).
    assert latency == 2 * settings.blocksize
    for run in runs:
        for m in run.latencies:
            assert m.seconds == pytest.approx(latency / settings.samplerate)
            assert m.gain == pytest.approx(1.0, abs=1e-6)  # exact digital loopback
            assert m.peak_to_sidelobe_db > 40.0
        for index, flags in run.xruns:
            assert isinstance(flags, StatusFlags) and flags
            assert index % settings.blocksize == 0


def test_digital_loopback_is_bit_exact_after_the_measured_latency(jack_server: Any) -> None:
    rng = np.random.default_rng(20240501)
    signal = (0.25 * rng.standard_normal((8192, 2))).clip(-1, 1).astype(np.float32)
    run = play_record_calibrated(
        SoundDeviceDuplex(_settings(jack_server)), signal, after_open=_wire
    )
    assert [m.samples for m in run.calibration.latencies] == [512, 512]
    assert np.array_equal(run.recording, signal)


def test_recording_before_the_latency_is_silence(jack_server: Any) -> None:
    settings = _settings(jack_server, channels_in=1, channels_out=1)
    pulse = np.zeros(2048, dtype=np.float32)
    pulse[0] = 0.5
    run = play_record(
        SoundDeviceDuplex(settings),
        pulse,
        extra_frames=1024,
        after_open=lambda: wire_portaudio_loopback(1),
    )
    assert np.flatnonzero(run.recording[:, 0]).tolist() == [2 * settings.blocksize]
    assert run.recording[2 * settings.blocksize, 0] == np.float32(0.5)


def test_callback_gets_the_contract_arguments(jack_server: Any) -> None:
    settings = _settings(jack_server, channels_in=2, channels_out=1)
    seen: list[tuple[tuple[int, ...], tuple[int, ...], str, int, BlockTime, StatusFlags]] = []

    def callback(
        indata: FloatArray, outdata: FloatArray, frames: int, time: BlockTime, status: StatusFlags
    ) -> None:
        outdata.fill(0.0)
        seen.append((indata.shape, outdata.shape, str(indata.dtype), frames, time.copy(), status))
        if len(seen) == 8:
            raise CallbackStop

    with SoundDeviceDuplex(settings) as backend:
        backend.open(callback)
        backend.start()
        assert backend.wait(10.0)
        assert backend.frames_processed == 8 * settings.blocksize
    assert [s[0] for s in seen] == [(256, 2)] * 8
    assert [s[1] for s in seen] == [(256, 1)] * 8
    assert {s[2] for s in seen} == {"float32"}
    assert [s[4].sample_index for s in seen] == [256 * k for k in range(8)]
    for *_, t, _status in seen:
        assert t.input_adc_time_s <= t.current_time_s <= t.output_dac_time_s


def test_exception_in_callback_stops_stream_and_is_reraised_on_wait(jack_server: Any) -> None:
    calls: list[int] = []

    def callback(
        indata: FloatArray, outdata: FloatArray, frames: int, time: BlockTime, status: StatusFlags
    ) -> None:
        outdata.fill(0.0)
        calls.append(time.sample_index)
        if time.sample_index == 1024:
            raise ValueError("boom at 1024")

    backend = SoundDeviceDuplex(_settings(jack_server))
    backend.open(callback)
    backend.start()
    with pytest.raises(ValueError, match="boom at 1024"):
        backend.wait(10.0)
    assert calls[-1] == 1024
    assert not backend.active
    backend.close()  # already raised once: closes quietly


def test_stalled_callback_is_logged_as_an_xrun_at_the_next_block(jack_server: Any) -> None:
    settings = _settings(jack_server)
    stall_at = 40 * settings.blocksize

    def callback(
        indata: FloatArray, outdata: FloatArray, frames: int, time: BlockTime, status: StatusFlags
    ) -> None:
        outdata.fill(0.0)
        if time.sample_index == stall_at:
            wallclock.sleep(0.05)  # fault injection: break the real-time rule on purpose
        if time.sample_index >= 80 * settings.blocksize:
            raise CallbackStop

    with SoundDeviceDuplex(settings) as backend:
        backend.open(callback)
        backend.start()
        assert backend.wait(10.0)
        xruns = dict(backend.xruns)
    print("xrun log:", xruns)
    assert stall_at + settings.blocksize in xruns
    assert xruns[stall_at + settings.blocksize] & (
        StatusFlags.OUTPUT_UNDERFLOW | StatusFlags.INPUT_OVERFLOW
    )


def test_portaudio_ports_appear_on_open(jack_server: Any) -> None:
    backend = SoundDeviceDuplex(_settings(jack_server))
    backend.open(_silent)
    try:
        outs, ins = portaudio_ports(jack_ports())
    finally:
        backend.close()
    assert len(outs) == 2 and len(ins) == 2
    assert backend.device is not None and backend.device.hostapi.startswith("JACK")


def test_unsupported_samplerate_is_refused_before_opening(jack_server: Any) -> None:
    backend = SoundDeviceDuplex(_settings(jack_server, samplerate=44100))
    with pytest.raises(ConfigError) as err:
        backend.open(_silent)
    message = str(err.value)
    assert message.startswith("samplerate = 44100 is not allowed: must be a rate 0 'system'")
    assert "its default is 192000 Hz" in message
    assert "Invalid sample rate" in message


def test_unknown_device_name_lists_the_devices(jack_server: Any) -> None:
    backend = SoundDeviceDuplex(_settings(jack_server, device="Scarlett 2i2"))
    with pytest.raises(ConfigError) as err:
        backend.open(_silent)
    message = str(err.value)
    assert message.startswith("device = 'Scarlett 2i2' is not allowed")
    assert "0 'system' (JACK Audio Connection Kit, 2 in, 2 out)" in message
    assert "python -m sounddevice" in message


def test_too_many_channels_for_the_device(jack_server: Any) -> None:
    backend = SoundDeviceDuplex(_settings(jack_server, device=0, channels_in=3))
    with pytest.raises(ConfigError) as err:
        backend.open(_silent)
    assert str(err.value).startswith(
        "channels_in/channels_out = (3, 2) is not allowed: must be at most (2, 2) on 0 'system'"
    )


def test_unwired_loop_is_refused_not_trusted_from_the_driver(jack_server: Any) -> None:
    # Without the out -> in connection PortAudio's inputs only hear the dummy capture ports
    # (silence): the measurement must refuse rather than report the driver's latency.
    with pytest.raises(LatencyMeasurementError, match="the reference chirp was not found cleanly"):
        measure_loopback_latency(SoundDeviceDuplex(_settings(jack_server)))


def test_an_opened_stream_describes_its_portaudio_device(jack_server: Any) -> None:
    backend = SoundDeviceDuplex(_settings(jack_server))
    with pytest.raises(RuntimeError, match=r"open\(\) the stream first"):
        backend.describe()
    backend.open(_silent)
    try:
        described = backend.describe()
        claimed = backend.reported_latency_s
    finally:
        backend.close()
    assert backend.abandoned is None
    assert described["host_api"].startswith("JACK") and described["device"] == backend.device.name
    assert described["device_index"] == backend.device.index
    # The driver's claims, as it makes them (JACK's PortAudio host API says 0 s for input).
    assert (described["input_latency_s"], described["output_latency_s"]) == claimed
    assert all(0.0 <= s < 1.0 for s in claimed)
