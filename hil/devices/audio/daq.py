"""An audio interface as the DAC/ADC of a run: the subset of the ``Board`` API the tank runner
uses, on top of a full-duplex audio backend.

:class:`AudioDaq` wraps a :class:`~hil.devices.audio.contract.DuplexBackend` (a real
:class:`~hil.devices.audio.portaudio_backend.SoundDeviceDuplex` or a
:class:`~hil.devices.audio.simulated.SimulatedDuplex`) and offers what
:func:`hil.experiments.tank_run.run_experiment` calls on a board: ``open()``,
``configure()``, ``start(source) -> start_index``, ``wait_for_samples``, ``read``,
``clock_fit``, ``ring``, ``annotations``, ``last_status``, ``stop()``, ``close()``.

Wiring (two in, two out): the DAC source drives both outputs (output 1: the transmitter's
amplifier; output 2: a cable to input 2, the DAC monitor the runner measures the loopback
latency on); input 1 is the hydrophone, input 2 whatever the interface gives there.

In the audio callback, for the block of ``frames`` samples starting at stream index ``j``:

- the source fills the DAC: ``source(j, frames)`` returns float samples, full scale +-1.0,
  shape (frames,), written to every output channel;
- the captured block, converted to int16 counts (``round(x * 32768)``, clipped), goes into a
  :class:`~hil.acquisition.SampleRing` at indices ``j ... j + frames - 1``;
- a sync stamp pairs index ``j`` with the host-clock time output sample ``j`` leaves the
  DAC: the host clock now, plus the driver's lead of the block (``output_dac_time_s -
  current_time_s``). A run's sample time is the transmit time, as on the board, whose DAC and
  ADC share one index and one clock: the receiver refers every echo to transmit time by the
  measured loopback latency, which holds the interface's input and output buffering, so the
  stage telemetry, mapped to sample indices by these pairs, lines up with the estimates
  whatever the block size (stamped with the capture time of input ``j`` instead, it would
  lag them by the interface's two blocks of buffering).
  Per ``sync_interval_s`` the least-delayed stamp is kept (the same minimum-delay rule the
  runner applies afterwards) and handed to :attr:`AudioDaq.clock_fit` on the host side.

Xruns reported by the backend become annotations (``adc_overrun`` for input flags,
``dac_underrun`` for output flags) when :attr:`AudioDaq.annotations` or
:attr:`AudioDaq.last_status` is read, so the audio thread never takes the annotation lock.

URL form for the runner's ``devices.board``: ``audio://DEVICE?rate=192000&blocksize=256``,
DEVICE a device index or a name substring (``python -m sounddevice`` lists them);
``sim://audio?rate=...&delay=N`` is the simulated interface (every simulated device is
``sim://DEVICE``), on its own a digital loopback ``N`` samples long paced in real time, in
a simulated tank run the tank's acoustics (see :func:`parse_audio_url`). ``audio://sim`` is
still read as ``sim://audio``, with a deprecation warning.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qsl, unquote, urlsplit, urlunsplit

import numpy as np
import numpy.typing as npt

from hil.acquisition.annotations import (
    ADC_CLIPPING_TEXT,
    Annotation,
    AnnotationKind,
    AnnotationLog,
)
from hil.acquisition.clock_fit import SampleClockFit
from hil.acquisition.ring import SampleRing
from hil.devices.audio.contract import BlockTime, DuplexBackend, FloatArray, StatusFlags
from hil.devices.audio.settings import AudioSettings
from hil.errors import ConfigError, DeviceLost

if TYPE_CHECKING:
    from hil.devices.clock import VirtualClock

_LOG = logging.getLogger(__name__)

#: ``source(first, n)``: DAC samples for stream indices ``first ... first + n - 1``, float,
#: full scale +-1.0, shape (n,).
DacSource = Callable[[int, int], npt.NDArray[Any]]

AUDIO_SCHEME = "audio"
SIM_DEVICE = "sim"
#: The simulated audio interface's URL (scheme ``sim``, as ``sim://board`` and ``sim://stage``).
SIM_AUDIO_URL = "sim://audio"
#: Its former spelling, still read (with a deprecation warning).
DEPRECATED_SIM_AUDIO_URL = "audio://sim"
CHANNELS = 2
_INT16_FULL_SCALE = 32768.0
_INPUT_FLAGS = StatusFlags.INPUT_OVERFLOW | StatusFlags.INPUT_UNDERFLOW
_OUTPUT_FLAGS = StatusFlags.OUTPUT_UNDERFLOW | StatusFlags.OUTPUT_OVERFLOW
_URL_KEYS = ("rate", "blocksize", "latency", "delay")
_URL_FORM = (
    "audio://DEVICE?rate=192000&blocksize=256 (DEVICE: an index or a name substring) or "
    "sim://audio?rate=192000 (the simulated interface)"
)


class AudioStreamLost(DeviceLost, RuntimeError):
    """The interface's stream ended while the run still needed samples (unplugged, powered
    off, taken by another program); the message names its URL."""


@dataclass(frozen=True)
class AudioUrl:
    """A parsed ``audio://`` board URL.

    ``device`` is None (the default device), an index, a name substring, or ``"sim"`` (the
    simulated interface, ``sim://audio``); ``samplerate_hz`` None when the URL does not say
    (the experiment's rate is used); ``delay_samples`` is the simulated loopback delay
    (``sim://audio`` only).
    """

    device: str | int | None
    samplerate_hz: int | None
    blocksize: int
    latency: str | float
    delay_samples: int

    @property
    def simulated(self) -> bool:
        """True for ``sim://audio``."""
        return self.device == SIM_DEVICE

    def settings(
        self,
        samplerate: float,
        channels_in: int = CHANNELS,
        channels_out: int = CHANNELS,
        blocksize: int | None = None,
    ) -> AudioSettings:
        """The stream this URL asks for at ``samplerate`` Hz with these channel counts;
        ``blocksize`` frames (default the URL's)."""
        return AudioSettings(
            samplerate=samplerate,
            channels_in=channels_in,
            channels_out=channels_out,
            blocksize=self.blocksize if blocksize is None else blocksize,
            latency=self.latency,
            device=None if self.simulated else self.device,
        )


def canonical_audio_url(url: str) -> str:
    """``url`` with the simulated interface spelled ``sim://audio``: the former spelling
    ``audio://sim`` is rewritten (and a deprecation warning logged); any other URL is
    returned as it is.

    >>> canonical_audio_url("audio://sim?rate=48000&delay=7")
    'sim://audio?rate=48000&delay=7'
    >>> canonical_audio_url("audio://JACK?rate=48000")
    'audio://JACK?rate=48000'
    """
    parts = urlsplit(url)
    if parts.scheme != AUDIO_SCHEME or unquote(parts.netloc).strip() != SIM_DEVICE:
        return url
    canonical = urlunsplit(("sim", "audio", parts.path, parts.query, parts.fragment))
    _LOG.warning(
        "%s is deprecated: write %s (every simulated device is sim://DEVICE)", url, canonical
    )
    return canonical


def is_audio_url(url: str) -> bool:
    """True for a URL :func:`parse_audio_url` reads: ``audio://...``, ``sim://audio...``.

    >>> is_audio_url("sim://audio?rate=48000"), is_audio_url("sim://board")
    (True, False)
    """
    parts = urlsplit(url)
    return parts.scheme == AUDIO_SCHEME or (parts.scheme == "sim" and parts.netloc == "audio")


def parse_audio_url(url: str) -> AudioUrl:
    """Parse ``audio://DEVICE?rate=HZ&blocksize=N[&latency=low|high|S]`` (a real
    interface) or ``sim://audio?rate=HZ&blocksize=N[&delay=N]`` (the simulated one).

    Examples
    --------
    >>> parse_audio_url("audio://2?rate=192000&blocksize=512")
    AudioUrl(device=2, samplerate_hz=192000, blocksize=512, latency='low', delay_samples=0)
    >>> parse_audio_url("audio://Scarlett%202i2").device
    'Scarlett 2i2'
    >>> parse_audio_url("sim://audio?delay=7").simulated
    True
    >>> parse_audio_url("sim://audio?rate=48k")
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: devices.board rate = '48k' is not allowed: must be a whole number \
of Hz; e.g. audio://JACK?rate=192000
    """
    parts = urlsplit(canonical_audio_url(url))
    if not is_audio_url(parts.geturl()) or parts.path not in ("", "/") or parts.fragment:
        raise ConfigError("devices.board", url, _URL_FORM, "check the URL's spelling")
    name = unquote(parts.netloc).strip()
    device: str | int | None = int(name) if name.isdigit() else (name or None)
    if parts.scheme == "sim":
        device = SIM_DEVICE
    query: dict[str, str] = {}
    for key, value in parse_qsl(parts.query, keep_blank_values=True, strict_parsing=False):
        if key not in _URL_KEYS:
            raise ConfigError(
                "devices.board query key", key, f"one of {', '.join(_URL_KEYS)}", _URL_FORM
            )
        query[key] = value
    rate = _whole(query, "rate", None, "of Hz", "e.g. audio://JACK?rate=192000")
    block = _whole(query, "blocksize", 256, "of frames", "e.g. blocksize=256")
    delay = _whole(query, "delay", 0, "of samples", "the simulated loopback delay, e.g. delay=64")
    if "delay" in query and device != SIM_DEVICE:
        raise ConfigError(
            "devices.board delay", query["delay"], "only with sim://audio", "remove it"
        )
    latency: str | float = query.get("latency", "low")
    if latency not in ("low", "high"):
        try:
            latency = float(latency)
        except ValueError:
            raise ConfigError(
                "devices.board latency", latency, "low, high or seconds", "e.g. latency=low"
            ) from None
    return AudioUrl(device, rate, block, latency, delay)


def _whole(query: dict[str, str], key: str, default: int | None, unit: str, hint: str) -> Any:
    text = query.get(key)
    if text is None:
        return default
    if not text.isdigit():
        raise ConfigError(f"devices.board {key}", text, f"a whole number {unit}", hint)
    return int(text)


def audio_settings(url: str, sample_rate_hz: int | None) -> tuple[AudioUrl, AudioSettings]:
    """The parsed ``url`` and the interface settings it asks for: 2 in, 2 out, at the URL's
    ``rate`` or else ``sample_rate_hz`` (the rate the run needs; a URL ``rate`` that differs
    is refused)."""
    spec = parse_audio_url(url)
    rate = spec.samplerate_hz if spec.samplerate_hz is not None else sample_rate_hz
    if rate is None:
        raise ConfigError("devices.board rate", None, "a whole number of Hz", _URL_FORM)
    if sample_rate_hz is not None and rate != sample_rate_hz:
        raise ConfigError(
            "devices.board rate",
            rate,
            f"the waveform's rate {sample_rate_hz} Hz",
            "the interface runs the waveform's sample rate: change one to match",
        )
    return spec, spec.settings(rate)


@dataclass(frozen=True)
class AudioDaqStatus:
    """Counters of the stream so far: frames captured, xrun blocks by direction."""

    frames: int
    """Frames handed to the callback since start."""
    overruns: int
    """Blocks with input xrun flags (samples lost or padded before them)."""
    underruns: int
    """Blocks with output xrun flags (a gap was played before them)."""

    # The board's Status names, so a run reads either device's counters the same way.
    @property
    def dac_underruns(self) -> int:
        """:attr:`underruns`, by the board's name for it."""
        return self.underruns

    @property
    def adc_overruns(self) -> int:
        """:attr:`overruns`, by the board's name for it."""
        return self.overruns


class AudioDaq:
    """An audio interface used as the run's DAC/ADC, with the Board API the runner uses.

    Parameters
    ----------
    backend:
        A full-duplex backend with 2 input and 2 output channels, not opened yet.
    ring_seconds:
        Capture kept in :attr:`ring`, s.
    host_clock:
        The host clock the sync pairs use, s (``time.monotonic``, the stage's clock, by
        default; a simulated backend's clock in tests).
    sync_interval_s:
        One sync pair per interval (the least-delayed stamp in it), s; 0 keeps one per block.
    virtual_time:
        The virtual clock a simulated backend runs its blocks on (in the host's thread, as
        a service of the clock): waits for samples then let virtual time pass on it
        instead of blocking. None for a backend with its own audio thread.

    Sample indices are the stream's: 0 is the first sample of the first callback, and DAC
    index ``n`` comes back on the ADC at ``n + latency`` (measured, not assumed).
    """

    def __init__(
        self,
        backend: DuplexBackend,
        *,
        ring_seconds: float = 8.0,
        host_clock: Callable[[], float] = time.monotonic,
        sync_interval_s: float = 0.1,
        virtual_time: VirtualClock | None = None,
        url: str = "audio interface",
    ) -> None:
        for name, n in (
            ("channels_in", backend.channels_in),
            ("channels_out", backend.channels_out),
        ):
            if n != CHANNELS:
                raise ConfigError(
                    name,
                    n,
                    f"{CHANNELS} (in 1 hydrophone, in 2 DAC monitor; outs 1 and 2 the DAC)",
                    "build the backend's AudioSettings with 2 in and 2 out",
                )
        if not (math.isfinite(ring_seconds) and ring_seconds > 0):
            raise ConfigError("ring_seconds", ring_seconds, "> 0 s")
        if not (math.isfinite(sync_interval_s) and sync_interval_s >= 0):
            raise ConfigError("sync_interval_s", sync_interval_s, ">= 0 s")
        self.backend = backend
        #: The interface's URL, as its errors name it.
        self.url = url
        self._virtual = virtual_time
        fs = backend.samplerate
        self.fs_hz = float(fs)
        self.ring: SampleRing | None = None
        self.annotations = _XrunAnnotations(self)
        self._ring_frames = max(int(round(ring_seconds * fs)), 2 * backend.blocksize)
        self._host_clock = host_clock
        self._sync_frames = max(1, int(round(sync_interval_s * fs)))
        self._fit = SampleClockFit(fs, max_pairs=256)
        # Sync pairs handed from the audio thread (deque.append is atomic in CPython).
        self._pending_pairs: deque[tuple[int, float]] = deque()
        self._best: tuple[int, float] | None = None
        self._best_offset = math.inf
        self._window_end = 0
        self._source: DacSource | None = None
        self._xruns_seen = 0
        self._overruns = 0
        #: Input values at or beyond full scale since start (every channel): clipping.
        self.adc_clipped_samples = 0
        self._clipped_blocks: list[tuple[int, int]] = []
        self._clipped_seen = 0
        self._underruns = 0
        self._opened = False
        self._started = False
        block = backend.blocksize
        self._scaled = np.zeros((block, CHANNELS), dtype=np.float32)
        self._counts = np.zeros((block, CHANNELS), dtype=np.int16)

    @classmethod
    def from_url(
        cls,
        url: str,
        *,
        sample_rate_hz: int | None = None,
        ring_seconds: float = 8.0,
        host_clock: Callable[[], float] = time.monotonic,
    ) -> AudioDaq:
        """The adapter for an ``audio://`` URL (nothing is opened yet).

        ``sample_rate_hz`` is the rate the run needs (the waveform's); a URL ``rate`` that
        differs is refused. ``sim://audio`` runs a :class:`SimulatedDuplex` paced in real
        time with a digital loopback of ``delay`` samples on both channels.
        """
        spec, settings = audio_settings(url, sample_rate_hz)
        backend: DuplexBackend
        if spec.simulated:
            from sim_devices.audio.simulated import (
                DigitalLoopbackWorld,
                RealtimeClock,
                SimulatedDuplex,
            )

            clock = RealtimeClock()
            backend = SimulatedDuplex(
                settings, DigitalLoopbackWorld(spec.delay_samples), clock=clock
            )
            host_clock = clock.now
        else:
            from hil.devices.audio.portaudio_backend import SoundDeviceDuplex

            backend = SoundDeviceDuplex(settings)
        return cls(backend, ring_seconds=ring_seconds, host_clock=host_clock, url=url)

    # --- the Board API the runner uses ---
    def open(self) -> AudioDaq:
        """Check the settings against the device and create the stream (nothing runs)."""
        if not self._opened:
            self.backend.open(self._callback)
            self._opened = True
        return self

    def configure(self) -> None:
        """Nothing left to send: rate, block size and channels were checked by ``open()``."""
        if not self._opened:
            raise RuntimeError("open() the audio DAQ before configure()")

    def start(self, source: DacSource) -> int:
        """Start transmitting ``source`` and capturing; the stream index of the first sample."""
        if not self._opened:
            raise RuntimeError("open() the audio DAQ before start()")
        if self._started:
            raise RuntimeError("the audio DAQ already started: open a new one to rerun")
        if not callable(source):
            raise ConfigError("source", source, "a callable source(first, n) -> (n,) floats")
        self._source = source
        self.ring = SampleRing(self._ring_frames, CHANNELS, np.int16)
        self._started = True
        self.backend.start()
        return 0

    def wait_for_samples(self, end: int, timeout_s: float) -> bool:
        """True once every sample before index ``end`` is captured, False after ``timeout_s``.

        Raises the exception that ended the stream (e.g. one from the source), or
        :class:`AudioStreamLost` if the stream ended before ``end`` (the interface went
        away).
        """
        if self.ring is None:
            raise RuntimeError("start() the audio DAQ before waiting for samples")
        if self._virtual is not None:
            ring, backend = self.ring, self.backend
            if (
                self._virtual.wait_until(
                    lambda: (ring.end_index or 0) >= end or not backend.active, timeout_s
                )
                and (ring.end_index or 0) >= end
            ):
                return True
        elif self.ring.wait_for(end, timeout_s):
            return True
        if not self.backend.active:
            self.backend.wait(0.0)  # re-raises what stopped the stream, if anything did
            if self.ring.wait_for(end, 0.0):
                return True
            raise AudioStreamLost(
                f"the audio stream ended at sample {self.ring.end_index}, before {end}: check"
                " the interface's cable and power (on JACK: that its server still runs), and that"
                " no other program took it",
                url=self.url,
            )
        return False

    def read(self, first: int, n: int) -> npt.NDArray[np.int16]:
        """Captured samples ``first ... first + n - 1``, int16 counts, shape (n, 2)."""
        if self.ring is None:
            raise RuntimeError("start() the audio DAQ before reading")
        return self.ring.read(first, n)

    @property
    def clock_fit(self) -> SampleClockFit:
        """Host time (s) <-> stream sample index, from the sync pairs received so far."""
        while self._pending_pairs:
            index, host_t = self._pending_pairs.popleft()
            self._fit.add(index, host_t)
        return self._fit

    @property
    def last_status(self) -> AudioDaqStatus:
        """Frames so far and xrun counts (also logged as annotations)."""
        self._collect_xruns()
        return AudioDaqStatus(self.backend.frames_processed, self._overruns, self._underruns)

    def stop(self) -> None:
        """Stop the stream (transmission off). Re-raises an exception from the callback."""
        try:
            self.backend.stop()
        finally:
            self._flush_sync()
            self._collect_xruns()

    def close(self) -> None:
        """Release the device. Re-raises an exception from the callback not yet raised.

        A stream the backend had to abandon (its host went away, see
        :mod:`hil.devices.audio.stream_release`) is recorded as a ``disconnect``
        annotation at the last captured sample, saying why."""
        try:
            self.backend.close()
        finally:
            abandoned = self.backend.abandoned
            if abandoned is not None and not self.annotations.log.of_kind(
                AnnotationKind.DISCONNECT
            ):
                end = (self.ring.end_index or 0) if self.ring is not None else 0
                self.annotations.log.add(
                    Annotation(end, AnnotationKind.DISCONNECT, 0, f"{self.url}: {abandoned}")
                )

    def __enter__(self) -> AudioDaq:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        try:
            self.stop()
        finally:
            self.close()

    # --- audio thread ---
    def _callback(
        self,
        indata: FloatArray,
        outdata: FloatArray,
        frames: int,
        time: BlockTime,
        status: StatusFlags,
    ) -> None:
        # Real-time path: only whole-block numpy work into preallocated arrays (the source
        # renders its block and the ring copies it under a briefly held lock).
        j = time.sample_index
        assert self._source is not None and self.ring is not None
        dac = np.asarray(self._source(j, frames))
        outdata[:] = dac.reshape(frames, 1)
        scaled, counts = self._scaled[:frames], self._counts[:frames]
        np.multiply(indata, _INT16_FULL_SCALE, out=scaled)
        np.rint(scaled, out=scaled)
        # An input at either rail (±1.0 full scale) is clipping: the interface's converter
        # delivers floats it already limited to ±1. Counted, and raised as an alarm when the
        # annotations are next read (nothing is allocated unless it clipped).
        over = int(np.count_nonzero(scaled > _INT16_FULL_SCALE - 1.0))
        over += int(np.count_nonzero(scaled <= -_INT16_FULL_SCALE))
        if over:
            self.adc_clipped_samples += over
            self._clipped_blocks.append((j, over))
        np.clip(scaled, -_INT16_FULL_SCALE, _INT16_FULL_SCALE - 1.0, out=scaled)
        counts[:] = scaled
        self.ring.write(j, counts)
        # Negative when the callback runs late (its output is already due): still exact.
        lead = time.output_dac_time_s - time.current_time_s
        if not -1.0 <= lead <= 1.0:
            lead = 0.0  # a driver without usable timestamps: stamp on arrival
        host_t = self._host_clock() + lead
        if j >= self._window_end:
            self._flush_sync()
            self._window_end = j + self._sync_frames
        offset = host_t - j / self.fs_hz
        if offset < self._best_offset:
            self._best, self._best_offset = (j, host_t), offset

    def _flush_sync(self) -> None:
        if self._best is not None:
            self._pending_pairs.append(self._best)
            self._best, self._best_offset = None, math.inf

    def _collect_xruns(self) -> None:
        events = self.backend.xruns
        for index, flags in events[self._xruns_seen :]:
            kinds = []
            if flags & _INPUT_FLAGS:
                self._overruns += 1
                kinds.append(AnnotationKind.ADC_OVERRUN)
            if flags & _OUTPUT_FLAGS:
                self._underruns += 1
                kinds.append(AnnotationKind.DAC_UNDERRUN)
            for kind in kinds:
                self.annotations.log.add(Annotation(index, kind, 0, f"audio xrun {flags!r}"))
        self._xruns_seen = len(events)
        blocks = self._clipped_blocks
        for index, count in blocks[self._clipped_seen :]:
            self.annotations.log.add(
                Annotation(index, AnnotationKind.ALARM, 0, f"{ADC_CLIPPING_TEXT}: {count} values")
            )
        self._clipped_seen = len(blocks)


class _XrunAnnotations:
    """The annotation log, brought up to date with the backend's xruns when read."""

    def __init__(self, daq: AudioDaq) -> None:
        self._daq = daq
        self.log = AnnotationLog()

    def all(self) -> list[Annotation]:
        """Every annotation so far, in arrival order."""
        self._daq._collect_xruns()
        return self.log.all()

    def of_kind(self, kind: AnnotationKind) -> list[Annotation]:
        """The annotations of one kind."""
        return [a for a in self.all() if a.kind is kind]

    def count(self, kind: AnnotationKind) -> int:
        """How many annotations of ``kind``."""
        return len(self.of_kind(kind))
