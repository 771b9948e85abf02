"""Streaming acquisition: ring buffers by sample index, gap detection, annotations, and the
sample-index <-> host-time map built from the board's SYNC messages."""

from hil.acquisition.annotations import Annotation, AnnotationKind, AnnotationLog
from hil.acquisition.clock_fit import SampleClockFit
from hil.acquisition.gaps import SampleGapDetector
from hil.acquisition.heap import HeapFreeze
from hil.acquisition.ring import SampleRing

__all__ = [
    "Annotation",
    "AnnotationKind",
    "AnnotationLog",
    "HeapFreeze",
    "SampleClockFit",
    "SampleGapDetector",
    "SampleRing",
]
