"""Play a signal and record the input at the same time, on any full-duplex backend.

The common case of tests and calibration: the whole output is known in advance, so the
callback only copies preallocated slices (no allocation in the audio thread).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hil.devices.audio.contract import (
    BlockTime,
    CallbackStop,
    DuplexBackend,
    FloatArray,
    StatusFlags,
)
from hil.errors import ConfigError


@dataclass(frozen=True)
class PlayRecording:
    """Result of :func:`play_record`.

    Attributes
    ----------
    recording:
        Input samples, shape (frames, channels_in), float32, full scale +-1.0; row ``n`` has
        sample index ``n`` (the same index as output row ``n``).
    xruns:
        ``(sample_index, flags)`` of every block that reported an xrun.
    samplerate:
        Sample rate (Hz).
    """

    recording: FloatArray
    xruns: list[tuple[int, StatusFlags]]
    samplerate: float


def as_output_frames(signal: npt.ArrayLike, channels_out: int) -> FloatArray:
    """The output as a C-contiguous float32 array (frames, channels_out).

    A 1-D signal goes to every output channel. Samples must be finite and within +-1.0
    (full scale): the converter would clip them.

    Examples
    --------
    >>> as_output_frames([0.5, -0.5], 2).tolist()
    [[0.5, 0.5], [-0.5, -0.5]]
    >>> as_output_frames([2.0], 1)
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: output peak = 2.0 is not allowed: must be finite samples within \
+-1.0 (full scale); scale the signal down
    """
    x = np.asarray(signal, dtype=np.float32)
    if x.ndim == 1:
        x = np.repeat(x[:, None], channels_out, axis=1)
    if x.ndim != 2 or x.shape[1] != channels_out or x.shape[0] == 0:
        raise ConfigError(
            "output shape",
            x.shape,
            f"(frames,) or (frames, {channels_out}) with frames >= 1",
            "give one column per output channel",
        )
    peak = float(np.max(np.abs(x)))
    if not np.isfinite(peak) or peak > 1.0:
        raise ConfigError(
            "output peak", peak, "finite samples within +-1.0 (full scale)", "scale the signal down"
        )
    return np.ascontiguousarray(x)


def play_record(
    backend: DuplexBackend,
    output: npt.ArrayLike,
    *,
    extra_frames: int = 0,
    timeout_s: float | None = None,
    after_open: Callable[[], object] | None = None,
) -> PlayRecording:
    """Play ``output`` and record ``len(output) + extra_frames`` input frames at once.

    Parameters
    ----------
    backend:
        A closed full-duplex backend; it is opened, run and closed here.
    output:
        Signal (frames,) or (frames, channels_out), float, full scale +-1.0. Silence is
        played after it for the ``extra_frames`` still recorded.
    extra_frames:
        Frames recorded after the output ends, >= 0 (room for the loopback latency).
    timeout_s:
        Longest wait for the stream to finish, in wall-clock seconds; default four times the
        duration plus 10 s. On timeout the stream is stopped and ``TimeoutError`` raised.
    after_open:
        Called once the stream exists and before it starts (e.g. to wire JACK ports).

    Returns
    -------
    PlayRecording
        The recording (frames, channels_in) and the xrun log.
    """
    if isinstance(extra_frames, bool) or not isinstance(extra_frames, int) or extra_frames < 0:
        raise ConfigError("extra_frames", extra_frames, "an integer >= 0 (frames)")
    out = as_output_frames(output, backend.channels_out)
    n_out = out.shape[0]
    total = n_out + extra_frames
    rec = np.zeros((total, backend.channels_in), dtype=np.float32)

    def callback(
        indata: FloatArray, outdata: FloatArray, frames: int, time: BlockTime, status: StatusFlags
    ) -> None:
        i = time.sample_index
        m_out = min(max(n_out - i, 0), frames)
        outdata[:m_out] = out[i : i + m_out]
        outdata[m_out:] = 0.0
        m_in = min(total - i, frames)
        rec[i : i + m_in] = indata[:m_in]
        if i + frames >= total:
            raise CallbackStop

    if timeout_s is None:
        timeout_s = 10.0 + 4.0 * total / backend.samplerate
    try:
        backend.open(callback)
        if after_open is not None:
            after_open()
        backend.start()
        if not backend.wait(timeout_s):
            backend.stop()
            raise TimeoutError(
                f"the audio stream did not finish {total} frames within {timeout_s:g} s; "
                "is the device (or the JACK server) running?"
            )
        xruns = backend.xruns
    finally:
        backend.close()
    return PlayRecording(recording=rec, xruns=xruns, samplerate=backend.samplerate)
