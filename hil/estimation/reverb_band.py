"""The reverberation band of a GCAS receiver: which Doppler cells stationary clutter fills.

Stationary clutter (volume reverberation, walls, the direct blast) returns every tone at zero
Doppler. A unit correlator integrates one hop, ``T_h`` seconds, so its Doppler main lobe is
``±1/T_h`` Hz wide to the first null: clutter of tone ``f`` fills the cells within ``1/T_h`` of
``f``, i.e. targets slower than the waveform's **Doppler resolution in speed**

    ``v_res = c / (2 f T_h)``  (m/s)

cannot be told from clutter by a single hop (tank-audio: 60 kHz, 10 ms → 1.24 m/s; att:
30 kHz, 30 ms → 0.83 m/s). The default band (``reverb_speed_mps = "auto"``) rejects exactly
those cells: half a resolution cell of clutter speeds (:func:`auto_reverb_speed_mps`) plus the
receiver's half-lobe guard puts the band's edge at each tone's first null.

Trade-off: with the band on, a target slower than ``v_res`` gives no estimate (it is where the
clutter is), and so does one within about a Doppler grid step past it, whose peak falls on the
refused edge (``att`` with 64 hypotheses over ±25.7 m/s: the cut measured in the chapter-6
run is about 3.3 m/s for ``v_res`` = 2.65 m/s); with it off (``reverb_speed_mps = 0``) such
a target is estimated, and so is any stationary clutter stronger than the noise (a stationary
target's echo, a tank wall, the direct blast) as a zero-speed estimate. Turn it off for a
stationary or slow target in a quiet tank.

With the band off, an echo slower than ``v_res`` shares its Doppler cells with the
reverberation, which is not white: it sits at the tones, so each hop's correlator of the echo
holds reverberation a white-noise model of the window's power does not predict, and the hops'
coherence falls short of what one echo in white noise has (att, a target at rest at 0 dB SRR:
0.74-0.87 of it, half the fits refused). The interference a hop's term really holds is
measured in the same windows at the same Doppler on the *other* tones
(:func:`reverberation_coherence`): the echo is not there (the tones are orthogonal over a
hop), the reverberation is (it arrives at every tone from the delays that sent it), and so
is the noise. The coherence one echo of that signal-to-interference ratio has is the
expectation such an echo is held to (:func:`in_reverberation`), where a point echo was
confirmed lately by the white-noise test on the hops the reverberation leaves clear
(:mod:`hil.estimation.gcas.point_echoes`: a few scatterers in one near range cell pass the
relative test too, never the white-noise one). What stays short of it is
not one point echo: where its coherence within each tone holds (each tone its own complex
gain, as a patch of scatterers spread over more than ``c/(2 B)`` in range gives, ``B`` the
tones' span), it is **clutter**, diffuse reverberation, counted apart
(:attr:`hil.estimation.gcas.GcasReceiver.clutter_count`) and not reported
(:func:`is_diffuse`).

A target inside the band is not reported at the band's edge: its Doppler response leaks into
the first allowed cells, whose weighted maximum is then a ghost at the edge speed. Detections
whose hypothesis lies on the edge (:func:`edge_hypotheses`) are therefore refused, and counted
(:attr:`hil.estimation.gcas.GcasReceiver.in_band_count`); with the refinement they are noted,
so that what the hidden echo leaks outside the band (its ghost one tone spacing out, its
Doppler sidelobes) is refused as any measured echo's (:mod:`hil.estimation.gcas.hidden_echoes`).

>>> round(auto_reverb_speed_mps(np.array([57e3, 59e3, 61e3, 63e3]), 0.01, 1482.3), 3)
0.65
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError

#: The setting that derives the band from the waveform (:func:`auto_reverb_speed_mps`).
AUTO = "auto"


def doppler_resolution_mps(tones_hz: ArrayLike, hop_s: float, sound_speed_mps: float) -> float:
    """The speed whose two-way Doppler shift at the lowest tone is one unit-correlator main
    lobe, ``1/T_h`` Hz: ``c / (2 f_lo T_h)``, m/s (the widest of the tones' cells)."""
    f_lo = float(np.min(np.asarray(tones_hz, dtype=np.float64)))
    return float(sound_speed_mps) / (2.0 * f_lo * float(hop_s))


def auto_reverb_speed_mps(tones_hz: ArrayLike, hop_s: float, sound_speed_mps: float) -> float:
    """Clutter speeds the default band covers: half the Doppler resolution, m/s.

    With the receiver's guard of half a main lobe around each tone's clutter band, the band
    then reaches each tone's first null, ``1/T_h`` from zero Doppler."""
    return 0.5 * doppler_resolution_mps(tones_hz, hop_s, sound_speed_mps)


def resolve_reverb_speed(
    value: float | str | None,
    tones_hz: ArrayLike,
    hop_s: float,
    sound_speed_mps: float,
    max_speed_mps: float,
) -> float:
    """The band's clutter speed (m/s) for a ``reverb_speed_mps`` setting.

    ``"auto"`` (or None) gives :func:`auto_reverb_speed_mps`, or 0 (no band) when the band
    would cover the whole search span ``±max_speed_mps``: no target of that span could then be
    told from clutter. A number (m/s, ``>= 0``) is taken as it is; 0 turns the band off.
    """
    if value is None or value == AUTO:
        v = auto_reverb_speed_mps(tones_hz, hop_s, sound_speed_mps)
        edge = 2.0 * v  # the band's edge with the half-lobe guard, m/s
        return v if edge < max_speed_mps else 0.0
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating):
        raise ConfigError(
            "reverb_speed_mps",
            value,
            f"'{AUTO}' or a speed >= 0 m/s",
            "give a number such as 0.8, 0 to turn the band off, or 'auto'",
        )
    v = float(value)
    if not (math.isfinite(v) and v >= 0):
        raise ConfigError("reverb_speed_mps", value, f"'{AUTO}' or a speed >= 0 m/s")
    return v


