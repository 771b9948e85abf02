"""Audio interface as the cheapest DAC/ADC: full-duplex streams, real and simulated.

- :mod:`~hil.devices.audio.contract`: the real-time callback contract (read it first).
- :class:`SoundDeviceDuplex`: a real interface over python-sounddevice (PortAudio), imported
  lazily, so this package imports without PortAudio installed.
- :class:`SimulatedDuplex`: the same contract, with a pluggable world (e.g.
  :class:`DigitalLoopbackWorld`) and an injected clock; it lives in
  :mod:`sim_devices.audio.simulated` and is resolved from there when asked for (the host
  imports simulated devices lazily).
- :func:`play_record`: play a signal and record the input at the same time.
- :func:`measure_loopback_latency` / :func:`play_record_calibrated`: the loopback latency
  measured with a reference chirp at every run.
"""

from typing import TYPE_CHECKING, Any

from hil.devices.audio.contract import (
    DTYPE,
    AudioCallback,
    BlockTime,
    CallbackStop,
    DuplexBackend,
    StatusFlags,
    XrunLog,
)
from hil.devices.audio.latency import (
    CalibratedRecording,
    LatencyMeasurement,
    LatencyMeasurementError,
    LoopbackCalibration,
    lfm_chirp,
    matched_filter_delay,
    measure_loopback_latency,
    play_record_calibrated,
    reference_chirp,
)
from hil.devices.audio.playrec import PlayRecording, play_record
from hil.devices.audio.portaudio_backend import (
    AudioUnavailableError,
    DeviceInfo,
    SoundDeviceDuplex,
    find_device,
    list_devices,
    portaudio_available,
    rescan_devices,
)
from hil.devices.audio.settings import AudioSettings
from hil.devices.clock import Clock
from hil.devices.clock import MonotonicClock as RealtimeClock

__all__ = [
    "DTYPE",
    "AudioCallback",
    "AudioSettings",
    "AudioUnavailableError",
    "BlockTime",
    "CalibratedRecording",
    "CallbackStop",
    "Clock",
    "DeviceInfo",
    "DigitalLoopbackWorld",
    "DuplexBackend",
    "LatencyMeasurement",
    "LatencyMeasurementError",
    "LoopbackCalibration",
    "ManualClock",
    "PlayRecording",
    "RealtimeClock",
    "SimulatedDuplex",
    "SoundDeviceDuplex",
    "StatusFlags",
    "World",
    "XrunLog",
    "find_device",
    "lfm_chirp",
    "list_devices",
    "matched_filter_delay",
    "measure_loopback_latency",
    "play_record",
    "play_record_calibrated",
    "portaudio_available",
    "reference_chirp",
    "rescan_devices",
]


if TYPE_CHECKING:
    from sim_devices.audio.simulated import (
        DigitalLoopbackWorld,
        ManualClock,
        SimulatedDuplex,
        World,
    )

#: Names resolved from :mod:`sim_devices.audio.simulated` when asked for.
_SIMULATED = ("DigitalLoopbackWorld", "ManualClock", "SimulatedDuplex", "World")


def __getattr__(name: str) -> Any:
    """The simulated interface's names (:data:`_SIMULATED`), resolved when asked for: they
    live with the simulated devices, which this package does not import when it loads."""
    if name in _SIMULATED:
        from sim_devices.audio import simulated

        return getattr(simulated, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
