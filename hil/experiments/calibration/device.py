"""The play/record shape every calibration routine is written against, and its errors.

A routine never talks to a backend directly: it gets a :class:`PlayRecordDevice`, i.e. a
function that plays an output block and returns what the inputs captured over the same
sample indices, plus the sample rate and channel counts. :func:`from_duplex` wraps a
full-duplex audio backend (:mod:`hil.devices.audio`); the transducer board driver will offer
the same shape, and a test can wrap any simulated world.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hil.devices.audio.contract import DuplexBackend
from hil.devices.audio.playrec import play_record
from hil.errors import ConfigError

FloatArray = npt.NDArray[np.float64]
Float32Array = npt.NDArray[np.float32]

#: ``play_record(output)``: output (n, channels_out) float32, full scale +-1 -> recording
#: (n', channels_in) float32 with n' >= n; row k of both carries the same sample index.
PlayRecordFn = Callable[[Float32Array], Float32Array]


class CalibrationError(RuntimeError):
    """A measurement ran but its result cannot be trusted (open loop, weak echo, ...).

    The message says what was seen and what to check; the command line prints it on one line.
    """


@dataclass(frozen=True)
class PlayRecordDevice:
    """A device that plays and records at once (audio interface, board, simulated world).

    Attributes
    ----------
    play_record:
        See :data:`PlayRecordFn`. The routines append the silence they need to hear the
        whole response (the loop latency plus the longest echo) to the output themselves.
    samplerate:
        Sample rate of both directions, Hz.
    channels_out, channels_in:
        Number of output (DAC) and input (ADC) channels.
    name:
        What to print and store as the device (``"sim://audio"``, an interface name, ...).
    """

    play_record: PlayRecordFn
    samplerate: float
    channels_out: int = 1
    channels_in: int = 1
    name: str = "device"

    def __post_init__(self) -> None:
        if not (np.isfinite(self.samplerate) and self.samplerate > 0):
            raise ConfigError("samplerate", self.samplerate, "a finite number of Hz > 0")
        for field in ("channels_out", "channels_in"):
            n = getattr(self, field)
            if isinstance(n, bool) or not isinstance(n, int) or n < 1:
                raise ConfigError(field, n, "an integer >= 1")

    def run(self, output: npt.ArrayLike, tail_frames: int) -> Float32Array:
        """Play ``output`` ((n,) to every channel, or (n, channels_out)) then ``tail_frames``
        of silence; return the recording, shape (n + tail_frames, channels_in), float32."""
        x = np.asarray(output, dtype=np.float32)
        if x.ndim == 1:
            x = np.repeat(x[:, None], self.channels_out, axis=1)
        if x.ndim != 2 or x.shape[1] != self.channels_out:
            raise ConfigError(
                "output shape", x.shape, f"(n,) or (n, {self.channels_out})", "one column each"
            )
        padded = np.concatenate([x, np.zeros((tail_frames, self.channels_out), np.float32)])
        rec = np.asarray(self.play_record(padded), dtype=np.float32)
        if rec.ndim != 2 or rec.shape[0] < padded.shape[0] or rec.shape[1] != self.channels_in:
            raise CalibrationError(
                f"device {self.name!r} returned a recording of shape {rec.shape}, expected "
                f"({padded.shape[0]}, {self.channels_in}) or longer; check the driver"
            )
        return rec[: padded.shape[0]]


def from_duplex(backend: DuplexBackend, name: str = "audio") -> PlayRecordDevice:
    """Wrap a closed full-duplex audio backend (opened, run and closed at every call).

    Examples
    --------
    >>> from hil.devices.audio import AudioSettings, DigitalLoopbackWorld, SimulatedDuplex
    >>> sim = SimulatedDuplex(AudioSettings(48000, blocksize=64), DigitalLoopbackWorld(3))
    >>> dev = from_duplex(sim, "sim://audio")
    >>> rec = dev.run(np.array([1.0, 0.0, 0.0]), tail_frames=200)
    >>> rec.shape, int(np.argmax(rec[:, 0]))   # 2 blocks of I/O delay + 3 samples of cable
    ((203, 1), 131)
    """

    def run(output: Float32Array) -> Float32Array:
        return play_record(backend, output).recording

    return PlayRecordDevice(
        play_record=run,
        samplerate=backend.samplerate,
        channels_out=backend.channels_out,
        channels_in=backend.channels_in,
        name=name,
    )


def check_channel(field: str, channel: int, count: int) -> int:
    """``channel`` if it is an index in ``[0, count)``, else a :class:`ConfigError`."""
    if isinstance(channel, bool) or not isinstance(channel, int) or not 0 <= channel < count:
        raise ConfigError(field, channel, f"an integer in [0, {count})", "count from 0")
    return channel


def check_positive_int(field: str, value: int, minimum: int = 1) -> int:
    """``value`` if it is an integer >= ``minimum``, else a :class:`ConfigError`."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(field, value, f"an integer >= {minimum}")
    return value
