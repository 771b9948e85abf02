"""The seam between a live run and its DAC/ADC: what the transducer board
(:class:`~hil.devices.board.Board`) and an audio interface
(:class:`~hil.devices.audio.daq.AudioDaq`) both offer, so the run uses either without
telling them apart.

A device is configured, then :meth:`StreamingDevice.start` transmits from a source of DAC
samples (``source(k, n)``: transmit samples ``k .. k+n-1``, full scale) and returns the board
index where sample 0 plays; captured samples land in its :attr:`~StreamingDevice.ring` by
board index. What happened to the stream is in :attr:`~StreamingDevice.annotations`, the
sample clock against host time in :attr:`~StreamingDevice.clock_fit`, the xrun counters in
:attr:`~StreamingDevice.last_status`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

import numpy.typing as npt

from hil.acquisition.annotations import Annotation, AnnotationKind
from hil.acquisition.clock_fit import SampleClockFit
from hil.acquisition.ring import SampleRing

if TYPE_CHECKING:
    from hil.devices.audio.daq import AudioDaq
    from hil.devices.board import Board


class Annotations(Protocol):
    """A device's annotation log, read-only."""

    def all(self) -> list[Annotation]: ...

    def of_kind(self, kind: AnnotationKind) -> list[Annotation]: ...


class XrunStatus(Protocol):
    """A device status with xrun counters: the board's
    :class:`~firmware_protocol.messages.Status` (counted since the board powered up) or the
    audio interface's :class:`~hil.devices.audio.daq.AudioDaqStatus` (since the stream
    started)."""

    @property
    def dac_underruns(self) -> int: ...

    @property
    def adc_overruns(self) -> int: ...


DacSamples = Callable[[int, int], npt.NDArray[Any]]
"""``source(k, n)``: transmit samples ``k .. k+n-1``, full scale, shape ``(n,)``."""


class StreamingDevice(Protocol):
    """The DAC/ADC of a run (see the module docstring)."""

    @property
    def ring(self) -> SampleRing | None: ...

    @property
    def annotations(self) -> Annotations: ...

    @property
    def clock_fit(self) -> SampleClockFit | None: ...

    @property
    def last_status(self) -> XrunStatus | None: ...

    def configure(self) -> None: ...

    def start(self, source: DacSamples, /) -> int: ...

    def wait_for_samples(self, end_index: int, /, timeout_s: float) -> bool: ...

    def read(self, first: int, n: int, /) -> npt.NDArray[Any]: ...

    def stop(self) -> None: ...

    def close(self) -> None: ...


def _both_conform(board: Board, audio: AudioDaq) -> tuple[StreamingDevice, StreamingDevice]:
    """Never called: mypy checks here that both devices implement the seam."""
    return board, audio
