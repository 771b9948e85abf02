"""A real full-duplex audio interface through python-sounddevice (PortAudio).

``sounddevice`` is imported inside the functions only: importing this module works without
the system PortAudio library, and a missing library is reported when a stream is opened,
with the package to install.

The callback contract is the one of :mod:`hil.devices.audio.contract`; this module adapts
PortAudio's callback to it (sample index, :class:`~hil.devices.audio.contract.StatusFlags`,
xrun log, exception hand-over to the host thread).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from time import monotonic
from types import ModuleType
from typing import Any

from hil.devices.audio.contract import (
    DTYPE,
    AudioCallback,
    BlockOutcome,
    CallbackRunner,
    StatusFlags,
    check_callback,
)
from hil.devices.audio.settings import AudioSettings, SettingsView
from hil.devices.audio.stream_release import (
    abandon,
    abandoned_why,
    call_bounded,
    release_timeout_s,
)
from hil.errors import ConfigError, DeviceUnavailable

PORTAUDIO_HINT = (
    "install the PortAudio library (Debian/Ubuntu: apt-get install libportaudio2) "
    "and python-sounddevice (pip install 'cas-hil[audio]')"
)


class AudioUnavailableError(DeviceUnavailable, RuntimeError):
    """python-sounddevice or the system PortAudio library cannot be loaded."""


def import_sounddevice() -> ModuleType:
    """Import ``sounddevice``, or raise :class:`AudioUnavailableError` saying what to install."""
    from hil.devices.audio.c_stderr import held_c_stderr

    try:
        # PortAudio initialises on import; its JACK host API prints libjack's complaints
        # when no JACK server runs: held back (logged at debug level), not shown.
        with held_c_stderr("PortAudio initialising"):
            import sounddevice
    except (ImportError, OSError) as exc:  # OSError: the PortAudio shared library is missing
        raise AudioUnavailableError(f"cannot load sounddevice ({exc}); {PORTAUDIO_HINT}") from exc
    return sounddevice


def portaudio_available() -> tuple[bool, str]:
    """``(True, "")`` when PortAudio loads, else ``(False, why)``; never raises."""
    try:
        import_sounddevice()
    except AudioUnavailableError as exc:
        return False, str(exc)
    return True, ""


def rescan_devices() -> None:
    """Re-initialise PortAudio so the device list reflects servers started since import.

    PortAudio enumerates devices once, when ``sounddevice`` is imported: a JACK server
    started later is invisible until this is called. No stream may be open. Raises
    :class:`AudioUnavailableError` when this process abandoned a stream
    (:mod:`hil.devices.audio.stream_release`): re-initialising would wait on it.
    """
    from hil.devices.audio.c_stderr import held_c_stderr

    why = abandoned_why()
    if why is not None:
        raise AudioUnavailableError(
            f"PortAudio cannot re-scan its devices in this process: it holds a stream it "
            f"could not release ({why}); start a new process to use audio devices again"
        )
    sd = import_sounddevice()
    with held_c_stderr("PortAudio initialising"):
        sd._terminate()
        sd._initialize()


@dataclass(frozen=True)
class DeviceInfo:
    """One PortAudio device: index, name, host API and channel counts."""

    index: int
    name: str
    hostapi: str
    max_input_channels: int
    max_output_channels: int
    default_samplerate: float

    def describe(self) -> str:
        """One-line description, e.g. ``"0 'system' (JACK Audio Connection Kit, 2 in, 2 out)"``."""
        return (
            f"{self.index} {self.name!r} ({self.hostapi}, {self.max_input_channels} in, "
            f"{self.max_output_channels} out)"
        )


def list_devices() -> list[DeviceInfo]:
    """Every device PortAudio knows, in index order."""
    sd = import_sounddevice()
    apis = sd.query_hostapis()
    return [
        DeviceInfo(
            index=i,
            name=str(d["name"]),
            hostapi=str(apis[d["hostapi"]]["name"]),
            max_input_channels=int(d["max_input_channels"]),
            max_output_channels=int(d["max_output_channels"]),
            default_samplerate=float(d["default_samplerate"]),
        )
        for i, d in enumerate(sd.query_devices())
    ]


def find_device(
    spec: str | int | None, devices: list[DeviceInfo], channels_in: int, channels_out: int
) -> DeviceInfo:
    """Pick the full-duplex device named by ``spec`` from ``devices``.

    ``spec`` is an index, a case-insensitive substring of ``"<name>, <host API>"``, or
    ``None`` for the first device that has enough input and output channels. An exact name
    match wins over substring matches. Raises :class:`~hil.errors.ConfigError` listing the
    devices when nothing (or more than one device) matches.

    Examples
    --------
    >>> devs = [DeviceInfo(0, "system", "JACK Audio Connection Kit", 2, 2, 192000.0),
    ...         DeviceInfo(1, "USB Audio", "ALSA", 2, 2, 48000.0)]
    >>> find_device("jack", devs, 2, 2).index
    0
    >>> find_device("Scarlett", devs, 1, 1)
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: device = 'Scarlett' is not allowed: must be an index or a name \
substring of a device with >= 1 in and >= 1 out: 0 'system' (JACK Audio Connection Kit, 2 in, \
2 out); 1 'USB Audio' (ALSA, 2 in, 2 out); is the interface plugged in (or the JACK server \
running)? `python -m sounddevice` lists the devices
    """
    usable = [
        d
        for d in devices
        if d.max_input_channels >= channels_in and d.max_output_channels >= channels_out
    ]
    listing = "; ".join(d.describe() for d in devices) or "(PortAudio lists no device)"
    allowed = (
        f"an index or a name substring of a device with >= {channels_in} in and "
        f">= {channels_out} out: {listing}"
    )
    hint = (
        "is the interface plugged in (or the JACK server running)? "
        "`python -m sounddevice` lists the devices"
    )
    if spec is None:
        if usable:
            return usable[0]
        raise ConfigError("device", spec, allowed, hint)
    if isinstance(spec, int):
        match = [d for d in devices if d.index == spec]
        if not match:
            raise ConfigError("device", spec, allowed, hint)
        dev = match[0]
        if dev not in usable:
            raise ConfigError(
                "channels_in/channels_out",
                (channels_in, channels_out),
                f"at most ({dev.max_input_channels}, {dev.max_output_channels}) on "
                f"{dev.describe()}",
                "lower the channel counts or pick another device",
            )
        return dev
    key = spec.lower()
    exact = [d for d in usable if d.name.lower() == key]
    found = exact or [d for d in usable if key in f"{d.name}, {d.hostapi}".lower()]
    if len(found) == 1:
        return found[0]
    if not found:
        raise ConfigError("device", spec, allowed, hint)
    names = "; ".join(d.describe() for d in found)
    raise ConfigError(
        "device", spec, f"a name matching one device, not several: {names}", "use an index"
    )


def _flags_of(status: Any) -> int:
    """PortAudio's CallbackFlags as an int (only called when an xrun was reported)."""
    return (
        StatusFlags.INPUT_UNDERFLOW * bool(status.input_underflow)
        | StatusFlags.INPUT_OVERFLOW * bool(status.input_overflow)
        | StatusFlags.OUTPUT_UNDERFLOW * bool(status.output_underflow)
        | StatusFlags.OUTPUT_OVERFLOW * bool(status.output_overflow)
        | StatusFlags.PRIMING_OUTPUT * bool(status.priming_output)
    )


