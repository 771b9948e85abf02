"""Streaming acquisition: ring buffers by sample index, gap detection, annotations, the
sample-index <-> host-time map built from the board's SYNC messages, and what keeps a live
loop on time (a quiet garbage collector; probes of how long the machine stalls)."""

from hil.acquisition.annotations import Annotation, AnnotationKind, AnnotationLog
from hil.acquisition.clock_fit import SampleClockFit
from hil.acquisition.gaps import SampleGapDetector
from hil.acquisition.heap import HeapFreeze
from hil.acquisition.machine_stalls import MachineStalls, StallProbes
from hil.acquisition.ring import SampleRing

__all__ = [
    "Annotation",
    "AnnotationKind",
    "AnnotationLog",
    "HeapFreeze",
    "MachineStalls",
    "SampleClockFit",
    "SampleGapDetector",
    "SampleRing",
    "StallProbes",
]