def clutter_cells(
    alphas: NDArray[np.floating],
    tones_hz: NDArray[np.floating],
    reverb_speed_mps: float,
    sound_speed_mps: float,
    guard_hz: float,
    *,
    any_tone: bool,
) -> NDArray[np.bool_]:
    """Unit-correlator cells that stationary clutter fills, shape ``(D, K)`` bool.

    Cell ``(d, k)`` listens at ``α_d f_k`` (``alphas`` shape ``(D,)``, ``tones_hz`` shape
    ``(K,)``). Clutter of speed ``|v| < reverb_speed_mps`` (m/s) of tone ``f_k'`` lies in
    ``[α(−v), α(v)]·f_k'``. A cell within ``guard_hz`` of its own tone's band is filled;
    with ``any_tone``, so is a cell inside another tone's band (a ghost speed, where
    ``α_d f_k = f_k'``), without the guard. Measured on the ``att`` random-cyclic code: the
    guard on the ghost cells as well removed most of a 25 m/s target next to the ghost
    speed (27.5 m/s): 0.22 of its hops detected at −20 dB against 0.88 without, while
    rejecting a stationary echo 6 dB above a target equally well.
    """
    c = float(sound_speed_mps)
    v = float(reverb_speed_mps)
    a_lo, a_hi = (c - v) / (c + v), (c + v) / (c - v)
    tones = np.asarray(tones_hz, dtype=np.float64)
    f = np.asarray(alphas, dtype=np.float64)[:, None] * tones[None, :]  # (D, K) Hz
    own = (f > a_lo * tones[None, :] - guard_hz) & (f < a_hi * tones[None, :] + guard_hz)
    if not any_tone:
        return np.asarray(own, dtype=bool)
    ghost = np.any(
        (f[:, :, None] > a_lo * tones[None, None, :])
        & (f[:, :, None] < a_hi * tones[None, None, :]),
        axis=2,
    )
    return np.asarray(own | ghost, dtype=bool)