class SoundDeviceDuplex(SettingsView):
    """Full-duplex stream on a real audio interface, float32, fixed block size.

    Follows :class:`~hil.devices.audio.contract.DuplexBackend`: ``open(callback)`` resolves
    the device and checks the settings against it (channel counts, sample rate) before
    creating the stream, ``start()``, ``wait()``, ``stop()``, ``close()``. A callback
    exception stops the stream and is re-raised by ``wait()``, ``stop()`` or ``close()``.

    ``stop()`` and ``close()`` never hang on a host that went away: a stream its host ended
    without finishing (:attr:`lost`) is abandoned without a call, and a stop or close that
    does not return within :func:`~hil.devices.audio.stream_release.release_timeout_s` of
    the stream's longest gap between callbacks is abandoned too (:attr:`abandoned` says
    why; see :mod:`hil.devices.audio.stream_release`).

    Parameters
    ----------
    settings:
        Validated stream settings.
    xrun_capacity:
        Number of xrun events the log keeps.
    """

    def __init__(self, settings: AudioSettings, *, xrun_capacity: int = 4096) -> None:
        self.settings = settings
        self._xrun_capacity = xrun_capacity
        self._runner: CallbackRunner | None = None
        self._stream: Any = None
        self._done = threading.Event()
        self._started = False
        self._longest_gap_s = 0.0
        self.device: DeviceInfo | None = None
        #: Why the stream was abandoned instead of stopped and closed; None when released.
        self.abandoned: str | None = None

    @property
    def active(self) -> bool:
        """True while the stream runs."""
        return self._stream is not None and bool(self._stream.active)

    @property
    def lost(self) -> bool:
        """True when the stream ended without finishing: its host took it away (PortAudio
        calls the finished callback whenever it ends a stream itself)."""
        stream = self._stream
        return (
            stream is not None and self._started and not stream.active and not self._done.is_set()
        )

    @property
    def frames_processed(self) -> int:
        """Frames handed to the callback since the stream opened."""
        return 0 if self._runner is None else self._runner.sample_index

    @property
    def xruns(self) -> list[tuple[int, StatusFlags]]:
        """Xruns of the current stream as ``(sample_index, flags)``."""
        return [] if self._runner is None else self._runner.xruns.events()

    @property
    def reported_latency_s(self) -> tuple[float, float]:
        """The driver's (input, output) latency claim in seconds; not trusted, see latency.py."""
        if self._stream is None:
            raise RuntimeError("open() the stream first")
        lat_in, lat_out = self._stream.latency
        return float(lat_in), float(lat_out)

    def describe(self) -> dict[str, Any]:
        """The PortAudio device this stream opened: its name, index and host API, and the
        driver's latency claims (s; not trusted: :mod:`hil.devices.audio.latency` measures)."""
        dev = self.device
        if dev is None:
            raise RuntimeError("open() the stream first")
        lat_in, lat_out = self.reported_latency_s
        return {
            "device": str(dev.name),
            "device_index": int(dev.index),
            "host_api": str(dev.hostapi),
            "input_latency_s": lat_in,
            "output_latency_s": lat_out,
        }

    def open(self, callback: AudioCallback) -> None:
        """Check the settings against the device, then create the stream (not started)."""
        check_callback(callback)
        if self._stream is not None:
            raise RuntimeError("the stream is already open: close() it first")
        sd = import_sounddevice()
        s = self.settings
        dev = find_device(s.device, list_devices(), s.channels_in, s.channels_out)
        self._check_samplerate(sd, dev)
        runner = CallbackRunner(callback, self._xrun_capacity)
        done = self._done
        done.clear()
        stop_exc, abort_exc = sd.CallbackStop, sd.CallbackAbort
        self._longest_gap_s = 0.0
        last = [math.inf]  # host time of the previous callback, s

        def pa_callback(indata: Any, outdata: Any, frames: int, time: Any, status: Any) -> None:
            now = monotonic()
            gap, last[0] = now - last[0], now
            if gap > self._longest_gap_s:
                self._longest_gap_s = gap
            outcome = runner.run_block(
                indata,
                outdata,
                frames,
                time.inputBufferAdcTime,
                time.outputBufferDacTime,
                time.currentTime,
                _flags_of(status) if status else 0,
            )
            if outcome is BlockOutcome.COMPLETE:
                raise stop_exc
            if outcome is BlockOutcome.ABORT:
                raise abort_exc

        self._stream = sd.Stream(
            samplerate=s.samplerate,
            blocksize=s.blocksize,
            device=dev.index,
            channels=(s.channels_in, s.channels_out),
            dtype=DTYPE,
            latency=s.latency,
            callback=pa_callback,
            finished_callback=done.set,
            dither_off=True,
        )
        self._runner = runner
        self._started = False
        self.abandoned = None
        self.device = dev

    def _check_samplerate(self, sd: ModuleType, dev: DeviceInfo) -> None:
        s = self.settings
        try:
            sd.check_input_settings(
                device=dev.index, channels=s.channels_in, dtype=DTYPE, samplerate=s.samplerate
            )
            sd.check_output_settings(
                device=dev.index, channels=s.channels_out, dtype=DTYPE, samplerate=s.samplerate
            )
        except sd.PortAudioError as exc:
            raise ConfigError(
                "samplerate",
                s.samplerate,
                f"a rate {dev.describe()} supports (its default is {dev.default_samplerate:g} "
                "Hz; a JACK device runs only at the server's rate)",
                f"PortAudio says: {exc}; set samplerate to the device's rate",
            ) from exc

    def start(self) -> None:
        """Start the stream: the callback runs from now on, in PortAudio's audio thread."""
        if self._stream is None:
            raise RuntimeError("open(callback) the stream before start()")
        self._stream.start()
        self._started = True

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until the stream ends; True if it has. Re-raises a callback exception."""
        running = self._stream is not None and self._started
        finished = self._done.wait(timeout_s) if running else True
        if finished and self._runner is not None:
            self._runner.raise_pending()
        return finished

    def stop(self) -> None:
        """Stop the stream (pending output still plays). Re-raises a callback exception.

        A lost stream gets no call (:meth:`close` abandons it); a stop that does not return
        in time abandons the stream."""
        stream = self._stream
        if stream is not None and self.abandoned is None and not self.lost:
            self._bounded(stream, lambda: stream.stop(ignore_errors=True), "stopping")
        if self._runner is not None:
            self._runner.raise_pending()

    def close(self) -> None:
        """Close the stream and release the device, or abandon it (see :meth:`stop`).
        Re-raises a callback exception."""
        lost = self.lost
        stream, self._stream = self._stream, None
        if stream is not None and self.abandoned is None:  # else a stop was abandoned
            if lost:
                self._abandon(
                    stream,
                    "its host ended it without finishing (a JACK server that shut down does "
                    "this); stopping or closing it would wait on that host",
                )
            else:
                self._bounded(stream, lambda: stream.close(ignore_errors=True), "closing")
        if self._runner is not None:
            self._runner.raise_pending()

    def _bounded(self, stream: Any, call: Callable[[], object], doing: str) -> None:
        """Run ``call`` (a stop or close of ``stream``) with a bounded wait; abandon the
        stream when it does not return."""
        timeout_s = release_timeout_s(self._longest_gap_s)
        if not call_bounded(call, timeout_s, f"PortAudio {doing}"):
            self._abandon(stream, f"{doing} it did not return within {timeout_s:.1f} s")

    def _abandon(self, stream: Any, why: str) -> None:
        where = self.device.describe() if self.device is not None else "its device"
        self.abandoned = f"the stream on {where}: {why}"
        abandon(stream, self.abandoned)

    def __enter__(self) -> SoundDeviceDuplex:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
