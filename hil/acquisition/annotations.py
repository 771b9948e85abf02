"""Sample-indexed annotations: what happened to the stream, and where (in samples)."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from enum import Enum

#: Text of the alarm annotation a device raises when its ADC clipped (the run counts them).
ADC_CLIPPING_TEXT = "ADC clipping"


class AnnotationKind(Enum):
    """What an annotation records."""

    GAP = "gap"
    """Samples that never arrived (``length`` samples from ``sample_index``)."""
    OVERLAP = "overlap"
    """Samples that arrived twice or out of order (the repeat was dropped)."""
    SEQUENCE_GAP = "sequence_gap"
    """Frames missing by sequence number (``length`` frames) before ``sample_index``."""
    FRAME_ERROR = "frame_error"
    """A damaged frame was dropped near ``sample_index``."""
    DAC_UNDERRUN = "dac_underrun"
    ADC_OVERRUN = "adc_overrun"
    WATCHDOG = "watchdog"
    """The board's watchdog expired and it stopped at ``sample_index``."""
    DISCONNECT = "disconnect"
    RECONNECT = "reconnect"
    ALARM = "alarm"
    PROTOCOL_ERROR = "protocol_error"
    START_RETRY = "start_retry"
    """The board refused START as its index had passed; streaming started at
    ``sample_index`` after ``length`` refusals."""


@dataclass(frozen=True)
class Annotation:
    """An event on the stream at board sample ``sample_index``, spanning ``length``."""

    sample_index: int
    kind: AnnotationKind
    length: int = 0
    """Samples (frames for SEQUENCE_GAP) the event covers."""
    detail: str = ""


class AnnotationLog:
    """Thread-safe, append-only list of annotations.

    >>> log = AnnotationLog()
    >>> log.add(Annotation(4000, AnnotationKind.GAP, 2041, "by sample index"))
    >>> [a.kind.value for a in log.of_kind(AnnotationKind.GAP)], log.count(AnnotationKind.GAP)
    (['gap'], 1)
    """

    def __init__(self) -> None:
        self._items: list[Annotation] = []
        self._lock = threading.Lock()

    def add(self, annotation: Annotation) -> None:
        """Append one annotation."""
        with self._lock:
            self._items.append(annotation)

    def all(self) -> list[Annotation]:
        """A copy of every annotation, in arrival order."""
        with self._lock:
            return list(self._items)

    def of_kind(self, kind: AnnotationKind) -> list[Annotation]:
        """The annotations of one kind."""
        return [a for a in self.all() if a.kind is kind]

    def count(self, kind: AnnotationKind) -> int:
        """How many annotations of ``kind``."""
        return len(self.of_kind(kind))
