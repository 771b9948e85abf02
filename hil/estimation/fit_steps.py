"""One fit's steps on the refinement kernels (:mod:`hil.estimation.refine_kernels`), shared by
the one-echo fit (:mod:`hil.estimation.refine`) and the accelerating fit
(:mod:`hil.estimation.refine_accel`): the delay–speed maximum with its grid recentred, and a
fit's quality (E/N0, coherences, amplitude)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.estimation.codewords import Codeword
from hil.estimation.echo_fits import Coherence
from hil.estimation.refine_kernels import RECENTRE, fit_quality, maximise

#: Points of the search's grid: over ±½ grating lobe in time, and at least SPEED_POINTS over
#: ± the speed span (more where half the M hops' Doppler resolution is finer).
TIME_POINTS = 9
SPEED_POINTS = 5
#: Stencil passes of the quadratic fit (the stencil halves each pass).
FIT_PASSES = 5
#: Searches re-centred where the speed line's maximum is at its end (each moves the tables
#: by one speed span: a detector's speed off by up to this many spans is still refined).
MAX_RECENTRES = 4


def maximise_recentred(
    args: tuple[Any, ...], known: NDArray[np.complex128], gamma: float, c: float, t: float,
    v: float, grid: tuple[Any, ...],
) -> tuple[float, float, int]:  # fmt: skip
    """:func:`~hil.estimation.refine_kernels.maximise` at the rate ``gamma`` (1/s) from
    ``(t, v)`` (s, m/s) over ``grid``, recentred on the grid's edge up to
    :data:`MAX_RECENTRES` times: ``(t, v, outcome)``."""
    outcome = RECENTRE
    for _ in range(MAX_RECENTRES + 1):
        t, v, outcome = maximise(*args, known, gamma, c, t, v, *grid)
        if outcome != RECENTRE:
            break
    return t, v, outcome


def echo_quality(
    args: tuple[Any, ...],
    known: NDArray[np.complex128],
    word: Codeword,
    n_tones: int,
    t_rx: float,
    alpha: float,
    gamma: float = 0.0,
) -> tuple[float, Coherence, Coherence, Coherence, complex]:
    """E/N0 (linear) of the echo at a candidate (time-scale rate ``gamma``, 1/s, as
    :func:`~hil.estimation.refine_kernels.candidate_sums`), its coherence across all hops,
    within each tone and over runs of consecutive hops, and its fitted amplitude
    ``β = 2C/E_s`` (:func:`~hil.estimation.refine_kernels.fit_quality`).

    ``Â = 2|C|/E_s``, the noise variance ``σ²`` what the echo leaves of the windows' energy,
    ``E/N0 = Â² N / (4 σ²)`` (module docstring). Coherence ``ρ = |Σ_i H_i|² / (M Σ_i |H_i|²)``:
    1 when every hop's term has the phase the one-echo model predicts, about ``1/M`` for
    noise. One echo of per-hop SNR ``s = mean |H_i|² / (N_i σ²) − 1`` gives
    ``E[ρ] ≈ (M s + 1) / (M (s + 1))``; an echo of another schedule or speed whose tones
    match some hops (a still echo read at the tone spacing's speed, a target beyond the
    span) has strong hops of unrelated phases: ``ρ`` far below that. Multipath a fraction of
    a millisecond long multiplies each tone by its own complex gain: ``ρ`` falls, the
    coherence within each tone (the same ratio over the hops of one tone,
    ``Σ_k |Σ_{i∈k} H_i|² / Σ_k n_k Σ_{i∈k} |H_i|²``, expected
    ``Σ_k (n_k² s + n_k) / Σ_k n_k² (s + 1)``) does not. An accelerating echo drifts in
    phase against the constant-speed model: ``ρ`` falls, the coherence over runs of
    :data:`~hil.estimation.refine_kernels.RUN_HOPS` consecutive hops (the same ratio summed
    over every run, expected ``(R s + 1) / (R (s + 1))``) holds up to about 7 m/s² on ``att``.
    """
    en0, rho, expected, rho_tone, expected_tone, rho_run, expected_run, c, es = fit_quality(
        *args, known, gamma, word.tones, n_tones, t_rx, alpha
    )
    return (
        en0,
        Coherence(rho, expected),
        Coherence(rho_tone, expected_tone),
        Coherence(rho_run, expected_run),
        2.0 * complex(c) / es if es > 0 else 0j,
    )
