"""GCAS: group correlators and accumulated sum, streaming (SPEC §3); the algorithm is described
in :mod:`hil.estimation.gcas.receiver`."""

from hil.estimation.gcas.receiver import (
    CFAR_MODES,
    COARSE_STEP,
    EXACT_ANCHOR,
    HFCCW_FAMILIES,
    M_MAX,
    NO_SAMPLE,
    NOISE_STRIDE,
    RANGE_READOUTS,
    RECENTRE_STEPS,
    REVERB_GUARD_LOBES,
    SEARCH_MODES,
    TRANSITION_FACTOR,
    DetectionInfo,
    GcasReceiver,
    MapCallback,
    minimum_m_hops,
)

__all__ = [
    "CFAR_MODES",
    "COARSE_STEP",
    "EXACT_ANCHOR",
    "HFCCW_FAMILIES",
    "M_MAX",
    "NOISE_STRIDE",
    "NO_SAMPLE",
    "RANGE_READOUTS",
    "RECENTRE_STEPS",
    "REVERB_GUARD_LOBES",
    "SEARCH_MODES",
    "TRANSITION_FACTOR",
    "DetectionInfo",
    "GcasReceiver",
    "MapCallback",
    "minimum_m_hops",
]
