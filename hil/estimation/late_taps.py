"""The direct path's complex amplitude at each hop boundary, with the late paths fitted as
nuisance taps: a least-squares fit of the raw input samples on the known transmission.

At a boundary the direct path switches from the hop's tone ``f_cur`` to the next one
``f_next``. A tank's late paths (at image order 3 in the built-in tank, the far end wall with
one or two more boundaries: the previous boundary's echo, 0.2-1 ms ahead of this one's direct
path) switch from the tone before, ``f_prev``, to ``f_cur`` around the same time. Read through
the next-tone window of :mod:`hil.estimation.first_arrival` (``1/Δf`` long, 0.5 ms), such a
switch leaks into the direct path's first 0.2 ms, and its phase pulls the direct path's Doppler.

The transmission is known, so every arrival in a short stretch around the onset is a delayed
copy of it with a complex gain: this module fits the samples ``y`` (real) of
``[o − LEAD_S, o + DIRECT_S]`` (``o`` the onset, samples) at each boundary with

- the direct path: ``f_cur`` before ``o``, ``f_next`` from ``o`` on, phase-continuous through
  the transmission's own phase step (the ramp model of the first-arrival readout);
- the paths that sound one tone throughout the stretch: a steady ``f_cur`` and a steady
  ``f_prev``;
- up to :data:`LATE_TAPS` late paths, each ``f_prev`` switching to ``f_cur`` at a sample ``s``
  of a one-sample grid over ``[o − LEAD_S, o]``, chosen greedily (orthogonal least squares:
  the tap that lowers the residual most, then all refitted);

each as ``Re{g · u(t)}`` with ``u(t) = e^{j2π α f t}`` (``t`` the absolute input time, ``α`` the
detection's time scale) and ``g`` complex, by least squares. The direct path's ``g`` is its
complex amplitude on the convention of the next-tone channel (demodulated at ``α f_next``), so
its Doppler is read from it as from the channel's (``FirstArrivalReadout._direct_alpha``).

Measured on the built-in tank at image order 3 (seed 1, the recorded detections replayed),
as the readout's second reading where the next-tone channel's gives a speed slower than every
image, for a target GCAS reads at 1 m/s or more (``LATE_TAP_RATIO`` and
``LATE_TAP_MIN_SPEED_MPS`` in :mod:`hil.estimation.first_arrival`): scored speed RMSE 0.075 ->
0.045 m/s. Fitting every boundary this way instead (not done; measured with the taps chosen by
their match to the residual alone, orthogonal matching pursuit) gave 0.033-0.048 m/s there,
but 0.021-0.023 m/s in the 12 x 6 x 4 m tank at order 2 (0.013 m/s on the channel), where an
onset read 0.26-0.32 ms early on the far wall's switch puts the direct path's model where it
is not. Late taps (with ``LEAD_S`` 0.8 ms, every boundary, matching pursuit): 1 0.083, 2
0.047, 3 0.033, 4 0.032 (1 ms), 5 0.055 (0.5 ms), 8 0.081 (0.5 ms) m/s: beyond a few, the taps
fit the direct path's own switch. The late paths' Doppler is taken as the direct path's:
fitting taps at 1 and 1/α too gave 0.057 m/s. Choosing each tap by the residual's fall
(orthogonal least squares) is exact on a noise-free late switch where the match alone picks a
neighbouring sample (tests/estimation_gcas/test_late_taps.py); as the second reading it gave
0.046 m/s against the match's 0.041.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation.first_arrival_kernels import late_tap_table

#: The fit's stretch before the onset, s: at least one window of the next-tone channel (0.5 ms
#: at 2 kHz spacing), so the steady tones are told apart by frequency. Measured (order 3,
#: every boundary fitted, 3 taps by matching pursuit): 0.3 ms 0.055, 0.5 ms 0.041, 0.8 ms
#: 0.033, 1 ms 0.048 m/s.
LEAD_S = 0.8e-3
#: Late paths fitted at most per boundary (see the module docstring).
LATE_TAPS = 3
#: Ridge added to the normal equations, relative to their mean diagonal: keeps a fit whose
#: taps coincide solvable, far below the noise.
RIDGE = 1e-9
#: A tap's two real columns, made orthogonal to the fit's, count as one direction where the
#: determinant of their products is below this fraction of the product of their norms².
COLLINEAR = 1e-9


@dataclass(frozen=True)
class DirectFit:
    """What :func:`direct_amplitudes` fits: the direct path's complex amplitude at each
    boundary (shape ``(M,)``, the next-tone channel's convention) and ``late_ratio``: the
    late taps' power ``Σ|g|²`` over the direct path's, both summed over the boundaries
    (dimensionless; taps fitted where no late path is hold a little, their gains partly
    cancelling each other)."""

    amplitude: NDArray[np.complex128]
    late_ratio: float


def _switch(
    i: NDArray[np.float64],
    s: NDArray[np.float64],
    w_old: NDArray[np.float64],
    w_new: NDArray[np.float64],
    jump: NDArray[np.float64],
) -> NDArray[np.complex128]:
    """A unit tone switching from ``w_old`` to ``w_new`` (rad per sample) at sample ``s``
    (samples from ``s`` on sound the new tone), phase-continuous but for the transmission's
    own step ``jump`` (rad): ``e^{j w_new i}`` from ``s`` on, ``e^{j(w_new s + w_old (i − s) −
    jump)}`` before. Broadcast shapes: ``i`` ``(M, 1, N)``, ``s`` ``(M, G, 1)``, the rest
    ``(M, 1, 1)``; result ``(M, G, N)``."""
    return np.asarray(
        np.where(i >= s, np.exp(1j * w_new * i), np.exp(1j * (w_new * s + w_old * (i - s) - jump))),
        dtype=np.complex128,
    )


def direct_amplitudes(
    y: NDArray[np.float64],
    first: NDArray[np.int64],
    onset: NDArray[np.float64],
    freqs_hz: NDArray[np.float64],
    jumps_rad: NDArray[np.float64],
    alpha: float,
    fs_hz: float,
    lead: int,
) -> DirectFit:
    """The direct path's complex amplitude at each of ``M`` boundaries (shape ``(M,)``) and
    the late taps' power over its own (:class:`DirectFit`).

    ``y`` (shape ``(M, N)``): the input samples of each boundary's stretch, from absolute
    index ``first`` (shape ``(M,)``); ``onset`` (shape ``(M,)``): the direct path's switch,
    absolute samples (fractional), ``lead`` samples after ``first`` rounded up
    (``first = ceil(onset) − lead``); ``freqs_hz`` (shape ``(3, M)``): ``f_prev``,
    ``f_cur``, ``f_next`` as transmitted, Hz; ``jumps_rad`` (shape ``(2, M)``): the
    transmission's phase step at the switch ``f_prev → f_cur`` and at ``f_cur → f_next``;
    ``alpha``: the time scale (dimensionless); ``fs_hz``: the input rate, Hz.
    """
    m, n = y.shape
    if not 0 < lead < n - 1:
        raise ConfigError("lead", lead, f"1 .. {n - 2} samples (the stretch holds {n})",
                          "the stretch must reach past the onset")  # fmt: skip
    if freqs_hz.shape != (3, m) or jumps_rad.shape != (2, m) or first.shape != (m,):
        raise ConfigError(
            "freqs_hz, jumps_rad, first",
            (freqs_hz.shape, jumps_rad.shape, first.shape),
            f"shapes (3, {m}), (2, {m}), ({m},) for {m} boundaries",
        )
    ii = np.arange(n, dtype=np.float64)[None, None, :]  # samples after ``first``
    o = (onset - first)[:, None, None]
    # Phases relative to ``first`` (small numbers); the direct path's gain is moved back to
    # absolute time at the end.
    w_prev, w_cur, w_next = (2.0 * np.pi * alpha * freqs_hz / fs_hz)[:, :, None, None]
    j_pc, j_cn = jumps_rad[:, :, None, None]
    base = np.concatenate(
        [_switch(ii, o, w_cur, w_next, j_cn), np.exp(1j * w_cur * ii), np.exp(1j * w_prev * ii)],
        axis=1,
    )  # (M, 3, N): the direct path, steady f_cur, steady f_prev
    # Each late tap switches at a sample s of the grid: e^{j w_cur i} from s on, and before it
    # e^{j w_prev i} times e^{j((w_cur − w_prev) s − jump)} (_switch's formula, its factors
    # apart): one product per tap, no exponential of the (M, G, N) table.
    grid = np.arange(1, lead + 1, dtype=np.float64)[None, :, None]
    at_switch = np.exp(1j * ((w_cur - w_prev) * grid - j_pc))  # (M, G, 1)
    # np.where(ii >= grid, e^{j w_cur i}, e^{j w_prev i} · at_switch), by one compiled pass
    # (the same bits, none of NumPy's (M, G, N) temporaries).
    taps = np.empty((m, lead, n), dtype=np.complex128)
    late_tap_table(
        np.exp(1j * w_cur * ii)[:, 0, :], np.exp(1j * w_prev * ii)[:, 0, :],
        np.ascontiguousarray(at_switch[:, :, 0]), taps,
    )  # fmt: skip
    rows = np.arange(m)[:, None]
    chosen = np.zeros((m, 0), dtype=np.int64)
    # Each tap as two real columns: Re{g u} = Re g Re u − Im g Im u.
    tap_re, tap_im = taps.real, -taps.imag  # (M, G, N) each
    re_re = np.einsum("mgn,mgn->mg", tap_re, tap_re)  # (M, G): the columns' products, once
    im_im = np.einsum("mgn,mgn->mg", tap_im, tap_im)
    re_im = np.einsum("mgn,mgn->mg", tap_re, tap_im)
    while True:
        u = np.concatenate([base, taps[rows, chosen]], axis=1)  # (M, K, N)
        x = np.concatenate([u.real, -u.imag], axis=1)  # (M, 2K, N)
        gram = x @ np.swapaxes(x, 1, 2)
        ridge = RIDGE * np.trace(gram, axis1=1, axis2=2) / gram.shape[1]
        gram += ridge[:, None, None] * np.eye(gram.shape[1])
        coef = np.linalg.solve(gram, np.einsum("mkn,mn->mk", x, y)[..., None])[..., 0]
        left = y - np.einsum("mkn,mk->mn", x, coef)
        if chosen.shape[1] == min(LATE_TAPS, lead):
            break
        # The tap that lowers the residual most once both its columns are made orthogonal
        # to the fit's (orthogonal least squares: neighbouring taps differ by one sample,
        # so the best-matching one alone is not the best to add). With ``q`` an orthonormal
        # basis of the fit's columns, a column ``t`` made orthogonal is ``t − q qᵀt``: its
        # products follow from ``qᵀt`` (shape (M, G, 2K)) without forming it.
        q = np.linalg.qr(np.swapaxes(x, 1, 2))[0]  # (M, N, 2K)
        pa, pb = tap_re @ q, tap_im @ q  # (M, G, 2K)
        ql = np.einsum("mnk,mn->mk", q, left)[:, :, None]  # (M, 2K, 1)
        aa = re_re - np.sum(pa * pa, axis=2)
        bb = im_im - np.sum(pb * pb, axis=2)
        ab = re_im - np.sum(pa * pb, axis=2)
        ar = (tap_re @ left[:, :, None] - pa @ ql)[..., 0]
        br = (tap_im @ left[:, :, None] - pb @ ql)[..., 0]
        det = aa * bb - ab * ab
        # A tap whose two columns are one direction once made orthogonal (the grid's first
        # sample: it differs from the steady f_cur in one sample only) would fit that sample,
        # and its gain is a ratio of two rounding errors: left out.
        solid = det > COLLINEAR * np.maximum(aa * bb, 1e-300)
        gain_g = np.where(
            solid,
            (bb * ar * ar - 2.0 * ab * ar * br + aa * br * br) / np.where(solid, det, 1.0),
            0.0,
        )
        gain_g[rows, chosen] = -1.0
        chosen = np.concatenate([chosen, np.argmax(gain_g, axis=1)[:, None]], axis=1)
    k = u.shape[1]
    power = coef[:, :k] ** 2 + coef[:, k:] ** 2  # (M, K): |g|² of each column
    direct = float(np.sum(power[:, 0]))
    late = float(np.sum(power[:, 3:])) / direct if direct > 0 else math.inf
    gain = coef[:, 0] + 1j * coef[:, k]
    return DirectFit(
        np.asarray(gain * np.exp(-1j * w_next[:, 0, 0] * first), dtype=np.complex128), late
    )
