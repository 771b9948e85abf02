"""The real-time callback contract shared by every full-duplex audio backend.

Both :class:`~hil.devices.audio.portaudio_backend.SoundDeviceDuplex` (a real interface through
PortAudio) and :class:`~hil.devices.audio.simulated.SimulatedDuplex` (a simulated one) call
the same user callback with the same arguments, modelled on python-sounddevice's ``Stream``::

    def callback(indata, outdata, frames, time, status) -> None

``indata`` : numpy.ndarray, shape (frames, channels_in), dtype float32
    The ADC samples of this block, full scale +-1.0. Read it during the call only: the
    buffer is reused for the next block, so copy what you keep (``rec[i:i+frames] = indata``).
``outdata`` : numpy.ndarray, shape (frames, channels_out), dtype float32
    The DAC samples of this block; the callback must fill every element (``outdata[:] = ...``,
    never ``outdata = ...``). Values outside +-1.0 clip in the converter.
``frames`` : int
    Number of frames in this block (the stream's fixed block size).
``time`` : :class:`BlockTime`
    ``sample_index``: running index of the first frame of this block, counted in frames
    handed to the callback since the stream started (0 for the first block). Input and
    output share it: ``indata[k]`` and ``outdata[k]`` both carry sample index
    ``sample_index + k``. The loopback latency is measured, not assumed: an output sample
    sent at index n comes back in the input at index n + latency (see
    :mod:`hil.devices.audio.latency`).
    ``input_adc_time_s``: the time (s, on the stream's clock) when the first input frame of
    the block was captured by the ADC. ``output_dac_time_s``: the time when the first output
    frame will leave the DAC. ``current_time_s``: the time when the callback was invoked.
    These are PortAudio's inputBufferAdcTime, outputBufferDacTime and currentTime; they come
    from the driver and are only as good as the driver's latency report.
``status`` : :class:`StatusFlags`
    Non-zero when the driver reports an xrun for this block: ``INPUT_OVERFLOW`` (input
    samples were lost before this block), ``INPUT_UNDERFLOW`` (input is padded with
    zeros), ``OUTPUT_UNDERFLOW`` (a gap was played before this block), ``OUTPUT_OVERFLOW``
    (output is discarded), ``PRIMING_OUTPUT`` (the output is pre-filling buffers). Every
    non-zero status is also logged by the backend as ``(sample_index, flags)``.

Ending the stream: raise :class:`CallbackStop` to end after this block (its output is still
played). Raising any other exception stops the stream at once (the block's output is
silenced), and the backend re-raises that same exception in the host thread from
``wait()``, ``stop()`` or ``close()``; the audio thread itself never prints or swallows it.

Real-time rules: the callback runs in the audio thread, once per block, with a hard deadline
of ``frames / samplerate`` seconds. It must never block (no locks held by other threads, no
I/O, no ``print``, no sleeping) and never allocate buffers: preallocate every array before
the stream starts and write into slices of it. Whole-block numpy slice copies are fine; per-
sample Python loops are not.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from hil.errors import ConfigError

FloatArray = npt.NDArray[np.float32]

#: The only sample format of the audio backends (full scale +-1.0).
DTYPE = "float32"


class StatusFlags(enum.IntFlag):
    """Xrun flags of one block, with PortAudio's ``paInputUnderflow``... bit values.

    Examples
    --------
    >>> StatusFlags(6) == StatusFlags.INPUT_OVERFLOW | StatusFlags.OUTPUT_UNDERFLOW
    True
    >>> bool(StatusFlags(0))
    False
    """

    INPUT_UNDERFLOW = 1
    INPUT_OVERFLOW = 2
    OUTPUT_UNDERFLOW = 4
    OUTPUT_OVERFLOW = 8
    PRIMING_OUTPUT = 16


_NO_FLAGS = StatusFlags(0)


class CallbackStop(Exception):
    """Raise in the callback to end the stream after the current block (output still plays)."""


class BlockTime:
    """Timestamps of one block (see the module docstring for their meaning).

    One instance per stream is updated in place before each call, so the hot path allocates
    nothing: keep :meth:`copy` if you need the values after the callback returns.

    Attributes
    ----------
    sample_index:
        Index of the first frame of the block, in frames since the stream started.
    input_adc_time_s, output_dac_time_s, current_time_s:
        Capture time of the first input frame, emission time of the first output frame and
        callback invocation time, in seconds on the stream's clock.

    Examples
    --------
    >>> t = BlockTime()
    >>> t.sample_index, t.current_time_s
    (0, 0.0)
    """

    __slots__ = ("current_time_s", "input_adc_time_s", "output_dac_time_s", "sample_index")

    def __init__(self) -> None:
        self.sample_index = 0
        self.input_adc_time_s = 0.0
        self.output_dac_time_s = 0.0
        self.current_time_s = 0.0

    def copy(self) -> BlockTime:
        """An independent copy of the current values."""
        other = BlockTime()
        other.sample_index = self.sample_index
        other.input_adc_time_s = self.input_adc_time_s
        other.output_dac_time_s = self.output_dac_time_s
        other.current_time_s = self.current_time_s
        return other

    def __repr__(self) -> str:
        return (
            f"BlockTime(sample_index={self.sample_index}, "
            f"input_adc_time_s={self.input_adc_time_s!r}, "
            f"output_dac_time_s={self.output_dac_time_s!r}, "
            f"current_time_s={self.current_time_s!r})"
        )


class AudioCallback(Protocol):
    """The user callback: ``callback(indata, outdata, frames, time, status) -> None``."""

    def __call__(
        self,
        indata: FloatArray,
        outdata: FloatArray,
        frames: int,
        time: BlockTime,
        status: StatusFlags,
        /,
    ) -> None: ...


class DuplexBackend(Protocol):
    """What every full-duplex backend offers (real and simulated alike).

    Life cycle: ``open(callback)`` (validates against the device, allocates, creates the
    stream; nothing runs yet) -> ``start()`` -> ``wait()`` until the callback raises
    :class:`CallbackStop` or ``stop()`` -> ``close()``. The backend is a context manager that
    closes on exit.
    """

    @property
    def samplerate(self) -> float: ...
    @property
    def channels_in(self) -> int: ...
    @property
    def channels_out(self) -> int: ...
    @property
    def blocksize(self) -> int: ...
    @property
    def active(self) -> bool: ...
    @property
    def frames_processed(self) -> int: ...
    @property
    def xruns(self) -> list[tuple[int, StatusFlags]]: ...
    @property
    def abandoned(self) -> str | None:
        """Why the stream was abandoned instead of stopped and closed (its host went away:
        :mod:`hil.devices.audio.stream_release`), or None."""

    def describe(self) -> dict[str, Any]:
        """What is connected, for the run's record of its devices (opened): ``device`` and
        ``host_api`` (str), ``input_latency_s`` (s) and what else the backend knows of its
        latency."""

    def open(self, callback: AudioCallback) -> None: ...
    def start(self) -> None: ...
    def wait(self, timeout_s: float | None = None) -> bool: ...
    def stop(self) -> None: ...
    def close(self) -> None: ...
    def __enter__(self) -> Any: ...
    def __exit__(self, *exc: object) -> None: ...


class XrunLog:
    """Preallocated log of xruns as ``(sample_index, flags)`` events.

    Recording an event writes two integers into fixed arrays; events beyond ``capacity``
    are counted in :attr:`dropped` instead of growing a list in the audio thread.

    Examples
    --------
    >>> log = XrunLog(capacity=2)
    >>> log.record(512, 2); log.record(1024, 4); log.record(2048, 6)
    >>> log.events()
    [(512, <StatusFlags.INPUT_OVERFLOW: 2>), (1024, <StatusFlags.OUTPUT_UNDERFLOW: 4>)]
    >>> log.dropped
    1
    """

    def __init__(self, capacity: int = 4096) -> None:
        self._index = np.zeros(capacity, dtype=np.int64)
        self._flags = np.zeros(capacity, dtype=np.int64)
        self._count = 0
        self.dropped = 0

    def clear(self) -> None:
        """Forget every event (called when a stream opens)."""
        self._count = 0
        self.dropped = 0

    def record(self, sample_index: int, flags: int) -> None:
        """Log one xrun at ``sample_index`` (first frame of the block that reported it)."""
        if self._count < self._index.shape[0]:
            self._index[self._count] = sample_index
            self._flags[self._count] = flags
            self._count += 1
        else:
            self.dropped += 1

    def events(self) -> list[tuple[int, StatusFlags]]:
        """The logged events, oldest first."""
        n = self._count
        return [
            (int(i), StatusFlags(int(f)))
            for i, f in zip(self._index[:n], self._flags[:n], strict=True)
        ]

    def __len__(self) -> int:
        return self._count


class BlockOutcome(enum.IntEnum):
    """What the backend does after a block: go on, finish, or abort on an error."""

    CONTINUE = 0
    COMPLETE = 1
    ABORT = 2


class CallbackRunner:
    """Runs the user callback for a backend: sample index, timestamps, xrun log, errors.

    Both backends call :meth:`run_block` once per block from their audio thread, so the
    contract (what ``time`` and ``status`` hold, what raising does) is implemented once.
    """

    def __init__(self, callback: AudioCallback, xrun_capacity: int = 4096) -> None:
        self.callback = callback
        self.time = BlockTime()
        self.xruns = XrunLog(xrun_capacity)
        self.sample_index = 0
        self.error: BaseException | None = None

    def run_block(
        self,
        indata: FloatArray,
        outdata: FloatArray,
        frames: int,
        input_adc_time_s: float,
        output_dac_time_s: float,
        current_time_s: float,
        flags: int,
    ) -> BlockOutcome:
        """Call the user callback for one block and advance the sample index."""
        t = self.time
        t.sample_index = self.sample_index
        t.input_adc_time_s = input_adc_time_s
        t.output_dac_time_s = output_dac_time_s
        t.current_time_s = current_time_s
        status = _NO_FLAGS
        if flags:
            status = StatusFlags(flags)
            self.xruns.record(self.sample_index, flags)
        outcome = BlockOutcome.CONTINUE
        try:
            self.callback(indata, outdata, frames, t, status)
        except CallbackStop:
            outcome = BlockOutcome.COMPLETE
        except BaseException as exc:  # re-raised in the host thread by raise_pending()
            self.error = exc
            outdata.fill(0.0)
            outcome = BlockOutcome.ABORT
        self.sample_index += frames
        return outcome

    def raise_pending(self) -> None:
        """Re-raise, once, the exception the callback raised (in the host thread)."""
        exc, self.error = self.error, None
        if exc is not None:
            raise exc


def check_callback(callback: Callable[..., object]) -> None:
    """Reject a non-callable callback before a stream is opened."""
    if not callable(callback):
        raise ConfigError(
            "callback",
            callback,
            "a callable (indata, outdata, frames, time, status) -> None",
            "pass a function, e.g. the one play_record builds",
        )
