"""Hop-boundary detection helpers for GCAS (SPEC §3.5, all [R]).

The detection statistic is ``s[n] = max_j P[n, j]`` (the time–codeword map at the chosen
Doppler). A hop boundary is declared at ``n*`` when ``s`` is a local maximum over
``±half_width`` samples, exceeds ``μ̂ + λ σ̂`` and the best codeword beats the runner-up by
``ρ``. Under noise alone one codeword's statistic, in units of the unit-correlator noise
power ``μ_U = E|u|²``, is

- noncoherent: the sum of ``M`` independent exponentials, ``Gamma(M, 1)``: mean ``M``,
  standard deviation ``√M``;
- coherent: ``|Σ_m u_m|²`` of ``M`` independent complex Gaussians, ``Exp(M)``: mean and
  standard deviation ``M``.

:func:`lambda_for_pfa` turns a requested false-alarm probability per update (per hop) into
``λ`` with a union bound over ``J × cells_per_update`` independent tests; the effective number
of independent cells per hop and codeword was measured on noise-only input (see
``tests/estimation_gcas``) and is the default of ``cells_per_update``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation.erlang_tail import erlang_isf

#: Independent tests per hop and codeword in the union bound of :func:`lambda_for_pfa`
#: (measured on noise-only input; local maxima over ±N/2 leave about one candidate per hop).
CELLS_PER_UPDATE = 256.0


def noise_moments(m_hops: int, coherent: bool) -> tuple[float, float]:
    """Mean and standard deviation of one codeword's statistic under noise, in units of μ_U.

    >>> noise_moments(9, False), noise_moments(9, True)
    ((9.0, 3.0), (9.0, 9.0))
    """
    if coherent:
        return float(m_hops), float(m_hops)
    return float(m_hops), math.sqrt(m_hops)


def lambda_for_pfa(
    pfa: float,
    m_hops: int,
    n_codewords: int,
    coherent: bool,
    cells_per_update: float = CELLS_PER_UPDATE,
) -> float:
    """The λ that gives false-alarm probability ``pfa`` per update (union-bound model).

    >>> round(lambda_for_pfa(1e-3, 10, 17, False), 3)
    7.808
    """
    if not (0 < pfa < 1):
        raise ConfigError("pfa", pfa, "in (0, 1)", "e.g. 1e-3 false alarms per hop")
    p1 = min(pfa / (n_codewords * cells_per_update), 0.5)
    mean, std = noise_moments(m_hops, coherent)
    if p1 <= 0.0:
        allowed = f"> {n_codewords * cells_per_update:g} x 5e-324 (the per-test share underflows)"
        raise ConfigError("pfa", pfa, allowed, "e.g. 1e-3 false alarms per hop")
    # Inverse survival functions of the statistic under noise: exponential of mean M
    # (coherent), gamma of integer shape M, i.e. Erlang (noncoherent), in closed form: scipy's
    # would cost a receiver's start-up the import of scipy.special.
    thr = -math.log(p1) * m_hops if coherent else erlang_isf(m_hops, p1)
    return (thr - mean) / std


def parabolic_offset(y_minus: float, y0: float, y_plus: float) -> float:
    """Vertex offset (in samples, within ±1) of the parabola through three equally spaced
    values; 0 when they are collinear.

    >>> parabolic_offset(1.0, 2.0, 1.0), parabolic_offset(0.0, 3.0, 2.0)
    (0.0, 0.25)
    """
    den = y_minus - 2.0 * y0 + y_plus
    if den >= 0 or not math.isfinite(den):
        return 0.0
    # min(max()) on floats is np.clip's result (a NaN passes through) without its wrapper.
    return float(min(max(0.5 * (y_minus - y_plus) / den, -1.0), 1.0)) + 0.0


def parabolic_offsets(
    y_minus: NDArray[np.float64], y0: NDArray[np.float64], y_plus: NDArray[np.float64]
) -> NDArray[np.float64]:
    """:func:`parabolic_offset` for arrays of triples (same shape; the same values, bit for
    bit).

    >>> parabolic_offsets(np.array([1.0, 0.0]), np.array([2.0, 3.0]), np.array([1.0, 2.0]))
    array([0.  , 0.25])
    """
    # Non-finite and huge triples are answered 0 through `ok`, as the scalar version does;
    # the overflow or inf − inf on the way is expected, not worth a warning.
    with np.errstate(over="ignore", invalid="ignore"):
        den = y_minus - 2.0 * y0 + y_plus
        ok = (den < 0) & np.isfinite(den)
        # minimum(maximum()) gives np.clip's result (NaN included) at a fraction of its cost.
        off = np.minimum(np.maximum(0.5 * (y_minus - y_plus) / np.where(ok, den, -1.0), -1.0), 1.0)
    result: NDArray[np.float64] = np.where(ok, off, 0.0) + 0.0
    return result
