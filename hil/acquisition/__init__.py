"""Streaming acquisition: ring buffers by sample index, gap detection, annotations, the
sample-index <-> host-time map built from the board's SYNC messages, the capture loop and
the receiver feed of a live run, and a quiet garbage collector that keeps the loop on time."""

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