def edge_hypotheses(hyp_weights: NDArray[np.floating], allow_in_band: bool) -> NDArray[np.bool_]:
    """Hypotheses whose detections are refused, shape ``(D,)`` bool.

    ``hyp_weights`` (shape ``(D,)``) is each hypothesis's smallest cell weight (1 outside the
    band). Refused: every hypothesis next to one with a weight below 1 (the band's edge, where
    an in-band target's leak peaks), and, unless ``allow_in_band`` (a soft band with weight
    > 0, where the user asked for in-band detections), those inside the band as well.
    """
    w = np.asarray(hyp_weights, dtype=np.float64)
    band = w < 1.0
    near = band.copy()
    near[1:] |= band[:-1]
    near[:-1] |= band[1:]
    return near & ~band if allow_in_band else near


def in_reverberation(speed_mps: float, tones_hz: ArrayLike, hop_s: float, c: float) -> bool:
    """Whether an echo of radial speed ``speed_mps`` (m/s) shares its Doppler cells with the
    still reverberation: slower than one Doppler resolution cell,
    :func:`doppler_resolution_mps` (the reverberation fills ``±1/T_h`` Hz about every tone).

    >>> in_reverberation(0.5, [28350.0, 31650.0], 0.01, 1500.0)
    True
    >>> in_reverberation(-3.0, [28350.0, 31650.0], 0.01, 1500.0)
    False
    """
    return abs(float(speed_mps)) < doppler_resolution_mps(tones_hz, hop_s, c)


def reverberation_coherence(
    on_tone: NDArray[np.complexfloating], off_tone: NDArray[np.complexfloating]
) -> float:
    """The coherence over ``M`` hops one echo has against the interference measured beside
    it: ``E[ρ] = (M s + 1) / (M (s + 1))`` with ``s`` its per-hop signal-to-interference
    ratio (the white-noise form of :func:`hil.estimation.fit_steps.echo_quality`, with the
    interference measured instead of modelled).

    ``on_tone`` (shape ``(M,)``): the hops' unit correlators at the echo's cell, each on its
    hop's tone; ``off_tone`` (shape ``(M, J)``, ``J ≥ 1``): the same windows and Doppler on
    the other tones (no echo there: the tones are orthogonal over a hop). The interference
    power is the mean ``|off_tone|²``; ``s = mean |on_tone|² / it − 1`` (0 at the least).
    1.0 where the other tones hold nothing (no interference to measure: silence or masked
    cells).

    >>> round(reverberation_coherence(np.full(10, 3.0 + 0j), np.ones((10, 3))), 3)
    0.9
    >>> reverberation_coherence(np.ones(10), np.zeros((10, 3)))
    1.0
    """
    on = np.asarray(on_tone)
    off = np.asarray(off_tone)
    level = float(np.mean(np.square(np.abs(off)))) if off.size else 0.0
    if not level > 0.0:
        return 1.0
    m = on.shape[0]
    s = max(float(np.mean(np.square(np.abs(on)))) / level - 1.0, 0.0)
    return (m * s + 1.0) / (m * (s + 1.0))


def is_diffuse(coherence: float, tone_coherence: float, fraction: float) -> bool:
    """Whether a fit short of one echo's coherence over all hops is diffuse reverberation:
    its coherence within each tone (both as fractions of one echo's, ``(0, 1]``) holds to
    ``fraction`` and stands above its coherence over all hops (a patch of scatterers
    spread in range answers each tone with its own complex gain; a point echo does not).

    >>> is_diffuse(0.55, 0.9, 0.8), is_diffuse(0.3, 0.45, 0.8)
    (True, False)
    """
    return tone_coherence >= fraction and tone_coherence > coherence
