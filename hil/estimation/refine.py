"""Coherent refinement of a detection: local maximum likelihood of delay and Doppler at the
input rate over the detection's ``M`` hops (detect with GCAS, then measure like the bank).

A detector hands over a boundary receive time ``t̂`` (s) and a time scale ``α̂``, good to a
fraction of a grating lobe; this module finds the ``(t_rx, α)`` that maximise the likelihood
of one echo of the exact transmitted schedule in white noise,

    L(t_rx, α) = |Σ_n x[n] s*(α (t_n − t_rx) + T_b)|²,

over the ``M`` hops ending at the detected boundary (transmit time ``T_b``): the ambiguity
function of the exact waveform, whose maximum is the estimator that reaches the Cramér–Rao
bound above the threshold SNR (:mod:`hil.estimation.crlb`). The matched-filter bank
(:mod:`hil.estimation.mfbank`) computes the same function everywhere; here it is computed
around one cell only.

How it is computed cheaply. Hop ``i`` of the ``M`` (tone ``f_i``, start ``T_i``, length
``D_i``, start phase ``φ_i``, amplitude ``a_i``) is heard over
``[t_rx + (T_i − T_b)/α, t_rx + (T_i + D_i − T_b)/α)``, as
``a_i exp(j(φ_i + 2π f_i (α (t − t_rx) + T_b − T_i)))``. With ``α = α̂ + ε`` and ``t = m_i + u``
(``m_i`` the hop's centre at ``(t̂, α̂)``),

    H_i = K_i e^{−j2π f_i α (m_i − t_rx)} Σ_p (−j2π f_i ε D)^p / p! · Z_i^p,
    Z_i^p = Σ_{n in window} x[n] e^{−j2π f_i α̂ u_n} (u_n / D)^p,

``K_i = a_i e^{−j(φ_i + 2π f_i (T_b − T_i))}``, ``D`` the hop length. The moments ``Z_i^p``
are prefix sums over a window widened by the search's reach, so a candidate's window edges
(which move with ``t_rx`` and ``α``) cost two look-ups per hop and moment; a sample on an edge
counts with the fraction of its interval inside (a continuous likelihood, no sample-grid
steps). Over the search ``|2π f ε D/2| ≤ 1`` (``ε`` up to 0.75 m/s as a time scale on the
``att`` tones), so the :data:`N_MOMENTS` terms leave a relative error below 2e-4 at a
window's edge. ``L = |Σ_i H_i|²``.

Why this estimator: it is the maximum-likelihood estimate for one echo in white noise, so it
is efficient above threshold; evaluated on the moments it costs a few hundred multiplies per
candidate instead of an input-rate correlation, and only a small neighbourhood is searched
because the detector has already chosen the codeword, the lobe and the speed to a fraction
of the Doppler resolution. Interpolating a fine cross-ambiguity would need that ambiguity on
a grid finer than its main lobe in both axes, the same evaluations without the fit.

Search (:func:`~hil.estimation.refine_kernels.maximise`): a grid over ±½ grating lobe in time
(``1/(α Δf)``, ``Δf`` the tone spacing: the detector's error is far smaller, so the lobe is
the detector's) and ±``speed_span`` in speed, re-centred where its maximum is on the speed
edge (a detector's speed biased next to masked Doppler cells), then 2-D quadratic fits on a
3 × 3 stencil around the best point, the stencil halving each pass. A detection that agrees
with a recent fit of its echo starts from that fit's prediction with a small grid instead.

Is it an echo of the schedule: the fit's coherence across the hops, within each tone and
over runs of consecutive hops, against what one echo of its SNR would give
(:func:`~hil.estimation.fit_steps.echo_quality`; the receiver refuses a detection below all three).

SNR: at the maximum, ``Â = 2|C|/E_s`` (``E_s = Σ a_i² N_i``, ``N_i`` the window's samples) and
the noise variance is what the echo leaves of the window's energy; ``E/N0 = Â² N / (4 σ²)``
(:func:`hil.estimation.crlb.sampled_e_over_n0`), from which the estimate's own Cramér–Rao
bounds follow.

Accelerating echoes: fitted with a changing time scale where the coherence shows a drift
(:mod:`hil.estimation.refine_accel`).


Beside still water: still water (volume reverberation at rest, a wall) lies on the
transmitted tones, and where it is stronger than an echo it leaks coherently into the echo's
fit through the hops' edges, the only place the grating lobes differ: a weak echo's fit can
sit a lobe off for runs of hops at an E/N0 well above the white-noise lobe threshold
(:data:`LOBE_Z`), as a threshold on white noise does not see it. There the lobe is decided
again on the input without its still water (:mod:`hil.estimation.still_lobe`: the
one-period canceller and an echo model that holds its copy, so the copy is no ghost), and the
fit within that lobe is still made on the input itself, which keeps the Cramér–Rao accuracy
of open water (:meth:`CoherentRefiner._lobe_without_still`). Chosen over fitting on the
cancelled input throughout: the canceller doubles the noise and blinds the tones whose
Doppler phase over a still period is a whole turn, and in open water it changes nothing
worth that; the decision runs only where the still water's measured power is a sizeable part
of the window's and above the echo's (:data:`STILL_OVER_REST`, :data:`STILL_OVER_ECHO`), so
estimates without still water are unchanged.

Limits: one echo. Through multipath a fraction of a millisecond long (a tank's images) the
maximum sits between the arrivals and the fit is not one echo (tanks read the first arrival
instead, :mod:`hil.estimation.first_arrival`). Tone schedules of equal hops only.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation.codewords import Codeword, CodewordBook
from hil.estimation.crlb import crlb
from hil.estimation.detection import parabolic_offset
from hil.estimation.echo_fits import EchoFit, EchoTest, Refinement
from hil.estimation.echo_model import echo_samples
from hil.estimation.fit_steps import (
    FIT_PASSES,
    MAX_RECENTRES,
    SPEED_POINTS,
    TIME_POINTS,
    echo_quality,
)
from hil.estimation.refine_accel import (
    ACCEL_GAIN,
    ACCEL_MARGIN_DB,
    ACCEL_POINTS,
    ACCEL_RUN_MIN,
    ACCEL_RUN_MIN_LONG,
    ACCEL_RUN_SEEDED,
    ACCEL_SEED_HOPS,
    ACCEL_TRY,
    MAX_ACCEL_MPS2,
    accel_fit,
    accel_gain,
    accel_seed,
    halves_seed,
    hops_on_curve,
    to_boundary,
    to_centre,
    with_acceleration,
)
from hil.estimation.refine_kernels import (
    FOUND,
    N_MOMENTS,
    NO_LOBE,
    RECENTRE,
    assign_slots,
    candidate_sums,
    ended_gain,
    grid_sums,
    maximise,
)
from hil.estimation.refine_pair import LOBE_MOVES, RESOLVED_LOBES, SEED_LOBES, fit_pair
from hil.estimation.reverb_band import doppler_resolution_mps
from hil.estimation.row_buffer import RowBuffer
from hil.estimation.still_lobe import StillStreams, canceller_gain, still_free_powers
from hil.estimation.still_period import still_period
from hil.signals.schedule import HopSchedule

#: A hop's tables are reused by a later detection whose predicted window edges are within
#: this many samples of the ones they were made for (and whose time scale is within half the
#: speed span): consecutive detections of one target share ``M − 1`` hops.
REUSE_SLACK = 16
#: Table slots per hop of a detection (least recently used slots are refilled).
SLOTS_PER_HOP = 4
#: A detection that agrees with a fit of the last WARM_HOPS hops starts from that fit's
#: prediction: a 3 × 3 grid of ±WARM_HALF_LOBES grating lobes and ±WARM_HALF_SPANS speed
#: spans, then the quadratic fit; the full search where its maximum is on that grid's edge.
WARM_HOPS = 3
WARM_HALF_LOBES = 1.0 / 16.0
WARM_HALF_SPANS = 0.125
#: Quadratic-fit passes from a warm start (its grid's steps are already a quarter of the
#: full search's).
WARM_FIT_PASSES = 3
#: A search without a warm start over more than SUB_HOPS hops first searches the last
#: SUB_HOPS of them (their likelihood's main lobe is wider in speed: a grid of fewer points
#: over the speed span finds it), then fits all ``M`` hops from there as from a warm start;
#: where that fit's maximum is on its small grid's edge, the full search over all ``M`` hops
#: follows. The search's cost then grows with ``M`` only through the final fit.
SUB_HOPS = 10
#: Recent fits kept for that (several echoes at once each keep theirs).
RECENT_FITS = 16
#: Another echo's latest fit is taken out of a detection's input while it is at most this
#: many hops from the detection (its echo continues at the fitted delay and time scale).
KNOWN_HOPS = 3

#: How far (hops) a still echo's boundary may lie from where the band's edge detection puts
#: it (:meth:`CoherentRefiner.refine_still`): the edge hypothesis's comb moves the detection's
#: time by up to a quarter hop (:mod:`hil.estimation.gcas.hidden_echoes`).
STILL_REACH_HOPS = 0.3
#: Grid points per grating lobe of a still echo's time search at rest
#: (:meth:`CoherentRefiner.refine_still`): a step of 1/32 lobe loses at most 0.2 dB of the
#: main lobe's peak, within the 0.8 dB that tells it from its neighbours.
STILL_GRID_PER_LOBE = 32
#: How long (hops) a still echo's fit (:meth:`CoherentRefiner.refine_still`) is taken out of
#: other detections' input: it does not move, and it is measured again only beside a
#: detection that its edge detections could outshine, while a moving echo beside it is
#: followed on without detections for tens of hops (att, a wall 20 dB above a target at
#: 8 m/s: with the wall taken out the target's fit collects 36-38 dB at 0 dB, without it
#: 16-17 dB, and at -10 dB its followed fits moved a grating lobe off 20-25 hops after the
#: wall's latest fit).
STILL_KNOWN_HOPS = 64
#: A still echo's ghosts and their main lobes lie within this many Doppler cells of a whole
#: number of tone spacings' speed from rest (:meth:`CoherentRefiner.ghost_of_rest`: detected
#: from 22.5 to 30 m/s on ``att`` beside a target at rest). The beyond-span check scans no
#: source beyond the span for a detection there where its window holds still water. A still
#: echo measured at rest is taken out of every detection's input, those where it leaks
#: included: left in them (near rest and at its ghosts), it hid every target there (att, a
#: wall 10 dB above a target at 27 m/s: pd 0.03; 16 dB above one at 5 m/s: 0.27), while
#: what its fit leaves there passes the echo test on a few boundaries (a lone echo at rest
#: or 0.05 m/s: false estimates 0.006 -> 0.008 per hop over 24 trials at 0 and -10 dB).
STILL_GHOST_CELLS = 2.0
#: An echo is followed to the boundaries no detection brought (:meth:`CoherentRefiner.due`)
#: where one of its fits collected at least this much more E/N0 than the echo test asks
#: (:attr:`EchoTest.min_e_over_n0_db`, 12 dB on GCAS): the leak of a stronger echo into a
#: ghost's or sidelobe's cells collects 6.7-10.6 dB (att, M = 10), one echo at -20 dB
#: per-sample SNR about 16 dB, so the gate (15 dB) passes such an echo and no leak. Each
#: followed boundary is fitted again and kept only where that fit is one echo. Measured on
#: the scenes (att, M = 10, 2 s, 4 seeds; against a gate at the lobe decision's threshold
#: region, 20.4 dB): a target 10 dB weaker than another at -10 dB per-sample SNR, pd 0.89
#: -> 0.99; in volume reverberation at 0 dB SRR, 0.38 -> 0.67 (the detector, whose noise
#: floor the reverberation's Doppler leak raises by 1.5 dB there, misses its boundaries;
#: its fits collect 16.6-18.6 dB, 10th-90th percentile, with and without reverberation);
#: false estimates at most 0.004 per hop more at any point. With no margin (every echo
#: followed): 0.70 in reverberation, and the still and slow targets' ghosts followed too
#: (0.005 -> 0.010 per hop).
FOLLOW_MARGIN_DB = 3.0
#: Below this many hops per detection an echo is followed only from fits in or above the
#: lobe decision's threshold region (:attr:`CoherentRefiner.lobe_sure_db`): over M = 5 hops a
#: fit on a speed sidelobe (0.6-0.7 m/s off; the main lobe is 0.5 m/s wide there) or at a
#: ghost's speed collects what the echo's own fits do (Fig 6.4's M = 5 at -15 dB: 18.3-19.8
#: dB against 17.4-19.9 dB), and once followed it is the next detections' warm start (that
#: point's false alarms 0.16 -> 0.43/s with the 15 dB gate); at M = 8 (sim-05, -20 dB) the
#: gate at 15 dB gave Pd 0.78 -> 0.90 with no false alarm.
FOLLOW_MIN_HOPS = 8
#: A detection is the echo of a fit when its boundary is within this many grating lobes of
#: where the fit puts it (and its speed within the speed span): a detector's time can be a
#: lobe off beside a stronger echo.
SAME_ECHO_LOBES = 1.5
#: A detection where a measured echo's ghost peaks (:data:`GHOST_HOPS`) is taken for that
#: ghost, without a fit, where read without a fit with that echo taken out (its fitted delay,
#: time scale and amplitude, :meth:`CoherentRefiner._amplitude_near`) it keeps at most this
#: fraction of the echo's fitted amplitude: the ghost is that echo's tones read at another
#: speed, and goes with it. Measured on att (one target at 40-70 m, 12-20 m/s closing and
#: 15 m/s opening, 2 s): its ghosts keep 0.02-0.04 of it at 0 dB per-sample SNR and
#: 0.07-0.13 at -10 dB (5th-95th percentile; 0.26-0.44 read with the echo in). A second echo
#: there keeps its own level (0.7-1.1 of it) and is fitted, with the measured echo taken out;
#: one more than 12 dB below the measured echo is given up.
GHOST_LEFT = 0.25
#: ...plus this many times the noise's reading there (``|β|/sqrt(E/N0)`` of the measured
#: echo's fit, per cell), the largest of the search's cells: where the echo's E/N0 is low
#: (short M at low SNR) what is left at its ghost is the noise's, which reads above
#: GHOST_LEFT alone, and the ghost was fitted and passed the echo test on its few hops.
#: sim-05 (30 trials a point, att, -20 dB per-sample SNR): false alarms per second at M = 3,
#: 5, 10, 22, 29 1.9/0.51/0.29/0.22/0.14 -> 1.2/0.29/0.07/0/0, boundaries detected the same
#: or more (M = 3 180 -> 191); Fig 6.4 at -20 dB M = 5 0.49 -> 0.27/s. At M = 10 and -10 dB
#: (E/N0 about 30 dB) it adds 0.1 of the echo: a second echo 10 dB weaker beside the ghost's
#: row (0.32 of it) and those a tone spacing's speed away 4-6 dB weaker are read as before.
GHOST_NOISE_Z = 3.0
#: Except beside an echo measured within this many Doppler cells of a hop (``c/(2 f_c
#: T_h)``) of rest: there it may be the leak of a still echo the reverberation band hides
#: (att, a target at rest, -10 dB: fits at 2-4 m/s), and what peaks where its ghost would
#: is that still echo's ghost, read at 0.3-1.1 of the fit. A detection there is taken for
#: a ghost up to the measured echo's own strength.
STILL_LEAK_CELLS = 2.0
#: Within STILL_LEAK_CELLS Doppler cells of rest a fit may be the leak of the still water
#: at its own delay (volume reverberation: many still scatterers, each leaking into the
#: speeds beside zero through the hops' Doppler response; taking the strongest of them out
#: leaves 0.67-1.03 of such a fit, so the leak is the field's, not one scatterer's). A fit
#: there is the still water's leak where its amplitude is at most STILL_SIDELOBE_FRACTION of
#: the still echo fitted at its delay (:meth:`CoherentRefiner.still_leak`): an echo alone
#: reads its own leak at zero speed, always below its amplitude, so it keeps a ratio above
#: 1 until the still water at its delay is more than twice as strong. Measured on sim-03's
#: trials (att, M = 10, -10 dB SNR, -10 dB SRR, default band, 30 trials each): the fits at
#: 2.5-4.1 m/s reported beside targets of 10-25 m/s, all false, 0.24-0.52; the estimates of
#: targets of 2-5 m/s, 0.34 (one of 573), then 0.68 (1 %), 0.82 (5 %), 1.41 (median).
STILL_SIDELOBE_FRACTION = 0.5
#: A detection at a measured echo's ghost whose detector statistic is at most this many
#: times the strongest of that echo's ghosts read so far on the same codeword (the hop
#: offset from the echo's, modulo a code period: a ghost's codeword recurs, on att 5-8 of
#: the 17 offsets) is taken for its ghost unread. A second echo at the ghost's speed is read
#: at its first boundary on an offset no ghost took (its detector statistic is 0.6-1.9 of
#: the ghost's), and followed after its fit (:meth:`CoherentRefiner.ghost_of_known`).
GHOST_STRENGTH_MARGIN = 1.5
#: How far (hops) from where an echo's ghost's comb peaks a detection at its ghost's speed is
#: taken for it (:meth:`CoherentRefiner.ghost_of_known`): measured 0.10-0.33 hop after the
#: boundary beside an expected 0.17 (att, 10 m/s, its ghost at -17.5 m/s). Widened by half
#: of what the ``M`` terms' spread of offsets exceeds half a hop: past that the comb's terms
#: that align with the echo's hops change along the comb and its ghost peak spreads (measured
#: 0.02-0.50 hop at M = 15, over ±0.3 hop at M = 22, anywhere in the hop at M = 29).
GHOST_HOPS = 0.25
#: A detection on the span's edge hypothesis where a measured echo's ghost lies beyond that
#: edge (more than one Doppler cell of a hop past it, at most GHOST_LEAK_CELLS: the reach of
#: the Doppler response's tail, as the beyond-span check's guard band) is that ghost's leak
#: when its strength read without a fit is at most GHOST_LEAK_FRACTION of the echo's
#: (:meth:`CoherentRefiner.ghost_of_known`). Measured on att (a target going to and fro at
#: 9 m/s, its ghost at 36.5 m/s beyond a 30 m/s span, 6 s): 314 edge detections, each
#: 0.02-0.089 of the echo, every one refused by its fit (E/N0 6-9 dB); a ghost's own peak
#: reads 0.15-0.34 of its echo. An echo at the edge weaker than that beside a strong one is
#: given up; one 10 dB weaker (0.32) is fitted.
GHOST_LEAK_FRACTION = 0.15
GHOST_LEAK_CELLS = 3.0
#: Times across ±½ grating lobe at which a detection's strength is read against the echo
#: whose ghost it may be (:meth:`CoherentRefiner._amplitude_near`): the likelihood's main
#: peak is ``1/B`` wide (``B`` the tones' span), a lobe holds about K of them (att: 4).
GHOST_POINTS = 9
#: The lobe decision's threshold region (:meth:`CoherentRefiner._lobe_by_more_hops`). The
#: likelihood's grating lobes one ``1/(α Δf)`` apart differ only by the hops' edges: a
#: neighbouring lobe keeps ``ρ = 1 − 1/(α Δf D)`` of the main lobe's amplitude (att at
#: 30 m/s: random-cyclic 0.913, three-state 0.956), and in noise it wins with probability
#: about ``Q(sqrt(E/N0 (1 − ρ)))`` on either side (att random-cyclic at −20 dB per-sample
#: SNR, E/N0 ≈ 17 dB: 3.6 % predicted, 4 % measured; in runs, as consecutive estimates share
#: M − 1 hops). There too a detector's time and speed can sit on the range–Doppler ridge a
#: lobe and about 1 m/s away, where the ±½-lobe search finds a Doppler sidelobe of the
#: codeword (att, 25 m/s, −20 dB: half the main lobe's ``|C|²``). Below
#: ``E/N0 = LOBE_Z² / (1 − ρ)`` (``Q(LOBE_Z) ≈ 1e-3``; att at a 30 m/s span: random-cyclic
#: 20.4 dB, three-state 23.4 dB, both about 6 dB below what an echo at −10 dB per-sample SNR
#: collects) a fit that is an echo is decided among searches over ±LOBE_SPANS speed spans
#: on its own lobe and its neighbours and on the detection's lobe and LOBE_DETECTOR lobes
#: either side (there a detector's time was up to 3.4 lobes off), on the M hops and the M
#: hops before them (there at LOBE_POINTS times across ±⅛ lobe and LOBE_SPEEDS speeds).
LOBE_Z = 3.1
LOBE_POINTS = 9
LOBE_SPEEDS = 3
LOBE_SPANS = 2
LOBE_DETECTOR = 2
#: The earlier hops decide only where they hold the fit's echo: at least LOBE_HELD of the
#: M hops' ``|C|²`` at the fit (one echo of constant speed is as strong there: measured on
#: att random-cyclic, 25 m/s, −20 dB, 616 fits: median 0.88, 5th percentile 0.39, least
#: 0.09). A ghost whose comb aligns at this boundary only holds 0.03 there (att, the ghost
#: of a still echo 6 dB above a −15 m/s target at 0 dB: moved, it left a second ghost); an
#: echo that has just appeared holds noise.
LOBE_HELD = 0.2
#: Two echoes at one speed (a formation) share their tones: each echo's hops hold the other's on the
#: hops where their tones meet, with unrelated phases, so neither fit reaches one echo's coherence
#: until the other is taken out, and neither is taken out until it has passed (measured on att, two
#: closing targets at 10 m/s 3 m apart, 0 dB: every fit at 0.70-0.80 of one echo's coherence, E/N0
#: 33-35 dB; the ghosts of the same scene at 0.30-0.44). A refused fit whose coherence over all hops
#: is at least PARTNER_COHERENCE of one echo's, that collects what an echo must, is kept as a
#: partner for KNOWN_HOPS; a later refused detection of another echo is fitted again with the
#: partners taken out as well, and kept where that fit is one echo (the partner's own next detection
#: then has it as a known echo). Not in the still reverberation's Doppler cells (band off): there
#: every lone scatterer of sparse volume reverberation is such a partner of the next (sim-03 at +5
#: dB SRR, one trial: 1 -> 3 scatterers reported); nor where the caller says a second echo is not
#: looked for (:meth:`CoherentRefiner.refine`'s ``partners``: the reverberation band's and the
#: span's edges, where other echoes' leaks fit as well once a partner is taken out).
PARTNER_COHERENCE = 0.5
#: Two echoes of nearby speeds (within this many Doppler cells of a hop, ``c/(2 f_c T_h)``,
#: 2.5 m/s on att, of each other) share the detector's Doppler resolution cell: each one's
#: row holds the other's Doppler response, so the weaker one's boundary is only a second
#: maximum of its row, decided beside the measured other
#: (:meth:`CoherentRefiner.beside_known`). Measured on att, two targets 2.3-3 m/s apart at
#: 0 dB, independent synthesis: per-target detection 0.48 / 0.49 -> 0.90 / 0.92 (equal),
#: 0.77 / 0.21 -> 0.95 / 0.96, 0.99 / 0.01 -> 1.0 / 0.77 (the second 1 dB weaker), no false
#: estimate or 0.006-0.011 per hop at the first boundaries; one target unchanged.
NEIGHBOUR_CELLS = 2.0
#: How far from a measured echo's speed or its ghosts' (Doppler cells of a hop) it can hide a
#: weaker echo from the first search (:meth:`CoherentRefiner.hidden_by_known`): its Doppler
#: response reaches ``4/(π x)²`` of its peak ``x`` cells away, and the first search takes a
#: cell below twice that beside it for its sidelobe (``search_two_stage.doppler_leak``): an
#: echo 10 dB weaker is hidden within 2.8 cells, 15 dB weaker within 5.
HIDING_CELLS = 4.0
#: Runs of hops kept for the other echoes' ``known`` rows
#: (:meth:`CoherentRefiner._hop_run`; all are dropped when full).
HOP_RUNS = 256
#: A run of hops (:meth:`CoherentRefiner._hop_run`): transmit phasors, tones (Hz), starts
#: after the boundary (s), lengths (s); shape ``(n,)`` each.
_HopRun = tuple[
    NDArray[np.complex128], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]
]
#: ``known`` rows of no other echo.
_NO_KNOWN = np.zeros((5, 0), dtype=np.complex128)
#: An echo that begins or ends within a detection's window (a target appearing, vanishing
#: or jumping: the hops on one side hold noise) loses coherence as drift does, but no rate
#: explains hops that hold no echo: the accelerating fit is not tried where the fit's
#: per-hop power ``|H_i|²/a_i⁴`` (an echo's share of a hop's term grows as ``a_i²``) is
#: below PARTIAL_LEVEL of its mean over at least PARTIAL_HOPS consecutive hops at one end
#: of the window and at none at the other (:meth:`CoherentRefiner._one_sided`). Drift
#: leaves the hops' power alone except where its phase turns within a hop, which happens at
#: both ends alike (the curvature is even about the window's centre). Measured on att,
#: bench_gcas's input (an echo jumping back every 2 s, 0 dB, 20 s): 63 of the 81 fits that
#: meet the other conditions at M = 10 and 246 of 264 at M = 29 are one-sided; tried there,
#: the accelerating fit is kept 18 and 9 times (1.2-1.3 m/s² on a target of constant
#: speed), on the others never. Braking targets of 2-12 m/s² at M = 10 keep their
#: accelerating fits (one fit of seven at 12 m/s² is one-sided).
PARTIAL_LEVEL = 0.25
PARTIAL_HOPS = 2
#: An estimate says its echo is there at its boundary, so the window's last hop must hold
#: it. A window whose echo ended ``k`` hops before its end still fits one echo on its
#: earlier hops (the detector fires on it for up to ``M − 1`` boundaries after the end). The
#: fit's echo is taken to have ended within the window (:attr:`Refinement.ended`) where, for
#: some ``k`` in ``1 … M − 1``, one echo on the first ``M − k`` hops and none on the last
#: ``k`` leaves a residual ``RSS_k`` over the hops' terms (``y_i = H_i/a_i²`` weighted by
#: ``a_i²``) so much smaller than one echo through all ``M`` hops leaves, ``RSS_M``, that
#: ``G_k = (RSS_M − RSS_k) / (RSS_k/(M − 1)) > (M − 1)((M − 1)/ENDED_CHANCE)^{1/(M−1)} −
#: (M − 1)`` (:meth:`CoherentRefiner._ended`). The hops' scatter is measured, not modelled
#: as white noise: reverberation and fading make a hop's term stray from the echo's far more
#: than the fit's E/N0 says (a 3-4 m/s target at -10 dB SRR: 0.35-1.7 of the mean at 25 dB),
#: and are not an end. For an echo there through the window each ``G_k`` is at most an
#: ``F(2, 2(M − 1))`` variable (a tail ``(1 + g/(M − 1))^{−(M − 1)}``), so at most
#: ENDED_CHANCE of such fits are refused (union over the ``M − 1`` splits; 15.8 at M = 10,
#: 12.4 at M = 29). At high SNR this refuses a last hop holding less than about half the
#: echo's amplitude (the boundary more than half a hop after the echo's last sample); at low
#: SNR only a surely empty end. Measured on att with an echo made outside this repository (60
#: m closing at 12 m/s, 3 seeds): an echo that ends keeps no estimate beyond the boundary
#: whose last hop straddles its end at 0 and -10 dB, M = 10 and 29 (183 refused); at -20 dB
#: (M = 10) 2 of 6 such later estimates are; no estimate of a continuous echo is (0, -10,
#: -20 dB, 2800; the largest G 4.6), nor of sim-03's 2-5 m/s targets in reverberation (577).
ENDED_CHANCE = 1e-3
#: :meth:`CoherentRefiner.left_beside_known`'s grid: ±LEFT_LOBES grating lobes in LEFT_TIMES
#: times (a quarter lobe apart) by LEFT_SPEEDS speeds over ± the speed span. ±½ lobe is not
#: enough: beside another echo a detector's time can be a lobe off its echo's (att, M = 5:
#: fits accepted as echoes read from 9.6 dB on ±½ lobe, from 12.5 dB on ±1.5 lobes).
LEFT_LOBES = 1.5
LEFT_TIMES = 13
LEFT_SPEEDS = 5

#: The lobe decision beside still water (:meth:`CoherentRefiner._lobe_without_still`,
#: :mod:`hil.estimation.still_lobe`). A fit is judged on the input without its still water
#: where, over its ``M`` hops' samples, the still water's power is at least STILL_OVER_REST
#: of the rest's (noise and moving echoes, the whole band) and at least STILL_OVER_ECHO
#: times the fitted echo's. Measured on att, M = 10: in volume reverberation at 0 dB SRR a
#: target 10 dB below another reads 3.6-15 times its own power (5th percentile to largest),
#: the stronger one 0.36-1.3 (its fits a lobe off: none); of the fits at least twice their
#: own power, the weaker target's read 0.38-0.62 of the rest at 0 dB per-sample SNR and
#: 0.061-0.127 at -10 dB, where without reverberation they read 0.015-0.033 (-10 dB) or
#: there are none (0 dB; every fit there -0.08 to 0.11, the stronger echoes' own copies).
#: Elsewhere the fit is left as found.
#: The evidence spans STILL_LOBES grating lobes either side of the fit, STILL_LOBE_POINTS
#: times across ±⅛ lobe each (the main peak is ¼ lobe wide on att), over STILL_WINDOWS
#: windows of M hops: with the still water and the other echoes out, a correct fit's
#: neighbours read 0.79-0.85 of it (``ρ²`` of the white-noise lobe decision, :data:`LOBE_Z`),
#: fits a lobe off 1.15-1.64 (that scene, one seed); over one window with the stronger echo
#: left in, correct fits' neighbours reached 1.05 and fits a lobe off read their echo's lobe
#: at 0.93-1.17 of their own: no decision.
STILL_OVER_REST = 0.05
STILL_OVER_ECHO = 2.0
#: ...and where the canceller keeps at least STILL_GAIN_MIN of the echo's SNR
#: (:func:`~hil.estimation.still_lobe.canceller_gain`; 3.6 % of the speeds from 2.5 to 30
#: m/s on att keep less, in bands about every 4 m/s): sim-03's 3.9 m/s target at -10 dB SNR
#: and SRR, kept 0.11-0.36 there, had two fits moved a lobe off, from its echo's lobe.
STILL_GAIN_MIN = 0.5
STILL_LOBES = 2
STILL_LOBE_POINTS = 5
STILL_WINDOWS = 2
#: Table slots per hop of the refiner of the input without its still water: a decision
#: reads each hop of its windows at 2 (2 STILL_LOBES + 1) times (both terms, every lobe), and
#: the next decision of the same echo reads the same hops' windows again (kept, only the new
#: hop's tables are made).
STILL_SLOTS_PER_HOP = 2 * (2 * STILL_LOBES + 1) * STILL_WINDOWS + 4


#: The echo test of a refiner built without one (:meth:`Refinement.is_echo`).
ECHO_TEST = EchoTest(0.8, 0.85, 12.0)


class CoherentRefiner:
    """Local maximum-likelihood delay and Doppler of detections (module docstring).

    Parameters
    ----------
    schedule:
        The transmit schedule (tones: no chirp; equal hop lengths); the first input sample is
        at its t = 0.
    fs_hz:
        Input sample rate, Hz.
    m_hops:
        Hops per detection (the detector's M).
    sound_speed_mps:
        c, m/s.
    speed_span_mps:
        Half-width of the speed search around the detector's speed, m/s (several times the
        detector's speed error).
    max_speed_mps:
        The largest speed a detection can have, m/s (sets the widest window kept and the
        lobe decision's threshold, :attr:`lobe_sure_db`).
    echo_test:
        :meth:`Refinement.is_echo`'s thresholds: a fit that is an echo seeds the warm start
        of the next detections of its echo.
    window_speed_mps:
        The largest speed a fit is asked at, m/s, where above ``max_speed_mps`` (the
        beyond-span check fits the sources of ghosts up to tone spacings past the span):
        sets the widest window and the history kept; the lobe threshold keeps
        ``max_speed_mps``'s.
    """

    def __init__(
        self,
        schedule: HopSchedule,
        fs_hz: float,
        m_hops: int,
        sound_speed_mps: float,
        speed_span_mps: float,
        max_speed_mps: float,
        echo_test: EchoTest = ECHO_TEST,
        window_speed_mps: float | None = None,
        still_free: bool = True,
        slots_per_hop: int = SLOTS_PER_HOP,
    ) -> None:
        if np.any(schedule.chirp_hz_per_s != 0):
            raise ConfigError("refine", True, "a schedule of tones (no chirps)", "refine=False")
        if np.ptp(schedule.duration_s) > 1e-12:
            raise ConfigError("refine", True, "a schedule of equal hop lengths", "refine=False")
        if not (math.isfinite(speed_span_mps) and speed_span_mps > 0):
            raise ConfigError("speed_span_mps", speed_span_mps, "a finite speed > 0 m/s")
        self.schedule = schedule
        self.fs_hz = float(fs_hz)
        self.m_hops = int(m_hops)
        self.c = float(sound_speed_mps)
        self.speed_span_mps = float(speed_span_mps)
        #: What a fit must reach to be an echo (:meth:`Refinement.is_echo`).
        self.echo_test = echo_test
        # The speed grid steps by half the Doppler resolution of the M hops,
        # c / (2 f_max M T_h): coarser, its points can all miss the main lobe (long M).
        v_res = self.c / (2.0 * float(np.max(schedule.tones_hz)) * m_hops * schedule.hop_s)
        half_steps = int(math.ceil(self.speed_span_mps / (0.5 * v_res)))
        self.speed_points = max(SPEED_POINTS, 2 * half_steps + 1)
        self.v_res = v_res
        #: Hops of the first search (:data:`SUB_HOPS`; all ``M`` where ``M`` is not more).
        self.sub_hops = min(SUB_HOPS, self.m_hops)
        #: The run coherence from which the accelerating fit is tried
        #: (:data:`~hil.estimation.refine_accel.ACCEL_RUN_MIN`).
        self._accel_run_min = ACCEL_RUN_MIN if self.m_hops <= SUB_HOPS else ACCEL_RUN_MIN_LONG
        half_sub = int(math.ceil(self.speed_span_mps * self.sub_hops / (0.5 * v_res * m_hops)))
        self.sub_speed_points = max(SPEED_POINTS, 2 * half_sub + 1)
        tones = np.unique(np.asarray(schedule.tones_hz, dtype=np.float64))
        self.spacing_hz = float(np.min(np.diff(tones))) if tones.size > 1 else 1 / schedule.hop_s
        self.n_tones = int(np.asarray(schedule.tones_hz).shape[0])
        self.hop_len_s = float(schedule.duration_s[0])
        v_max = abs(float(max_speed_mps)) + self.speed_span_mps
        v_window = max(v_max, abs(float(window_speed_mps or 0.0)) + self.speed_span_mps)
        alpha_lo = (self.c - v_window) / (self.c + v_window)
        # How far a candidate's window edge can move from the detection's: the time grid's
        # reach (±½ lobe and the fit's two steps), the edges' drift over M hops as α moves
        # by up to twice the speed span (a reused table's own α may be a quarter span away,
        # the fit may step past the grid), and the reuse slack.
        lobe = 1.0 / (alpha_lo * self.spacing_hz)
        reach = 0.5 * lobe * (1.0 + 4.0 / (TIME_POINTS - 1))
        drift = (self.m_hops + 1) * self.hop_len_s * 4.0 * self.speed_span_mps / self.c
        self._half = int(math.ceil((reach + drift) * self.fs_hz)) + REUSE_SLACK + 2
        self._alpha_tol = 0.5 * self.speed_span_mps / self.c  # a quarter span, as a time scale
        # Below this E/N0 (dB) a fit's grating lobe is decided on 2M hops (:data:`LOBE_Z`):
        # the neighbouring lobe's amplitude ρ at the fastest time scale (the shortest lobe).
        alpha_hi = (self.c + v_max) / (self.c - v_max)
        rho = 1.0 - 1.0 / (alpha_hi * self.spacing_hz * self.hop_len_s)
        self.lobe_sure_db = 10.0 * math.log10(LOBE_Z**2 / max(1.0 - rho, 1e-12))
        #: E/N0 (dB) one of an echo's fits must reach for it to be followed (:meth:`due`,
        #: :data:`FOLLOW_MARGIN_DB`, :data:`FOLLOW_MIN_HOPS`).
        self.follow_db = (
            echo_test.min_e_over_n0_db + FOLLOW_MARGIN_DB
            if self.m_hops >= FOLLOW_MIN_HOPS
            else self.lobe_sure_db
        )
        # The M hops of a detection and the M before them (the lobe decision's threshold
        # region, :data:`LOBE_Z`).
        self.history = int(math.ceil((2 * self.m_hops + 1) * self.hop_len_s / alpha_lo * fs_hz))
        self.history += 2 * self._half + 8
        #: :attr:`history` without the caller's decision lag (:meth:`allow_lag`).
        self._own_history = self.history
        self._ring = RowBuffer(self.history, (), np.float64)
        self._valid_from = 0
        n_slots = int(slots_per_hop) * self.m_hops
        rows = 2 * self._half + 2
        self._prefix = np.zeros((n_slots, 2, rows + 1, N_MOMENTS), dtype=np.complex128)
        self._energy = np.zeros((n_slots, 2, rows + 1))
        self._first = np.zeros(n_slots, dtype=np.int64)
        self._tail = np.zeros(n_slots, dtype=np.int64)
        self._alpha0 = np.zeros(n_slots)
        self._centre = np.zeros(n_slots)
        self._edge = np.zeros(n_slots)  # the lower window edge the slot was made for, samples
        self._hop = np.full(n_slots, np.iinfo(np.int64).min, dtype=np.int64)
        self._used = np.zeros(n_slots, dtype=np.int64)
        self._clock = 0
        self._codewords = CodewordBook.of(schedule, self.m_hops, self.fs_hz)
        self._hop_runs: dict[tuple[int, int, int], _HopRun] = {}
        self._sub_words: dict[int, Codeword] = {}
        self._half_words: dict[tuple[int, bool], Codeword] = {}
        self._recent: deque[tuple[int, float, float, float]] = deque(maxlen=RECENT_FITS)
        #: The detections brought lately, ``(hop_index, t_s, speed m/s)``, the latest last:
        #: the acceleration the earlier ones show seeds the latest's curved fit
        #: (:func:`~hil.estimation.refine_accel.speed_trend`).
        self.detections: deque[tuple[int, float, float]] = deque(maxlen=4 * ACCEL_SEED_HOPS + 1)
        #: The latest curved fit of each echo accelerating towards rest, ``(hop_index, t_s,
        #: alpha, rate 1/s, E/N0 dB)`` (:meth:`band_exit`).
        self._into_band: deque[tuple[int, float, float, float, float]] = deque(maxlen=RECENT_FITS)
        #: The latest fit of each echo measured lately (:meth:`_known_hops`).
        self._echoes: list[EchoFit] = []
        #: Refused fits that may be one of two echoes at one speed (:data:`PARTNER_COHERENCE`).
        self._partners: list[EchoFit] = []
        # The acceleration grid's time-scale rates (1/s): an eighth of a cycle of the highest
        # tone at the window's ends, ±half the window from its centre, a step.
        half_window = 0.5 * self.m_hops * self.hop_len_s
        step = 1.0 / (4.0 * float(np.max(schedule.tones_hz)) * half_window**2)
        n_side = min(int(math.ceil(2.0 * MAX_ACCEL_MPS2 / self.c / step)), ACCEL_POINTS // 2)
        self.gammas = step * np.arange(-n_side, n_side + 1, dtype=np.float64)
        # A ghost's speed offset, c Δf / (2 f_c) (m/s), and one Doppler cell of a hop (m/s).
        f_c = 0.5 * float(np.min(schedule.tones_hz) + np.max(schedule.tones_hz))
        self._ghost_speed = self.c * self.spacing_hz / (2.0 * f_c)
        self._cell_speed = self.c / (2.0 * f_c * self.hop_len_s)
        #: Speeds below this share their Doppler cells with the still reverberation (m/s,
        #: :func:`~hil.estimation.reverb_band.doppler_resolution_mps`).
        self._still_mps = doppler_resolution_mps(schedule.tones_hz, self.hop_len_s, self.c)
        #: The likelihood's main lobe in time, ``1/B`` (s; ``B`` the tones' span): how far a
        #: followed fit may move from where its echo's fit carried it (:meth:`refine`).
        tones = np.asarray(schedule.tones_hz, dtype=np.float64)
        self.main_lobe_s = 1.0 / (float(np.ptp(tones)) if tones.size > 1 else 1.0 / self.hop_len_s)
        # :meth:`_ended`'s F test: its degrees of freedom and threshold, and its kernel
        # call's buffers (one candidate: t, α, rate; C, model, no input energy; the hops'
        # terms).
        self._end_m = float(self.m_hops - 1)
        self._end_limit = self._end_m * ((self._end_m / ENDED_CHANCE) ** (1.0 / self._end_m) - 1)
        self._end_buffers = (
            np.zeros(1), np.zeros(1), np.zeros(1), np.empty(1, np.complex128), np.empty(1),
            np.empty(0), np.empty((1, self.m_hops), np.complex128),
        )  # fmt: skip
        #: The input with the still water taken out and a refiner of it, for the lobe
        #: decision beside still water (:meth:`_lobe_without_still`); None where the schedule's
        #: still water does not repeat in whole samples.
        self._still: StillStreams | None = None
        self._still_fits: CoherentRefiner | None = None
        self._still_period_s = 0.0
        self._still_extra = 0
        period = schedule.period_samples(self.fs_hz) if still_free else None
        if period:
            try:
                q, sign = still_period(schedule, period)
            except ConfigError:
                q = 0
            if q:
                self._still_period_s = q / self.fs_hz
                self._still_fits = CoherentRefiner(
                    schedule, fs_hz, m_hops, sound_speed_mps, speed_span_mps, max_speed_mps,
                    echo_test, window_speed_mps, still_free=False,
                    slots_per_hop=STILL_SLOTS_PER_HOP,
                )  # fmt: skip
                # Its history reaches the earlier windows (:data:`STILL_WINDOWS`, one more
                # where the latest's copy is not in yet) and the copies' move.
                self._still_extra = int(
                    math.ceil(
                        (STILL_WINDOWS * self.m_hops * self.hop_len_s / alpha_lo
                         + q / self.fs_hz * (1.0 / alpha_lo - 1.0)) * self.fs_hz
                    )
                )  # fmt: skip
                self._still_fits.allow_lag(self._still_extra)
                self._still = StillStreams(q, sign, self._still_fits.history)
                self._still_fits._valid_from = self._still.valid_from

    # ------------------------------------------------------------------ stream
    def allow_lag(self, samples: int) -> None:
        """Keep ``samples`` (input samples) more history: a detection reaches :meth:`refine`
        up to that long after its boundary's samples were pushed (the caller's decision lag),
        and its hops' windows must still be in the history. Forgets the history."""
        if samples < 0:
            raise ConfigError("samples", samples, ">= 0 (input samples of decision lag)")
        self.history = self._own_history + int(samples)
        self._ring = RowBuffer(self.history, (), np.float64)
        if self._still is not None and self._still_fits is not None:
            self._still_fits.allow_lag(int(samples) + self._still_extra)
            self._still = StillStreams(
                self._still.period, self._still.sign, self._still_fits.history
            )
        self.reset(0)

    def reset(self, input_index: int) -> None:
        """Forget the history; the next sample is ``input_index`` (after a gap)."""
        self._ring.reset(input_index)
        self._valid_from = int(input_index)
        self._hop[:] = np.iinfo(np.int64).min
        self._recent.clear()
        self.detections.clear()
        self._into_band.clear()
        self._echoes.clear()
        self._partners.clear()
        if self._still is not None and self._still_fits is not None:
            self._still.reset(input_index)
            self._still_fits.reset(input_index)
            self._still_fits._valid_from = self._still.valid_from

    def warm_up(self) -> None:
        """Run every compiled kernel once on a made-up detection in silence, then forget it:
        the first call in a process loads the machine code from numba's cache (or compiles
        it, seconds), which must not happen at the first live detection. Every codeword's
        window moments (one FFT each, for the bounds) are made now for the same reason."""
        for key in range(self.schedule.period_hops):
            self._codeword(key)
        hop = 2 * self.m_hops + 1
        t_b = float(self.schedule.hops(hop + 1, 1).start_s[0])
        self.reset(0)
        self.push(np.zeros(int(math.ceil(t_b * self.fs_hz)) + 2 * self.history), 0)
        self.refine(t_b, 1.0, hop)
        self._amplitude_near(t_b, 1.0, hop, around=True)
        self.correlation(t_b, 1.0, hop, np.array([t_b]), np.array([1.0]))
        echo_samples(np.zeros((5, 1), dtype=np.complex128), 0, 1, self.fs_hz)
        # :meth:`_ended` runs on echoes only, which silence has none of.
        ended_gain(
            np.zeros(self.m_hops, np.complex128), np.zeros(self.m_hops), 0.0, 1.0, 1.0
        )  # fmt: skip
        self.reset(0)

    def push(self, x: NDArray[np.float64], first_index: int) -> None:
        """Append input samples (shape ``(n,)``) starting at absolute index ``first_index``."""
        self._ring.append(x, first_index)
        if self._still is not None:
            self._still.push(x, first_index)

    def _still_up_to_date(self, still: StillStreams, fits: CoherentRefiner) -> None:
        """Bring the refiner of the input without its still water up to the input pushed:
        ``y`` (:meth:`StillStreams.canceller`) of the samples pushed since it was last read,
        or of its whole history where more have been pushed since (its earlier samples are
        then out of its reach: :attr:`_valid_from` moves past them). The samples it holds are
        the ones pushing ``y`` with the input would give it; ``y`` is made only where a lobe
        decision reads it (:meth:`still_free_evidence`)."""
        ring, newest = fits._ring, still.next_index
        first = ring.next_index
        if first >= newest:
            return
        if newest - first > fits.history:
            first = newest - fits.history
            ring.reset(first)
            fits._valid_from = max(still.valid_from, first)
        ring.append(still.canceller(first, newest), first)

    # ------------------------------------------------------------------ refinement
    def refine(
        self, t_s: float, alpha: float, hop_index: int, echo_test: EchoTest | None = None,
        partners: bool = True, followed: bool = False, residual: bool = False,
        lag_s: float = 0.0, pairs: bool = False, new_pairs: bool = False,
        curve: tuple[float, float, float] | None = None, halves: bool = True,
        remember: bool = True,
    ) -> Refinement | None:  # fmt: skip
        """The maximum-likelihood boundary time and time scale near ``(t_s, alpha)`` for the
        boundary that ends hop ``hop_index``; None where the input does not cover the ``M``
        hops (start, gaps). Where no maximum lies inside the search (``found`` False) the
        detection's own point is kept and its fit reported. The other echoes measured lately
        are taken out of the input first (module docstring, several echoes). A fit that
        passes ``echo_test`` (default :attr:`echo_test`) is remembered as one echo. With
        ``partners`` a refused fit may be one of two echoes at one speed
        (:data:`PARTNER_COHERENCE`); the caller says where that cannot be (the reverberation
        band's edges, the span's). A ``followed`` boundary (no detection brought it,
        :meth:`due`) at ``t_s`` where its echo's fit carried on is measured only within the
        likelihood's main lobe (``1/B``) of ``t_s`` (further is another grating lobe or
        another echo, and remembered it would be followed on) and where the fit's last hop
        holds its echo (at least
        :data:`PARTIAL_LEVEL` of the hops' mean power): an echo that ended within the window
        still fits one echo on its earlier hops, and followed on it would go on where it
        is no more; None otherwise. Where its window holds still water
        (:meth:`in_still_water`) its grating lobe is its echo's, which that echo's fits
        decided: a fit weaker than :attr:`lobe_sure_db` stays on the lobe of ``t_s`` (no lobe
        moves, no lobe decision on more hops or without the still water; att, M = 10, an echo
        at -20 dB per-sample SNR beside volume reverberation: those decisions moved a third
        of its followed fits a lobe off, then refused); a stronger fit decides its lobe on
        its own hops. In open water its lobe is decided as a detection's, and a fit the lobe
        moves put more than the main lobe from ``t_s`` is refused (a three-state chain
        followed from a detection off its echo, at -20 dB, collects 16-17 dB: the lobe moves
        end it). A ``residual`` detection is the second search's
        (:meth:`known_input`): its echo, remembered, is not taken out of that search's input
        (a followed fit keeps its echo's own). ``lag_s``: how far (s) the detection may lie
        behind the fits measured since (the second search's lag): an echo whose latest fit is
        up to that much later than :data:`KNOWN_HOPS` hops after the detection is taken out
        too (:meth:`_known_hops`). With ``pairs`` a refused fit may be two echoes
        of one time scale close in range (:mod:`hil.estimation.refine_pair`): where they are
        resolved the fit returned carries the other as :attr:`Refinement.second`, both
        remembered; a pair not measured before is looked for only with ``new_pairs`` too
        (:meth:`_two_echoes`). ``curve``: where an echo's earlier fit carried on puts the
        boundary (s, time scale, rate 1/s; :meth:`band_exit`), the fit's warm start in place
        of a recent fit's. ``halves``: whether a curved fit may be seeded from the window's
        halves (:func:`~hil.estimation.refine_accel.halves_seed`; the caller says where not:
        the span's edges, which gather other echoes' leaks). Without ``remember`` neither the
        detection nor its fit is kept (no warm start, no echo taken out or followed, no speed
        trend): a look at a detection that is refused whatever its fit (a ghost on the
        reverberation band's edge whose source is looked for beyond the span,
        :mod:`hil.estimation.gcas.beyond_span`)."""
        test = self.echo_test if echo_test is None else echo_test
        word = self._codeword(hop_index)
        hop_ids = np.arange(hop_index - self.m_hops + 1, hop_index + 1, dtype=np.int64)
        lobe = 1.0 / (alpha * self.spacing_hz)
        speed0 = self.c * (alpha - 1.0) / (alpha + 1.0)
        known = self._known_hops(hop_index, t_s, speed0, lag_s)
        if not followed and remember:
            # A followed boundary's time and speed are its echo's fit carried on, no detection.
            self.detections.append((hop_index, t_s, speed0))
        keep_lobe = followed and self.in_still_water(t_s, alpha)
        fit = self._fit_near(word, hop_ids, t_s, speed0, lobe, hop_index, known, keep_lobe, curve)
        if keep_lobe and fit is not None and fit.e_over_n0_db >= self.lobe_sure_db:
            # Strong enough to tell its lobe from the neighbours' on its own M hops.
            keep_lobe = False
            fit = self._fit_near(word, hop_ids, t_s, speed0, lobe, hop_index, known)
        if followed and fit is not None:
            if abs(fit.t_s - t_s) > self.main_lobe_s:
                return None  # another grating lobe, or another echo
            power = self._hop_powers(fit, word, hop_ids, known)
            if power is None or power[-1] < PARTIAL_LEVEL * np.mean(power):
                return None
        if (
            fit is not None
            and fit.found
            and fit.accel_mps2 == 0.0
            and fit.coherence.fraction < ACCEL_TRY
            and fit.run_coherence.fraction >= min(ACCEL_RUN_SEEDED, self._accel_run_min)
            and fit.e_over_n0_db >= test.min_e_over_n0_db + ACCEL_MARGIN_DB
        ):
            # The detections' trend is read only where a curved fit may be tried.
            seed = None if followed else accel_seed(self, hop_index, t_s, speed0, lobe)
            one_sided: bool | None = None
            if seed is None and halves and not followed and not self.in_still_water(t_s, alpha):
                # No track to read it from (an echo just detected, or out of the band):
                # the window's own halves (HALVES_MIN_HOPS). Not where the window holds still
                # water: there strong incoherent fits are its leaks and ghosts, whose halves
                # cost 4-7 % of the receiver's CPU (att random-cyclic, 0 dB SRR) and seed
                # nothing; a target moving there keeps its detections' track.
                one_sided = self._one_sided(fit, word, hop_ids, known)
                if not one_sided:
                    seed = halves_seed(self, fit, word, hop_ids, lobe, known)
            run_min = (
                self._accel_run_min if seed is None else min(ACCEL_RUN_SEEDED, self._accel_run_min)
            )
            if fit.run_coherence.fraction >= run_min and not (
                self._one_sided(fit, word, hop_ids, known) if one_sided is None else one_sided
            ):
                fit = with_acceleration(self, fit, word, hop_ids, lobe, known, seed)
        if (
            fit is not None
            and fit.found
            and fit.accel_mps2 == 0.0
            and not keep_lobe
            and fit.e_over_n0_db < self.lobe_sure_db
            and fit.is_echo(test)
            and abs(fit.speed_mps(self.c)) >= self._still_mps
        ):
            # Not in the still reverberation's Doppler cells (band off): a lone scatterer's
            # weak fit moved to the lobe its neighbours' echoes favour is reported as a still
            # target (sim-03, band off, +5 dB SRR: 136 -> 173 false alarms in 30 trials).
            fit = self._lobe_by_more_hops(fit, word, hop_ids, t_s, speed0, lobe, known)
        if (
            fit is not None
            and fit.found
            and fit.accel_mps2 == 0.0
            and not keep_lobe
            and fit.is_echo(test)
            and abs(fit.speed_mps(self.c)) >= self._still_mps
        ):
            fit = self._lobe_without_still(fit, word, hop_ids, lobe, known)
        if partners and fit is not None and fit.found and not fit.is_echo(test):
            fit = self._with_partners(fit, word, hop_ids, t_s, speed0, lobe, hop_index, known, test)
        if pairs and fit is not None and abs(speed0) >= self._still_mps:
            two = self._two_echoes(
                fit, word, hop_ids, hop_index, lobe, known, test, residual, new_pairs
            )
            if two is not None:
                return two
        if not remember:
            return fit
        if fit is not None and fit.is_echo(test) and self._ended(fit, word, hop_ids, known):
            # Not remembered as its echo's latest, but the next detections of its windows
            # (up to M - 1 after the end) start from it: a warm start each, not a full
            # search (bench_gcas at M = 29: 4.3 -> 1.9 s of CPU per 20 s, the same estimates).
            self._recent.append((hop_index, fit.t_s, fit.alpha, fit.rate(self.c)))
            return replace(fit, ended=True)
        if fit is not None and fit.is_echo(test):
            self._recent.append((hop_index, fit.t_s, fit.alpha, fit.rate(self.c)))
            self._remember(fit, hop_index, None if followed else not residual)
            if fit.accel_mps2 * fit.speed_mps(self.c) < 0.0:
                self._slowing(fit, hop_index)
        return fit

    def _slowing(self, fit: Refinement, hop_index: int) -> None:
        """Keep ``fit`` (accelerating towards rest, of the boundary ending hop ``hop_index``)
        as its echo's latest curve into the still band (:meth:`band_exit`), in place of
        an earlier fit of the same echo (one whose curve puts this boundary within
        :data:`SAME_ECHO_LOBES` grating lobes of the fit)."""
        lobe = 1.0 / (fit.alpha * self.spacing_hz)
        for i, (hop, t_fit, a_fit, gamma, _) in enumerate(self._into_band):
            curve = self._on_curve(hop, t_fit, a_fit, gamma, hop_index)
            if curve is not None and abs(curve[0] - fit.t_s) <= SAME_ECHO_LOBES * lobe:
                del self._into_band[i]
                break
        self._into_band.append((hop_index, fit.t_s, fit.alpha, fit.rate(self.c), fit.e_over_n0_db))

    def _on_curve(
        self, hop: int, t_fit: float, a_fit: float, gamma: float, hop_index: int
    ) -> tuple[float, float] | None:
        """Where the curve of a fit (boundary ending hop ``hop`` at ``t_fit``, s, time scale
        ``a_fit`` changing at ``gamma``, 1/s) puts the boundary ending hop ``hop_index``:
        its receive time (s) and time scale; None before the fit or where the curve turns
        back (its time scale reaches zero first)."""
        k = hop_index - hop
        if k < 1:
            return None
        # The transmit time heard tau after t_fit is T + a_fit tau + gamma tau² / 2.
        span = k * self.hop_len_s
        root = a_fit * a_fit + 2.0 * gamma * span
        if root <= 0.0:
            return None
        tau = 2.0 * span / (a_fit + math.sqrt(root))
        return t_fit + tau, a_fit + gamma * tau

    def band_exit(
        self, t_s: float, alpha: float, hop_index: int, least_mps: float
    ) -> tuple[tuple[float, float, float], float] | None:
        """Where the curve of an echo that went into the still band accelerating
        (:meth:`_slowing`) and has come out on the other side puts the boundary ending hop
        ``hop_index`` (its receive time s, time scale and rate 1/s: :meth:`refine`'s
        ``curve``), and the E/N0 (dB) that echo's fit collected going in, where a detection
        ``(t_s, alpha)`` on the band's edge (refused there as a rule) lies on it: the
        curve's boundary within :data:`SAME_ECHO_LOBES` grating lobes of the detection, at a
        speed of the detection's sign at least ``least_mps`` (m/s), and not yet past it by
        more than a window's lag (``|a| M T_h``: the detections then are off the edge) and
        the speed span; else None. A target that moves on through rest comes out of the band
        on its curve while its window still holds hops inside (the detector, reading the
        window's mean speed, sees it on the edge for ``M/2`` hops); one that stops does not."""
        lobe = 1.0 / (alpha * self.spacing_hz)
        speed = self.c * (alpha - 1.0) / (alpha + 1.0)
        for hop, t_fit, a_fit, gamma, e_db in reversed(self._into_band):
            curve = self._on_curve(hop, t_fit, a_fit, gamma, hop_index)
            if curve is None:
                continue
            v = self.c * (curve[1] - 1.0) / (curve[1] + 1.0)
            lag = abs(gamma) * self.c / 2.0 * self.m_hops * self.hop_len_s
            if (
                abs(curve[0] - t_s) <= SAME_ECHO_LOBES * lobe
                and v * speed > 0.0
                and least_mps <= abs(v) <= least_mps + lag + self.speed_span_mps
            ):
                return (curve[0], curve[1], gamma), e_db
        return None

    def _with_partners(
        self, fit: Refinement, word: Codeword, hop_ids: NDArray[np.int64], t_s: float,
        speed: float, lobe: float, hop_index: int, known: NDArray[np.complex128],
        test: EchoTest,
    ) -> Refinement:  # fmt: skip
        """A refused ``fit`` of the detection at ``t_s`` (s) and ``speed`` (m/s) that may be
        one of two echoes at one speed (it collects what an echo must, with at least
        :data:`PARTNER_COHERENCE` of one echo's coherence) fitted again with the partners of
        other echoes taken out: that fit where it is one echo by ``test``; else ``fit``, kept
        as a partner. A fit short of an echo's E/N0 is neither: taking another fit out only
        lowers the noise it is measured against."""
        if not (
            fit.amplitude != 0
            and fit.e_over_n0_db >= test.min_e_over_n0_db
            and fit.coherence.fraction >= PARTNER_COHERENCE
            and abs(speed) >= self._still_mps
        ):
            return fit
        oldest = fit.t_s - KNOWN_HOPS * self.hop_len_s
        self._partners = [p for p in self._partners if p.t_s >= oldest]
        others = [
            p for p in self._partners
            if abs(p.speed(self.c) - speed) <= self.speed_span_mps
            and not self._same_echo(p, hop_index, t_s, speed)
        ]  # fmt: skip
        if others:
            rows = [known, self.echo_rows(others, t_s)]
            with_others = np.ascontiguousarray(np.concatenate(rows, axis=1))
            again = self._fit_near(word, hop_ids, t_s, speed, lobe, hop_index, with_others)
            if again is not None and again.is_echo(test):
                return again
        v = self.c * (fit.alpha - 1.0) / (fit.alpha + 1.0)
        kept = [p for p in self._partners if not self._same_echo(p, hop_index, fit.t_s, v)]
        new = EchoFit(hop_index, fit.t_s, fit.alpha, fit.amplitude, fit.rate(self.c))
        self._partners = [*kept, new]
        return fit

    def _two_echoes(
        self, fit: Refinement, word: Codeword, hop_ids: NDArray[np.int64], hop_index: int,
        lobe: float, known: NDArray[np.complex128], test: EchoTest, residual: bool,
        new: bool,
    ) -> Refinement | None:  # fmt: skip
        """``fit`` as two echoes of one time scale (:func:`~hil.estimation.refine_pair.
        fit_pair`): the first of them, carrying the second where they are resolved, both
        remembered (the stronger alone where they are one resolution cell); None where they are
        not two echoes, or either ended within the window, or none is looked for. Looked
        for from a pair measured within :data:`WARM_HOPS` hops near ``fit``; else from
        ``fit`` and an echo measured there that it jumped from (:meth:`_jumped`: two echoes
        one grating lobe apart hold the same hops' terms, and the one-echo fit passes on
        either by turns; kept where both collect more than the lobe decision's threshold
        region, :data:`LOBE_Z`); else, with ``new``, where ``fit`` is refused as not one echo yet
        collects what an echo must and is coherent within each tone (each tone's hops hold
        one sum of the two), and its hops were all transmitted (the first ``M − 1``
        boundaries' windows begin before the transmission: a second echo there fits what
        the silence leaves). Whether or not the one-echo search found a maximum: between
        two echoes it may not (``fit`` is then the detection's own point)."""
        seeds = self._pair_seeds(hop_index, fit, lobe)
        jumped = seeds is None and fit.is_echo(test)
        if jumped:
            seeds = self._jumped(hop_index, fit, lobe)
            if seeds is None:
                return None
        elif seeds is None and not (
            new
            and hop_ids[0] >= 0
            and fit.e_over_n0_db >= test.min_e_over_n0_db
            and fit.tone_coherence.fraction >= test.fraction
        ):
            return None
        pair = fit_pair(self, fit, word, hop_ids, hop_index, lobe, known, test, seeds)
        if pair is None:
            return None
        one, two = pair.first, pair.second
        if jumped and min(one.e_over_n0_db, two.e_over_n0_db) < self.lobe_sure_db:
            # An echo and its own grating lobe are two echoes a lobe apart only where each
            # one's lobe is decided surely (LOBE_Z).
            return None
        if self._ended(one, word, hop_ids, known) or self._ended(two, word, hop_ids, known):
            return None
        if not pair.resolved:
            # One resolution cell: its stronger echo.
            one = max((one, two), key=lambda r: abs(r.amplitude))
        kept = [one, two] if pair.resolved else [one]
        for r in kept:
            self._recent.append((hop_index, r.t_s, r.alpha, 0.0))
        self._remember_all(kept, hop_index, not residual, pair.resolved)
        return replace(one, second=two) if pair.resolved else one

    def _pair_seeds(
        self, hop_index: int, fit: Refinement, lobe: float
    ) -> tuple[EchoFit, EchoFit] | None:
        """The two echoes of a pair measured within :data:`WARM_HOPS` hops before
        ``hop_index`` nearest ``fit`` where their fits put this boundary (within the pair's
        search, :data:`~hil.estimation.refine_pair.SEED_LOBES` grating lobes, and the speed
        span); None where there are not two."""
        v = fit.speed_mps(self.c)
        near = []
        for e in self._echoes:
            k = hop_index - e.hop_index
            t = e.boundary_s(hop_index, self.hop_len_s)
            if (
                e.pair
                and 1 <= k <= WARM_HOPS
                and abs(t - fit.t_s) <= SEED_LOBES * lobe
                and abs(e.speed(self.c) - v) <= self.speed_span_mps
            ):
                near.append((abs(t - fit.t_s), e))
        if len(near) < 2:
            return None
        near.sort(key=lambda n: n[0])
        return near[0][1], near[1][1]

    def _jumped(
        self, hop_index: int, fit: Refinement, lobe: float
    ) -> tuple[EchoFit, EchoFit] | None:
        """An echo measured within :data:`WARM_HOPS` hops before ``hop_index`` whose fit
        puts this boundary a resolution cell or more from ``fit`` (at least
        :data:`~hil.estimation.refine_pair.RESOLVED_LOBES` main lobes, at most
        :data:`~hil.estimation.refine_pair.SEED_LOBES` grating lobes, within the speed
        span) while no echo measured lately is carried to ``fit``'s own cell: that echo and
        ``fit`` (the pair's seeds); None otherwise (``fit`` continues an echo, or is alone),
        and where ``fit`` or that echo is in the lobe decision's threshold region
        (:data:`LOBE_Z`: there one echo's fit moves a grating lobe by noise, and the pair of
        an echo and its own lobe fits the hops' edges of the reverberation: sim-03's trials
        at -10 dB SNR and SRR, 4 -> 15 false estimates in 30)."""
        if fit.e_over_n0_db < self.lobe_sure_db:
            return None
        v = fit.speed_mps(self.c)
        main = self.main_lobe_s
        left = None
        for e in self._echoes:
            k = hop_index - e.hop_index
            if not (1 <= k <= WARM_HOPS and abs(e.speed(self.c) - v) <= self.speed_span_mps):
                continue
            gap = abs(e.boundary_s(hop_index, self.hop_len_s) - fit.t_s)
            if gap < RESOLVED_LOBES * main:
                return None
            if gap <= SEED_LOBES * lobe and left is None and e.e_over_n0_db >= self.lobe_sure_db:
                left = e
        if left is None:
            return None
        return left, EchoFit(hop_index, fit.t_s, fit.alpha, fit.amplitude)

    def beside_known(self, t_s: float, alpha: float, hop_index: int) -> bool:
        """Whether a second echo at the speed of a detection at ``t_s`` (s) and time scale ``alpha``
        (the boundary ending hop ``hop_index``) may be there: within :data:`KNOWN_HOPS` hops
        of it and within the speed span, a partner kept lately (:data:`PARTNER_COHERENCE`)
        that is not this detection's own echo, or two echoes measured lately, one of them
        not this detection's own; or an echo measured lately beyond the speed span but
        within :data:`NEIGHBOUR_CELLS` Doppler cells of a hop of it, above the lobe
        decision's threshold region (:data:`LOBE_Z`: near threshold the fits that pass
        include noise's, beside which a second maximum is noise too); or where an echo
        measured lately at its speed puts its boundary and has no fit at this hop yet, while
        another echo's ghost shares the row (the ghost is the row's maximum there, the echo's
        own peak a second one). A second maximum of a
        Doppler row (:mod:`hil.estimation.gcas.candidates`) is decided only there: beside
        one lone echo of its speed it is that echo's shoulder (its fit would be that echo on
        another codeword), and in noise alone one more chance for a false alarm."""
        speed = self.c * (alpha - 1.0) / (alpha + 1.0)
        reach = KNOWN_HOPS * self.hop_len_s

        def near(e: EchoFit) -> bool:
            return abs(e.t_s - t_s) <= reach and abs(e.speed(self.c) - speed) <= self.speed_span_mps

        if any(near(e) and not self._same_echo(e, hop_index, t_s, speed) for e in self._partners):
            return True
        echoes = [e for e in self._echoes if near(e)]
        if len(echoes) >= 2 and any(not self._same_echo(e, hop_index, t_s, speed) for e in echoes):
            return True
        if any(
            e.hop_index < hop_index and self._same_echo(e, hop_index, t_s, speed) for e in echoes
        ) and any(
            abs(e.t_s - t_s) <= reach
            and abs(abs(speed - e.speed(self.c)) - self._ghost_speed) <= self._cell_speed
            for e in self._echoes
        ):
            return True
        cells = NEIGHBOUR_CELLS * self._cell_speed
        return any(
            abs(e.t_s - t_s) <= reach
            and self.speed_span_mps < abs(e.speed(self.c) - speed) <= cells
            and e.e_over_n0_db >= self.lobe_sure_db
            for e in self._echoes
        )

    def followed_near(self, t_s: float, alpha: float, hop_index: int) -> bool:
        """Whether a detection at ``t_s`` (s) and time scale ``alpha`` (the boundary ending hop
        ``hop_index``) is the boundary of an echo that :meth:`due` gives: measured before this
        hop, within :data:`KNOWN_HOPS` hops, held (:attr:`EchoFit.held`) and
        moving, and the same echo (:meth:`_same_echo`). A peak masked by a greater one of
        another boundary (:attr:`~hil.estimation.gcas.threshold.Peak.masked`) is not decided
        there: the echo is fitted where its fit puts it, and the detector's boundary, read
        beside the greater echo's Doppler response, would take that hop from it."""
        speed = self.c * (alpha - 1.0) / (alpha + 1.0)
        return any(
            (e.held or e.e_over_n0_db >= self.follow_db)
            and abs(e.speed(self.c)) >= self._still_mps
            and 0 < hop_index - e.hop_index <= KNOWN_HOPS
            and self._same_echo(e, hop_index, t_s, speed)
            for e in self._echoes
        )

    def due(self, t_s: float) -> list[tuple[int, float, float, float]]:
        """The boundaries of echoes measured lately that no detection brought by ``t_s`` (s):
        for each echo one of whose fits reached :attr:`follow_db` (:data:`FOLLOW_MARGIN_DB`;
        :attr:`EchoFit.held`: one weak echo's fits scatter about its mean, so a gate on each
        fit would drop it at each dip; att, M = 10, the weaker target at -20 dB per-sample
        SNR beside still reverberation: 14.3-18 dB in one seed)
        outside the still reverberation's Doppler cells, its next boundary where its latest
        fit carries on, received before ``t_s`` and at most :data:`KNOWN_HOPS` hops after
        that fit, each once: ``(hop_index, t, α, E/N0)`` (hop, s, 1, dB: what that fit
        collected). Another echo's ghost or
        Doppler response can hold the row's maximum at an echo's boundary (a weaker echo a
        tone spacing's speed from a stronger one: the ghost's peak beside it); the echo is
        then fitted there (:meth:`refine`) and its echo test decides. So are the boundaries
        a fit's detection came after without any brought (:attr:`EchoFit.gap`, where that fit
        puts them): a closing echo's next boundary comes less than a hop after a missed one,
        so before the peaks have passed the missed one by the readout's lag. An echo of a
        formation (:meth:`_formation`: another echo of its speed within a few grating lobes)
        is due one grating lobe earlier: the detections of its next boundary and of its
        partner's come within a lobe of each other, and its own next detection (a lobe early
        at the detector's time) would otherwise pass the boundary it missed."""
        out = []
        for i, e in enumerate(self._echoes):
            if (
                not (e.held or e.e_over_n0_db >= self.follow_db)
                or abs(e.speed(self.c)) < self._still_mps
            ):
                continue
            if e.gap >= 0:
                t_gap = e.boundary_s(e.gap, self.hop_len_s)
                if t_gap <= t_s:
                    out.append((e.gap, t_gap, e.alpha, e.e_over_n0_db))
                    e = replace(e, gap=e.gap + 1 if e.gap + 1 < e.hop_index else -1)
                    self._echoes[i] = e
            hop = max(e.hop_index, e.followed) + 1
            t_next = e.boundary_s(hop, self.hop_len_s)
            if hop - e.hop_index > KNOWN_HOPS:
                continue
            if t_next <= t_s or (
                t_next <= t_s + 1.0 / (e.alpha * self.spacing_hz) and len(self._formation(e)) > 1
            ):
                out.append((hop, t_next, e.alpha, e.e_over_n0_db))
                self._echoes[i] = replace(e, followed=hop)
        return out

    def refine_still(self, t_s: float, hop_index: int, echo_test: EchoTest) -> Refinement | None:
        """The still echo (a wall, a mooring: time scale exactly 1) nearest the boundary at
        ``t_s`` (s) ending hop ``hop_index``: the search from rest (:meth:`_fit_near`, the
        other echoes measured lately taken out) finds its grating lobe, then its delay and
        complex amplitude are fitted at ``α = 1`` (a point echo at rest repeats as the
        transmit does, the still period's sign included: its hops' phases are the
        schedule's). Remembered, as :meth:`refine` remembers a fit, where it is one echo by
        ``echo_test`` (replacing its earlier fits); None where the input does not cover the hops
        or they were not all transmitted (the first ``M`` - 1 boundaries). A fit at the searched
        speed instead (a few cm/s off rest, within the still water's Doppler cell) taken out
        of a moving echo's input leaves that echo a residue growing over its hops."""
        if hop_index < self.m_hops - 1:
            # Not all M hops transmitted: every lobe near the echo's collects about as much.
            return None
        word = self._codeword(hop_index)
        hop_ids = np.arange(hop_index - self.m_hops + 1, hop_index + 1, dtype=np.int64)
        lobe = 1.0 / self.spacing_hz
        # The other echoes, not this one's earlier fits (at rest within the detection's
        # uncertainty, STILL_REACH_HOPS: one a lobe off would push this fit away from it).
        reach = STILL_REACH_HOPS * self.hop_len_s
        others = [
            e for e in self._others(hop_index, t_s, 0.0)
            if not (e.alpha == 1.0 and abs(e.boundary_s(hop_index, self.hop_len_s) - t_s) <= reach)
        ]  # fmt: skip
        known = self.echo_rows(others, t_s)
        near = self._fit_near(word, hop_ids, t_s, 0.0, lobe, None, known)
        if near is None:
            return None
        if not near.found:
            # A start about half a grating lobe from the echo's lobes (the saddle between
            # two): the search from rest stops there, and the lobe scan below reads only
            # +-1/4 lobe around the lobes of where it stopped. From half a lobe either side
            # it climbs a lobe (att, a wall 10 dB above a 27 m/s target at 0 dB: its fits
            # at hops 9, 10 and 13 started about 6 ms, 6.6 lobes, off its boundary and
            # failed; of starts 0-7 ms off in 0.5 ms steps, those 0.5, 5 and 6 ms off).
            for dt in (-0.5 * lobe, 0.5 * lobe):
                other = self._fit_near(word, hop_ids, t_s + dt, 0.0, lobe, None, known)
                if (
                    other is not None
                    and other.found
                    and (not near.found or other.e_over_n0_db > near.e_over_n0_db)
                ):
                    near = other
        # The grating lobe at rest: the band's edge detection puts the echo's time up to a
        # quarter hop off, and at rest every lobe near the echo's collects within 1 dB of its
        # |C|² (att: continuous-phase hops), so the search's own lobe moves, from a fit a
        # few cm/s off rest, stop on any. Each lobe within the reach is read at rest on a
        # grid of ±¼ lobe (main lobe at rest: -1.9 dB 0.1 lobe off), the greatest kept.
        n_lobes = int(math.ceil(reach / lobe))
        step = lobe / STILL_GRID_PER_LOBE
        each = step * np.arange(
            -(STILL_GRID_PER_LOBE // 4), STILL_GRID_PER_LOBE // 4 + 1, dtype=np.float64
        )
        ones, zeros = np.ones(each.size), np.zeros(each.size)
        best_p, centre = -1.0, near.t_s
        for k in range(-n_lobes, n_lobes + 1):
            # Tables of each lobe's own window: a hop's table reaches a few samples beyond it.
            t_lobe = near.t_s + k * lobe
            slots = self.hop_slots(hop_ids, word, t_lobe, 1.0)
            if slots is None:
                continue
            lobe_args = (*self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s)
            power = self.candidate_powers(lobe_args, known, t_lobe + each, ones, zeros)
            i = int(np.argmax(power))
            if power[i] > best_p:
                best_p, centre = float(power[i]), float(t_lobe + each[i])
        slots = self.hop_slots(hop_ids, word, centre, 1.0)
        if slots is None:
            return None
        args = (*self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s)
        best_t, grid_step = centre, step
        for _ in range(FIT_PASSES + 1):
            t3 = best_t + step * np.array([-1.0, 0.0, 1.0])
            p3 = self.candidate_powers(args, known, t3, np.ones(3), np.zeros(3))
            curve = p3[0] - 2.0 * p3[1] + p3[2]
            if curve < 0.0:
                best_t += step * parabolic_offset(p3[0], p3[1], p3[2])
            elif p3[0] != p3[2]:
                best_t = float(t3[0] if p3[0] > p3[2] else t3[2])
            step *= 0.5
        found = near.found and abs(best_t - centre) <= grid_step
        fit = self.refinement_at(args, known, word, best_t if found else centre, 1.0, 0.0, found)
        if fit.is_echo(echo_test):
            self._remember(fit, hop_index, True)
            last = self._echoes[-1] if self._echoes else None
            if last is not None and (last.hop_index, last.t_s) == (hop_index, fit.t_s):
                # It replaces the earlier fits of this still echo (at rest within the reach:
                # one a lobe or two off, kept beside it, would be taken out as a second echo).
                self._echoes = [
                    e for e in self._echoes[:-1]
                    if not (
                        e.still
                        and abs(e.boundary_s(hop_index, self.hop_len_s) - fit.t_s) <= reach
                    )
                ] + [replace(last, still=True)]  # fmt: skip
        return fit

    def still_leak(self, fit: Refinement, hop_index: int) -> bool:
        """Whether ``fit`` (the boundary ending hop ``hop_index``), within
        :data:`STILL_LEAK_CELLS` Doppler cells of rest, is the leak of the still water at its
        delay: its amplitude at most :data:`STILL_SIDELOBE_FRACTION` of the largest still
        echo's fitted within ±½ grating lobe of its time (the other echoes measured lately
        taken out of both). False farther from rest."""
        speed = fit.speed_mps(self.c)
        if abs(speed) > STILL_LEAK_CELLS * self._cell_speed:
            return False
        known = self._known_hops(hop_index, fit.t_s, speed)
        still = self._amplitude_near(fit.t_s, 1.0, hop_index, known=known)
        return abs(fit.amplitude) <= STILL_SIDELOBE_FRACTION * still

    def weak_in_still_leak(self, fit: Refinement) -> bool:
        """Whether ``fit`` lies where a still echo measured lately leaks (within
        :data:`STILL_LEAK_CELLS` Doppler cells of rest, or at one of its ghosts:
        :meth:`ghost_of_rest`), that echo taken out of its input, and is not one echo by
        more than the echo test: it collects less than :attr:`follow_db`, the gate of a fit
        at a boundary no detection of its own brought (:data:`FOLLOW_MARGIN_DB`), or its
        coherence over all hops is below the echo test's :attr:`EchoTest.fraction` (it
        passes over runs of consecutive hops only). There the detection is the still echo's
        leak: with the echo taken out, its fit reads the noise and reverberation left in the
        cells the leak lit, and the echo test, set for detections of their own, passes a
        few of them (a target at rest or 0.05 m/s at -10 dB: fits of 12.0-17.7 dB, 0.16-0.32
        of the still echo's amplitude, at +-24-30 m/s and at any range; braking to rest in
        reverberation at -10 dB: fits of 15.3-17.7 dB whose coherence is 0.73-0.80 over all
        hops and 0.85-0.90 over runs). The run branch is for an echo whose speed drifts over
        the window (such a fit is tried again with an acceleration, :meth:`refine`); where
        a still echo leaks it passed the leak's fits.
        False elsewhere, and where no still echo is measured within :data:`STILL_KNOWN_HOPS`
        hops of it."""
        if fit.e_over_n0_db >= self.follow_db and fit.coherence.fraction >= self.echo_test.fraction:
            return False
        speed = fit.speed_mps(self.c)
        if abs(speed) > STILL_LEAK_CELLS * self._cell_speed and not self.ghost_of_rest(speed):
            return False
        return any(e.still for e in self._measured_near(fit.t_s))

    def known_echoes(self, t_s: float, lag_s: float = 0.0) -> list[tuple[float, float]]:
        """The echoes measured within :data:`KNOWN_HOPS` hops of ``t_s`` (s), the ones taken
        out of a detection's input there: ``(speed m/s, |β|)`` each, ``β`` the fitted
        amplitude (:attr:`Refinement.amplitude`). ``lag_s`` as :meth:`hidden_by_known`'s:
        also those up to that much later."""
        return [(e.speed(self.c), abs(e.amplitude)) for e in self._measured_near(t_s, lag_s)]

    def forget(self, fit: Refinement) -> None:
        """Forget ``fit``, remembered by :meth:`refine` as one echo, where the caller found it
        to be none (another echo's ghost, :mod:`hil.estimation.gcas.ghost_inside`): it is then
        neither taken out of other detections' input, nor followed, nor a warm start."""
        self._echoes = [e for e in self._echoes if (e.t_s, e.alpha) != (fit.t_s, fit.alpha)]
        kept = [r for r in self._recent if (r[1], r[2]) != (fit.t_s, fit.alpha)]
        self._recent.clear()
        self._recent.extend(kept)

    def _measured_near(self, t_s: float, lag_s: float = 0.0) -> list[EchoFit]:
        """The echoes whose latest fits lie within :data:`KNOWN_HOPS` hops of ``t_s`` (s),
        or up to ``lag_s`` (s) more after it (a detection decided that late hears the echoes
        measured since: an echo measured at one speed since is there at that speed before)."""
        reach = KNOWN_HOPS * self.hop_len_s
        still = STILL_KNOWN_HOPS * self.hop_len_s
        return [
            e for e in self._echoes
            if -(still if e.still else reach) <= e.t_s - t_s <= reach + lag_s
        ]  # fmt: skip

    def left_beside_known(
        self, t_s: float, alpha: float, hop_index: int, max_speed_mps: float
    ) -> float | None:
        """The E/N0 (dB) a detection at ``t_s`` (s) and time scale ``alpha``, the boundary
        ending hop ``hop_index``, collects with the echoes measured lately taken out, read at
        the largest ``|C|²`` of a grid of :data:`LEFT_TIMES` times over ±:data:`LEFT_LOBES`
        grating lobes and :data:`LEFT_SPEEDS` speeds over ± the speed span (the lobes the
        full search may reach, :meth:`_fit_near`, at a quarter lobe and half a span): one
        kernel call on the tables of the ``M`` hops at the detection's point, which the full
        search makes there too (read without refusing, every estimate of ``bench_gcas``'s
        input stays bit for bit at M = 5, 10 and 29).

        None where :meth:`refine` would not search from the detection's point: a recent fit
        predicts it (the warm fit), no other echo was measured near (nothing taken out), a
        pair was measured near (its fit starts from the pair whatever the one-echo fit
        finds), or the input does not cover the hops; and where an echo measured near lies
        beyond the span ``±max_speed_mps`` (m/s): the detection may be its ghost, which the
        beyond-span check reads from the fit (:mod:`hil.estimation.gcas.beyond_span`).

        Where an echo was taken out, what is left is its residue and noise, and the full
        search's fit collects little more than this reading: att, ``bench_gcas``'s input,
        over the 430, 420 and 145 such detections at M = 5, 10 and 29, 0.5, 0.8 and 1.6 dB
        more at the median and 5.4, 5.5 and 5.9 dB at most, while every fit accepted as an
        echo read 12.5 dB or more. A reading far below what an echo must collect decides
        such a detection without the fit
        (:data:`~hil.estimation.gcas.readout.LEFT_MARGIN_DB`)."""
        speed = self.c * (alpha - 1.0) / (alpha + 1.0)
        lobe = 1.0 / (alpha * self.spacing_hz)
        if self._predicted(hop_index, t_s, speed, lobe) is not None:
            return None
        others = self._others(hop_index, t_s, speed)
        if not others or any(
            e.pair or abs(e.speed(self.c)) > max_speed_mps for e in self._measured_near(t_s, 0.0)
        ):
            return None
        word = self._codeword(hop_index)
        hop_ids = np.arange(hop_index - self.m_hops + 1, hop_index + 1, dtype=np.int64)
        slots = self.hop_slots(hop_ids, word, t_s, (self.c + speed) / (self.c - speed))
        if slots is None:
            return None
        speeds = speed + self.speed_span_mps * np.linspace(-1.0, 1.0, LEFT_SPEEDS)
        alphas = np.ascontiguousarray((self.c + speeds) / (self.c - speeds))
        known = self.echo_rows(others, t_s)
        args = (*self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s)
        t_first, step = t_s - LEFT_LOBES * lobe, 2.0 * LEFT_LOBES * lobe / (LEFT_TIMES - 1)
        c = np.empty((LEFT_SPEEDS, LEFT_TIMES), dtype=np.complex128)
        grid_sums(*args, known, t_first, step, alphas, c, np.empty(c.shape))
        i, j = np.unravel_index(int(np.argmax(np.abs(c))), c.shape)
        one, model, signal = np.empty(1, np.complex128), np.empty(1), np.empty(1)
        candidate_sums(
            *args, np.array([t_first + j * step]), alphas[i : i + 1], np.zeros(1), one, model,
            signal, np.empty((1, 0), np.complex128), known,
        )  # fmt: skip
        # E/N0 = |C|² / (E_s σ²), σ² E_s = the windows' energy − 2|C|²/E_s (echo_quality).
        mag2 = float(one[0].real * one[0].real + one[0].imag * one[0].imag)
        noise = float(signal[0]) - 2.0 * mag2 / float(model[0])
        return 10.0 * math.log10(mag2 / noise) if noise > 0.0 and mag2 > 0.0 else math.inf

    def known_input(self, first_index: int, count: int) -> NDArray[np.float64] | None:
        """What the echoes measured lately put into input samples ``first_index …``
        (``count`` of them; shape ``(count,)``): each echo's latest fit carried on at its
        delay, time scale (and rate) and amplitude (:mod:`hil.estimation.echo_model`), for
        the echoes fitted within :data:`KNOWN_HOPS` hops of those samples that the first
        search measured (:attr:`EchoFit.cancelled`); None where there is none. Taken out
        of the input, what is left is searched again (:mod:`hil.estimation.gcas.residual`)."""
        t_lo = first_index / self.fs_hz
        t_hi = (first_index + count) / self.fs_hz
        reach = KNOWN_HOPS * self.hop_len_s
        echoes = [e for e in self._echoes if e.cancelled and t_lo - reach <= e.t_s <= t_hi + reach]
        if not echoes:
            return None
        columns = np.concatenate([self._echo_hops(e, t_lo, t_hi) for e in echoes], axis=1)
        return echo_samples(columns, first_index, count, self.fs_hz)

    def recent_input(self, first_index: int) -> tuple[int, NDArray[np.float64]]:
        """The input pushed from ``first_index`` on, or from the earliest sample kept since
        the last reset where that is later: its first index and the samples (shape ``(n,)``,
        a copy)."""
        ring = self._ring
        first = max(int(first_index), self._valid_from, ring.next_index - ring.keep)
        return first, np.array(ring.span(first, ring.next_index))

    def hidden_by_known(self, t_s: float, alpha: float, lag_s: float = 0.0) -> bool:
        """Whether an echo at ``t_s`` (s) and time scale ``alpha`` may have been hidden from
        the first search by an echo taken out of the second search's input
        (:meth:`known_input`, measured within :data:`KNOWN_HOPS` hops): within
        :data:`HIDING_CELLS` Doppler cells of a hop of its speed or of its ghosts' (one tone
        spacing's speed either way), where its Doppler row, its sidelobes above the leak
        bound or its ghost's row hold the weaker echo's cells. Elsewhere the first search
        sees what the second would. ``lag_s``: how far (s) the detection may lie before the
        echoes' latest fits (the second search's lag behind the first)."""
        speed = self.c * (alpha - 1.0) / (alpha + 1.0)
        reach, near = KNOWN_HOPS * self.hop_len_s, HIDING_CELLS * self._cell_speed
        return any(
            e.cancelled
            and -reach <= e.t_s - t_s <= reach + lag_s
            and min(abs(speed - e.speed(self.c) - k * self._ghost_speed) for k in (-1, 0, 1))
            <= near
            for e in self._echoes
        )

    def continues_known(self, t_s: float, alpha: float, hop_index: int, lag_s: float = 0.0) -> bool:
        """Whether a detection at ``t_s`` (s) and time scale ``alpha`` (the boundary ending hop
        ``hop_index``) is where an echo measured within :data:`KNOWN_HOPS` hops puts that
        boundary (:meth:`_same_echo`) and is taken out of the input (:meth:`known_input`):
        what is left of it there. ``lag_s`` as :meth:`hidden_by_known`'s."""
        speed = self.c * (alpha - 1.0) / (alpha + 1.0)
        reach = KNOWN_HOPS * self.hop_len_s
        return any(
            e.cancelled
            and -reach <= e.t_s - t_s <= reach + lag_s
            and self._same_echo(e, hop_index, t_s, speed)
            for e in self._echoes
        )

    def ghost_of_known(
        self, t_s: float, alpha: float, hop_index: int, edge_side: int = 0,
        strength: float = math.inf, residual: bool = False,
    ) -> bool:  # fmt: skip
        """Whether a detection at ``t_s`` (s) and time scale ``alpha``, the boundary ending
        hop ``hop_index``, is the ghost of an echo measured lately, where that echo's every
        tone is read as its neighbour: one tone spacing's speed away from it (within one
        Doppler resolution cell), where its comb peaks, ``(M − 1)/2`` hops of the two time
        scales' drift after one of the echo's boundaries (within :data:`GHOST_HOPS`), and
        not an echo measured lately itself continuing there (a second echo at the ghost's
        speed, found once, is followed through the ghost's hops). It is the ghost where,
        read with the echo taken out, at most :data:`GHOST_LEFT` of the echo's strength is
        left, plus :data:`GHOST_NOISE_Z` times the noise's reading at the echo's E/N0 (the
        ghost goes with its echo; a second echo there keeps its own level); beside
        a slow echo (:data:`STILL_LEAK_CELLS`, whose ghosts may be a hidden still echo's
        and stay when it is taken out) where read with it in it is at most the echo's own
        strength. Such a detection is refused without a fit; any other is fitted with the
        measured echoes taken out, and the echo test decides. A detection whose detector
        statistic ``strength`` (above its noise mean) is at most
        :data:`GHOST_STRENGTH_MARGIN` times that of a detection already read as this echo's
        ghost on the same codeword is taken for its ghost without reading it.

        On the span's edge hypothesis (``edge_side`` +1 closing, −1 opening; 0 elsewhere), a
        ghost beyond that edge (more than one Doppler cell past the detection's speed, at
        most :data:`GHOST_LEAK_CELLS`) leaks into it at any time of the echo's hops: there
        the detection is the leak when it is at most :data:`GHOST_LEAK_FRACTION` of the
        echo's strength. A ``residual`` detection (the second search's) is checked against
        the echoes that were not taken out of its input only (:attr:`EchoFit.cancelled`:
        the others' ghosts went with them)."""
        speed = self.c * (alpha - 1.0) / (alpha + 1.0)
        amplitude: float | None = None
        if edge_side:
            leak_of = [
                abs(e.amplitude) for e in self._echoes
                if not (residual and e.cancelled)
                and abs(e.t_s - t_s) <= KNOWN_HOPS * self.hop_len_s
                and self._cell_speed
                < edge_side * (e.speed(self.c) + edge_side * self._ghost_speed - speed)
                <= GHOST_LEAK_CELLS * self._cell_speed
            ]  # fmt: skip
            if leak_of:
                inside = self._amplitude_near(t_s, alpha, hop_index, inward=-edge_side)
                if inside <= GHOST_LEAK_FRACTION * max(leak_of):
                    return True
        for i, e in enumerate(self._echoes):
            if residual and e.cancelled:
                continue  # taken out of the second search's input with its ghosts
            if abs(abs(speed - e.speed(self.c)) - self._ghost_speed) > self._cell_speed:
                continue
            period = self.hop_len_s / e.alpha
            drift = 0.5 * (self.m_hops - 1) * (e.alpha / alpha - 1.0)  # hops
            k = round((t_s - e.t_s) / period - drift)
            spread = 2.0 * abs(drift)  # hops between the first and the last term's offsets
            if abs((t_s - e.t_s) / period - drift - k) > GHOST_HOPS + max(0.0, spread - 0.5) / 2:
                continue
            slow = abs(e.speed(self.c)) <= STILL_LEAK_CELLS * self._cell_speed
            if not slow and any(self._same_echo(o, hop_index, t_s, speed) for o in self._echoes):
                return False
            # The ghost's codeword (its hop's offset from the echo's, modulo a code period)
            # recurs: a detection there no stronger than its ghosts is one of them.
            offset = (hop_index - e.hop_index - round((t_s - e.t_s) / period)) % len(
                e.ghost_strength
            )
            if strength <= GHOST_STRENGTH_MARGIN * e.ghost_strength[offset]:
                return True
            if slow:
                if amplitude is None:
                    amplitude = self._amplitude_near(t_s, alpha, hop_index, around=True)
                ghost = amplitude <= abs(e.amplitude)
            else:
                # Echoes of one speed close in range share their ghosts: all are taken out.
                group = self._formation(e)
                left = self._amplitude_near(
                    t_s, alpha, hop_index, around=True, known=self.echo_rows(group, t_s)
                )
                ref = max(group, key=lambda g: abs(g.amplitude))
                noise = abs(ref.amplitude) * 10.0 ** (-min(ref.e_over_n0_db, 300.0) / 20.0)
                ghost = left <= GHOST_LEFT * abs(ref.amplitude) + GHOST_NOISE_Z * noise
            if ghost:
                if math.isfinite(strength) and strength > e.ghost_strength[offset]:
                    read = list(e.ghost_strength)
                    read[offset] = strength
                    self._echoes[i] = replace(e, ghost_strength=tuple(read))
                return True
        return False

    def _formation(self, echo: EchoFit) -> list[EchoFit]:
        """``echo`` and the other echoes measured within :data:`KNOWN_HOPS` hops of it at its
        speed (within the speed span) and within
        :data:`~hil.estimation.refine_pair.SEED_LOBES` grating lobes of its delay (each
        carried to its hop): echoes of one speed close in range, whose ghosts share their
        cells."""
        lobe = 1.0 / (echo.alpha * self.spacing_hz)
        out = [echo]
        for e in self._echoes:
            k = echo.hop_index - e.hop_index
            if (
                e is not echo
                and abs(k) <= KNOWN_HOPS
                and abs(e.speed(self.c) - echo.speed(self.c)) <= self.speed_span_mps
                and abs(e.boundary_s(echo.hop_index, self.hop_len_s) - echo.t_s)
                <= SEED_LOBES * lobe
            ):
                out.append(e)
        return out

    def _amplitude_near(
        self,
        t_s: float,
        alpha: float,
        hop_index: int,
        inward: int = 0,
        around: bool = False,
        known: NDArray[np.complex128] = _NO_KNOWN,
    ) -> float:
        """The largest fitted amplitude ``|β| = 2|C|/E_s`` of an echo of constant speed
        within ±½ grating lobe of ``t_s`` (s, :data:`GHOST_POINTS` times) at the detection's
        time scale ``alpha``: a detection's strength without its fit (0 where the input does
        not cover its hops). With ``inward`` (+1 or −1, the sign of the speeds toward the
        span's inside from a detection on its edge hypothesis, whose speed the detector
        cannot interpolate) also at the speeds up to the speed span that way, every half
        Doppler resolution cell of the ``M`` hops (an echo 0.2 m/s inside the edge reads a
        third of its amplitude at the edge's speed on att); with ``around``, at the speeds
        within the speed span either way, on the same steps (a detection where a measured
        echo's ghost peaks: a second echo there read at the detector's speed alone fell to
        0.17 of its level)."""
        lobe = 1.0 / (alpha * self.spacing_hz)
        alphas = np.array([alpha])
        if inward or around:
            speed = self.c * (alpha - 1.0) / (alpha + 1.0)
            span = self.speed_span_mps
            steps = int(math.ceil(span / (0.5 * self.v_res)))
            if inward:
                v = speed + inward * np.linspace(0.0, span, steps + 1)
            else:
                v = speed + np.linspace(-span, span, 2 * steps + 1)
            alphas = (self.c + v) / (self.c - v)
        word = self._codeword(hop_index)
        hop_ids = np.arange(hop_index - self.m_hops + 1, hop_index + 1, dtype=np.int64)
        slots = self.hop_slots(hop_ids, word, t_s, alpha)
        if slots is None:
            return 0.0
        c = np.empty((alphas.size, GHOST_POINTS), dtype=np.complex128)
        e_s = np.empty((alphas.size, GHOST_POINTS))
        grid_sums(
            *self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s, known,
            t_s - 0.5 * lobe, lobe / (GHOST_POINTS - 1), np.ascontiguousarray(alphas), c, e_s,
        )  # fmt: skip
        ok = e_s > 0
        return float(np.max(2.0 * np.abs(c[ok]) / e_s[ok])) if ok.any() else 0.0

    def _remember_all(
        self, fits: list[Refinement], hop_index: int, cancelled: bool, pair: bool
    ) -> None:
        """Keep ``fits`` (echoes of one detection's hops, :meth:`_two_echoes`) as their
        echoes' latest, replacing every earlier fit of either (:meth:`_same_echo`) and
        forgetting fits :data:`KNOWN_HOPS` hops old; ``pair`` as :attr:`EchoFit.pair`."""
        oldest = min(f.t_s for f in fits) - KNOWN_HOPS * self.hop_len_s
        ghost_strength = (0.0,) * self.schedule.period_hops
        kept = []
        was_held = [False] * len(fits)
        for e in self._echoes:
            if e.t_s < self._oldest_kept(e, oldest):
                continue
            same = [self._same_echo(e, hop_index, f.t_s, f.speed_mps(self.c)) for f in fits]
            if any(same):
                ghost_strength = tuple(map(max, ghost_strength, e.ghost_strength or ghost_strength))
                was_held = [w or (s and e.held) for w, s in zip(was_held, same, strict=True)]
            else:
                kept.append(e)
        new = [
            EchoFit(
                hop_index, f.t_s, f.alpha, f.amplitude, 0.0, ghost_strength, f.e_over_n0_db,
                cancelled=cancelled, pair=pair, held=self._holds(f.e_over_n0_db, w),
            )
            for f, w in zip(fits, was_held, strict=True) if f.amplitude != 0
        ]  # fmt: skip
        self._echoes = [*kept, *new]

    def _remember(self, fit: Refinement, hop_index: int, cancelled: bool | None) -> None:
        """Keep ``fit`` as its echo's latest (with its fitted amplitude ``β = 2C/E_s``),
        replacing that echo's earlier fit (the strength of its ghosts read so far carried
        on) and forgetting fits :data:`KNOWN_HOPS` hops old; ``cancelled`` as
        :attr:`EchoFit.cancelled` (None: the echo's earlier fit's, True for a new echo). A fit
        of a boundary before the echo's latest fit (a gap looked for, :meth:`due`) is not kept
        in its place; a fit after boundaries neither fitted nor looked for since the echo's
        earlier fit notes them (:attr:`EchoFit.gap`, at most :data:`KNOWN_HOPS` of them)."""
        if fit.amplitude == 0:
            return
        speed = self.c * (fit.alpha - 1.0) / (fit.alpha + 1.0)  # EchoFit.speed
        oldest = fit.t_s - KNOWN_HOPS * self.hop_len_s
        kept = []
        ghost_strength = (0.0,) * self.schedule.period_hops
        was: bool | None = None
        covered = -1
        was_held = False
        for e in self._echoes:
            if e.t_s < self._oldest_kept(e, oldest):
                continue
            if self._same_echo(e, hop_index, fit.t_s, speed):
                if e.hop_index > hop_index:
                    return  # a boundary looked for behind the echo's latest fit keeps that
                ghost_strength = tuple(map(max, ghost_strength, e.ghost_strength or ghost_strength))
                was = e.cancelled if was is None else was or e.cancelled
                covered = max(covered, e.hop_index, e.followed)
                was_held = was_held or e.held
            else:
                kept.append(e)
        if cancelled is None:
            cancelled = True if was is None else was
        gap = covered + 1 if covered >= 0 and 0 < hop_index - covered - 1 <= KNOWN_HOPS else -1
        new = EchoFit(
            hop_index, fit.t_s, fit.alpha, fit.amplitude, fit.rate(self.c), ghost_strength,
            fit.e_over_n0_db, cancelled=cancelled, gap=gap,
            held=self._holds(fit.e_over_n0_db, was_held),
        )  # fmt: skip
        self._echoes = [*kept, new]

    def _oldest_kept(self, echo: EchoFit, oldest: float) -> float:
        """The earliest time (s) at which ``echo``'s fit is still kept where fits before
        ``oldest`` (s, :data:`KNOWN_HOPS` hops back) are forgotten: a still echo's
        :data:`STILL_KNOWN_HOPS` - :data:`KNOWN_HOPS` hops earlier."""
        if not echo.still:
            return oldest
        return oldest - (STILL_KNOWN_HOPS - KNOWN_HOPS) * self.hop_len_s

    def _holds(self, e_over_n0_db: float, was_held: bool) -> bool:
        """Whether a fit collecting ``e_over_n0_db`` (dB) holds its echo
        (:attr:`EchoFit.held`): the echo was held, or the fit reaches :attr:`follow_db`."""
        return was_held or e_over_n0_db >= self.follow_db

    def _same_echo(self, fit: EchoFit, hop_index: int, t_s: float, speed: float) -> bool:
        """Whether a detection at ``t_s`` (s) ending hop ``hop_index`` at ``speed`` (m/s) is
        the echo of ``fit``: its boundary where the fit's echo puts that hop's (within
        :data:`SAME_ECHO_LOBES` grating lobes) at a speed within the speed span. An
        accelerating fit's speed is carried on to that hop, and a detection may read it at
        the boundary or as its window's mean (the detector's constant-speed reading, half a
        window earlier: at 25 m/s² on att, M = 10, 1.25 m/s below the boundary's)."""
        v_fit = fit.speed(self.c)
        if fit.rate != 0.0:
            accel = fit.rate * 2.0 * self.c / (fit.alpha + 1.0) ** 2
            v_fit += accel * (hop_index - fit.hop_index) * self.hop_len_s
            v_mean = v_fit - 0.5 * self.m_hops * self.hop_len_s * accel
            if abs(v_mean - speed) <= self.speed_span_mps:
                v_fit = v_mean
        if abs(v_fit - speed) > self.speed_span_mps:
            return False
        t_pred = fit.boundary_s(hop_index, self.hop_len_s)
        return abs(t_pred - t_s) <= SAME_ECHO_LOBES / (fit.alpha * self.spacing_hz)

    def _known_hops(
        self, hop_index: int, t_s: float, speed: float, lag_s: float = 0.0
    ) -> NDArray[np.complex128]:
        """The hops of the other echoes measured lately that a detection at ``t_s`` (s) and
        ``speed`` (m/s) ending hop ``hop_index`` hears over its ``M`` hops, as the ``known``
        rows of :func:`~hil.estimation.refine_kernels.candidate_sums` (shape ``(5, Q)``):
        each echo continues at its fitted delay, time scale and amplitude, before its latest
        fit as after it (``lag_s``: :meth:`_others`)."""
        return self.echo_rows(self._others(hop_index, t_s, speed, lag_s=lag_s), t_s)

    def _others(
        self, hop_index: int, t_s: float, speed: float, stronger_than: float = 0.0,
        lag_s: float = 0.0,
    ) -> list[EchoFit]:  # fmt: skip
        """The echoes measured within :data:`KNOWN_HOPS` hops of a detection at ``t_s`` (s)
        and ``speed`` (m/s) ending hop ``hop_index`` that are not its own, with a fitted
        ``|β|`` above ``stronger_than``; a detection decided ``lag_s`` (s) late (the second
        search's) also hears the echoes whose latest fits are up to that much later: an echo
        measured at one speed since is there at that speed before too, and left in it holds
        the detection's fit on its own partial-overlap lobe (a target 0.84 m/s and 6.6 m from
        a stronger one, -10 dB: fitted at the stronger one's speed half a hop off, 0.13 false
        estimates per hop)."""
        return [
            e for e in self._measured_near(t_s, lag_s)
            if abs(e.amplitude) > stronger_than
            and not self._same_echo(e, hop_index, t_s, speed)
        ]  # fmt: skip

    def ghost_of_rest(self, speed: float) -> bool:
        """Whether ``speed`` (m/s) is where a still echo's ghost is read: within
        :data:`STILL_GHOST_CELLS` Doppler cells of one hop of a whole number (one or more)
        of tone spacings' speed from rest (the ghost and its main lobe; ±27.5 m/s on
        ``att``). Used also by :mod:`hil.estimation.gcas.beyond_span`, which scans no
        source beyond the span for such a detection where its window holds still water."""
        k = round(abs(speed) / self._ghost_speed)
        near = STILL_GHOST_CELLS * self._cell_speed
        return k >= 1 and abs(abs(speed) - k * self._ghost_speed) <= near

    def echo_rows(self, echoes: list[EchoFit], t_end: float) -> NDArray[np.complex128]:
        """The ``known`` rows (shape ``(5, Q)``) of ``echoes`` over the ``M`` hops whose
        last boundary is received at ``t_end`` (s), widened by the speed span's drift."""
        if not echoes:
            return _NO_KNOWN
        t_lo = t_end - (self.m_hops + 1) * self.hop_len_s / (
            1.0 - 2.0 * self.speed_span_mps / self.c
        )
        t_hi = t_end + self.hop_len_s
        columns = [self._echo_hops(e, t_lo, t_hi) for e in echoes]
        return np.ascontiguousarray(np.concatenate(columns, axis=1))

    def _echo_hops(self, echo: EchoFit, t_lo: float, t_hi: float) -> NDArray[np.complex128]:
        """The ``known`` columns of ``echo``'s hops received within ``[t_lo, t_hi]`` (s)."""
        key = echo.hop_index % self.schedule.period_hops
        t_len = self.hop_len_s / echo.alpha  # a hop's received length, s
        # Hop key + r is received over [t_e + (r − 1) T/α, t_e + r T/α).
        r_lo = int(math.floor((t_lo - echo.t_s) / t_len))
        r_hi = int(math.ceil((t_hi - echo.t_s) / t_len)) + 1
        k, f, dt_lo, duration = self._hop_run(key, r_lo, r_hi - r_lo + 1)
        # Each hop heard on the tangent of the echo's curve at its centre (an accelerating
        # fit's time scale changes at its rate; the boundary's line where it does not).
        t_i, a_i = hops_on_curve(echo.t_s, echo.alpha, echo.rate, dt_lo + 0.5 * duration)
        out = np.empty((5, f.shape[0]), dtype=np.complex128)
        out[0] = 0.5 * echo.amplitude * np.conj(k)
        out[1] = f * a_i
        out[2] = t_i + dt_lo / a_i
        out[3] = t_i + (dt_lo + duration) / a_i
        out[4] = t_i
        return out

    def _hop_run(self, key: int, r_first: int, count: int) -> _HopRun:
        """Hops ``key + r_first …`` (``count`` of them) relative to the boundary ending hop
        ``key`` of the first code period: each one's transmit phasor ``a e^{−j(φ − 2π f
        dt_lo)}``, tone (Hz), start ``dt_lo`` after that boundary (s) and length (s). Kept
        (:data:`HOP_RUNS` of them): the other echoes' hops of consecutive detections are
        the same runs."""
        run = self._hop_runs.get((key, r_first, count))
        if run is None:
            hops = self.schedule.hops(key + r_first, count)
            end = self.schedule.hops(key, 1)
            t_b = float(end.start_s[0] + end.duration_s[0])
            dt_lo = hops.start_s - t_b
            f = hops.freq_hz
            k: NDArray[np.complex128] = hops.amplitude * np.exp(
                -1j * (hops.phase_rad - 2 * np.pi * f * dt_lo)
            )
            if len(self._hop_runs) >= HOP_RUNS:
                self._hop_runs.clear()
            run = self._hop_runs[(key, r_first, count)] = (k, f, dt_lo, hops.duration_s)
        return run

    def _fit_near(
        self,
        word: Codeword,
        hop_ids: NDArray[np.int64],
        t0: float,
        v0: float,
        lobe: float,
        warm_hop: int | None,
        known: NDArray[np.complex128],
        keep_lobe: bool = False,
        curve: tuple[float, float, float] | None = None,
    ) -> Refinement | None:
        """The fit of the search around ``(t0, v0)`` (s, m/s): from ``curve`` (the boundary's
        time s, time scale and rate 1/s where an echo's fit carried on puts it) or a recent
        fit's prediction when ``warm_hop`` is given and one agrees, else the full search,
        then the lobe check (none with ``keep_lobe``: a followed boundary's lobe is its
        echo's, which that echo's fits decided); None where the input does not cover the
        hops."""
        outcome = RECENTRE
        gamma = 0.0
        start = curve
        if start is None and warm_hop is not None:
            start = self._predicted(warm_hop, t0, v0, lobe)
        if start is not None:
            # Near a recent fit's prediction: a 3 × 3 grid of the fit's first steps (an
            # accelerating fit's: the rate's fit from there, at the hops' centre).
            best_t, alpha, gamma = start
            if gamma != 0.0:
                best_t, alpha = to_centre(best_t, alpha, gamma, word.centre_s)
            best_v = self.c * (alpha - 1.0) / (alpha + 1.0)
            slots = self.hop_slots(hop_ids, word, best_t, alpha)
            if slots is None:
                return None
            args = (*self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s)
            if gamma == 0.0:
                best_t, best_v, outcome = maximise(
                    *args, known, 0.0, self.c, best_t, best_v, WARM_HALF_LOBES * lobe,
                    WARM_HALF_SPANS * self.speed_span_mps, 3, 3, WARM_FIT_PASSES,
                )  # fmt: skip
            else:
                fitted = accel_fit(self, args, known, best_t, alpha, gamma, lobe)
                if fitted is not None:
                    best_t, alpha, gamma = fitted[:3]
                    best_v, outcome = self.c * (alpha - 1.0) / (alpha + 1.0), FOUND
                    if not accel_gain(self, args, known, word, best_t, alpha, gamma) > ACCEL_GAIN:
                        # No longer accelerating: the constant speed's warm fit.
                        gamma, outcome = 0.0, RECENTRE
                        best_t, best_v, outcome = maximise(
                            *args, known, 0.0, self.c, best_t, best_v, WARM_HALF_LOBES * lobe,
                            WARM_HALF_SPANS * self.speed_span_mps, 3, 3, WARM_FIT_PASSES,
                        )  # fmt: skip
        if outcome != FOUND:
            gamma = 0.0
            searched = self._search_from_fewer_hops(word, hop_ids, t0, v0, lobe, known)
            if searched is None:
                return None
            best_t, best_v, outcome, args = searched
        if outcome == NO_LOBE and known.shape[1]:
            # Beside another echo the detector's time can be a whole lobe off: its search then
            # rises to an edge. Start again from the better neighbouring lobe.
            side = self.better_lobe(args, t0, v0, lobe, known, any_side=True)
            searched = self.search_near(word, hop_ids, side, v0, lobe, known) if side else None
            if searched is not None:
                best_t, best_v, outcome, args = searched
            if outcome == NO_LOBE:
                # Still at an edge: the detector's time is more than a lobe off (beside a
                # stronger echo its envelope can peak two lobes away). Search three lobes.
                wide = (1.5 * lobe, self.speed_span_mps, 3 * TIME_POINTS - 2, self.speed_points)
                searched = self.search_near(word, hop_ids, t0, v0, lobe, known, wide)
                if searched is not None:
                    best_t, best_v, outcome, args = searched
        for _ in range(LOBE_MOVES if outcome == FOUND and not keep_lobe else 0):
            # The lobe: the envelope tells a grating lobe from its neighbours by ~1 dB, which
            # a detector's time (noncoherent, beside a stronger echo) can miss; the
            # likelihood's own neighbours decide.
            moved = self.better_lobe(args, best_t, best_v, lobe, known, gamma=gamma)
            if moved is None:
                break
            narrow = self.narrow_grid(lobe)
            searched = self.search_near(word, hop_ids, moved, best_v, lobe, known, narrow, gamma)
            if searched is not None and searched[2] != FOUND:
                searched = self.search_near(word, hop_ids, moved, best_v, lobe, known, gamma=gamma)
            if searched is None:
                return None
            best_t, best_v, outcome, args = searched
            if outcome != FOUND:
                break
        if outcome != FOUND:
            best_t, best_v, gamma = t0, v0, 0.0
        a_best = (self.c + best_v) / (self.c - best_v)
        return self.refinement_at(args, known, word, best_t, a_best, gamma, outcome == FOUND)

    def _earlier_power(
        self, hop_ids: NDArray[np.int64], t_s: float, alpha: float, lobe: float,
        known: NDArray[np.complex128],
    ) -> float | None:  # fmt: skip
        """The largest ``|C|²`` over the ``M`` hops before ``hop_ids`` of the echo whose
        boundary ending ``hop_ids[-1]`` is received at ``t_s`` (s) with time scale ``alpha``
        (constant speed: that window's boundary ``M T_h / α`` earlier), over
        :data:`LOBE_POINTS` times across ±⅛ lobe and :data:`LOBE_SPEEDS` speeds across ± a
        quarter of the ``M`` hops' speed resolution, with the ``known`` rows of the other
        echoes over those hops taken out (:meth:`_known_before`). None where the input does
        not cover those hops."""
        before = hop_ids - self.m_hops
        word = self._codeword(int(before[-1]))
        centre = t_s - self.m_hops * self.hop_len_s / alpha
        slots = self.hop_slots(before, word, centre, alpha)
        if slots is None:
            return None
        v = self.c * (alpha - 1.0) / (alpha + 1.0)
        speeds = v + 0.25 * self.v_res * np.linspace(-1.0, 1.0, LOBE_SPEEDS)
        alphas = np.repeat((self.c + speeds) / (self.c - speeds), LOBE_POINTS)
        t = np.tile(centre + 0.125 * lobe * np.linspace(-1.0, 1.0, LOBE_POINTS), LOBE_SPEEDS)
        args = (*self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s)
        return float(np.max(self.candidate_powers(args, known, t, alphas, np.zeros(t.size))))

    def _known_before(
        self, hop_index: int, t_s: float, alpha: float, amplitude: float
    ) -> NDArray[np.complex128]:
        """The ``known`` rows of the other echoes measured lately stronger than
        ``amplitude`` (a fit's ``|β|``; as :meth:`_known_hops` for a detection at ``t_s``,
        s, time scale ``alpha``, ending hop ``hop_index``) over the ``M`` hops before the
        detection's: each echo continued back at its fitted delay, time scale and amplitude.
        Beside a stronger echo, the earlier window of a weak one holds the stronger one's
        lobes as much as its own window does (att, a target 10 dB below another at -10 dB
        per-sample SNR: 5 of 200 hops a lobe off without them, none with them)."""
        speed = self.c * (alpha - 1.0) / (alpha + 1.0)
        others = self._others(hop_index, t_s, speed, stronger_than=amplitude)
        return self.echo_rows(others, t_s - self.m_hops * self.hop_len_s / alpha)

    def _lobe_by_more_hops(
        self, fit: Refinement, word: Codeword, hop_ids: NDArray[np.int64], t0: float,
        v0: float, lobe: float, known: NDArray[np.complex128],
    ) -> Refinement:  # fmt: skip
        """``fit`` (constant speed, found, its E/N0 in the threshold region, :data:`LOBE_Z`)
        or the maximum the ``M`` hops and the ``M`` hops before them favour together among
        the searches (±½ lobe, ±:data:`LOBE_SPANS` speed spans, re-centred) on the grating
        lobe of ``fit`` and its neighbours and on the detection's ``(t0, v0)`` (s, m/s) and
        :data:`LOBE_DETECTOR` lobes either side of it: there a
        detector's time and speed can sit on the range–Doppler ridge a lobe or more away,
        and a fit's lobe is beaten by its neighbour by noise. Each candidate's evidence is
        its ``|C|²`` plus the earlier window's (:meth:`_earlier_power`; each window its own
        phase: ``ln Λ`` is that sum over ``σ² E_s``, the windows' ``E_s`` equal). ``fit``
        where the earlier hops are not in the input (start, gaps)."""
        v_fit = fit.speed_mps(self.c)
        v_reach = LOBE_SPANS * self.speed_span_mps
        grid = (0.5 * lobe, v_reach, TIME_POINTS, 2 * LOBE_SPANS * (self.speed_points // 2) + 1)
        before = self._known_before(int(hop_ids[-1]), fit.t_s, fit.alpha, abs(fit.amplitude))
        first = self._earlier_power(hop_ids, fit.t_s, fit.alpha, lobe, before)
        if first is None:
            return fit
        slots = self.hop_slots(hop_ids, word, fit.t_s, fit.alpha)
        if slots is None:
            return fit
        args = (*self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s)
        own = self.candidate_powers(
            args, known, np.array([fit.t_s]), np.array([fit.alpha]), np.zeros(1)
        )
        if first < LOBE_HELD * own[0]:
            return fit
        best = (float(own[0]) + first, fit.t_s, v_fit)
        starts = [(fit.t_s + k * lobe, v_fit) for k in (-1, 0, 1)]
        for k in range(-LOBE_DETECTOR, LOBE_DETECTOR + 1):
            t_k = t0 + k * lobe
            if all(abs(t_k - t) > 0.5 * lobe or abs(v0 - v) > v_reach for t, v in starts):
                starts.append((t_k, v0))
        moved = False
        for t_k, v_k in starts:
            searched = self.search_near(word, hop_ids, t_k, v_k, lobe, known, grid)
            if searched is None or searched[2] != FOUND:
                continue
            t, v, _, args = searched
            alpha = (self.c + v) / (self.c - v)
            p = self.candidate_powers(args, known, np.array([t]), np.array([alpha]), np.zeros(1))
            earlier = self._earlier_power(hop_ids, t, alpha, lobe, before)
            if earlier is not None and p[0] + earlier > best[0]:
                best, moved = (float(p[0]) + earlier, t, v), True
        if not moved:
            return fit
        _, t, v = best
        # The winner's tables, made by its search (later searches' fills may have taken some
        # of its slots: those are made again, the others reused).
        alpha = (self.c + v) / (self.c - v)
        slots = self.hop_slots(hop_ids, word, t, alpha)
        if slots is None:
            return fit
        args = (*self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s)
        return self.refinement_at(args, known, word, t, alpha, 0.0, True)

    def in_still_water(self, t_s: float, alpha: float) -> bool:
        """Whether the ``M`` hops' window of the boundary at ``t_s`` (s, time scale
        ``alpha``) holds still water, at least :data:`STILL_OVER_REST` of the rest's power:
        where the grating lobe decisions read its leak through the hops' edges. Read at the
        boundary a followed echo's fit predicts, before that boundary is fitted, so without
        :meth:`_lobe_without_still`'s conditions on the fitted echo (its power, the
        canceller's gain at its speed): the lobe kept is the echo's, whatever its fit."""
        s_pow, rest = self._still_powers(t_s, alpha)
        return s_pow > 0 and s_pow >= STILL_OVER_REST * rest

    def in_open_water(self, t_s: float, alpha: float) -> bool:
        """Whether the ``M`` hops' window of the boundary at ``t_s`` (s, time scale ``alpha``)
        is known to hold no still water (less than :data:`STILL_OVER_REST` of the rest's
        power): False where that is not known (no still-water streams, or a window before
        they cover the input: a code period from the start or a gap), unlike
        :meth:`in_still_water`."""
        s_pow, rest = self._still_powers(t_s, alpha)
        return rest > 0 and s_pow < STILL_OVER_REST * rest

    def _still_powers(self, t_s: float, alpha: float) -> tuple[float, float]:
        """The still water's power and the rest's per sample (input units²) over the ``M``
        hops' samples before the boundary at ``t_s`` (s, time scale ``alpha``)
        (:meth:`~hil.estimation.still_lobe.StillStreams.powers`); ``(0, 0)`` without the
        still-water streams."""
        if self._still is None:
            return 0.0, 0.0
        stop = int(math.floor(t_s * self.fs_hz))
        window_s = self.m_hops * self.hop_len_s / alpha
        return self._still.powers(stop - int(math.ceil(window_s * self.fs_hz)), stop)

    def _lobe_without_still(
        self, fit: Refinement, word: Codeword, hop_ids: NDArray[np.int64], lobe: float,
        known: NDArray[np.complex128],
    ) -> Refinement:  # fmt: skip
        """``fit`` (constant speed, an echo), or the fit on the grating lobe that the input
        without its still water favours (:meth:`still_free_evidence`, with the other echoes
        measured lately taken out), where the still water over the ``M`` hops' samples holds
        at least :data:`STILL_OVER_REST` of the rest's power and :data:`STILL_OVER_ECHO` of
        the fitted echo's, and the canceller keeps at least :data:`STILL_GAIN_MIN` of the
        echo's SNR (:func:`~hil.estimation.still_lobe.canceller_gain`). Where another lobe's
        evidence exceeds ``fit``'s own: that lobe's fit on ``x`` (the search over ±⅛ lobe and
        half the speed span about ``fit`` moved by whole lobes; ``x`` keeps the Cramér–Rao
        accuracy within a lobe), or ``fit`` refused (``found`` False) where that search finds
        no maximum inside. ``fit`` where ``y`` does not cover the evidence's windows."""
        still, fits = self._still, self._still_fits
        if still is None or fits is None:
            return fit
        hop_index = int(hop_ids[-1])
        alpha = fit.alpha
        s_pow, rest = self._still_powers(fit.t_s, alpha)
        if s_pow <= 0 or s_pow < STILL_OVER_REST * rest:
            return fit  # open water: the echo's power is not needed
        echo_pow = 0.5 * abs(fit.amplitude) ** 2 * float(np.mean(word.hops[4]))
        if s_pow < STILL_OVER_ECHO * echo_pow:
            return fit
        delta = self._still_period_s * (alpha - 1.0)
        if canceller_gain(word.hops[1], word.hops[4], self.hop_len_s, delta) < STILL_GAIN_MIN:
            return fit  # a blind speed of the canceller: y holds too little of the echo
        others = self._others(hop_index, fit.t_s, fit.speed_mps(self.c))
        evidence = self.still_free_evidence(fit.t_s, alpha, hop_index, others)
        if evidence is None:
            return fit
        ks = np.arange(-STILL_LOBES, STILL_LOBES + 1)
        j = int(np.argmax(evidence))
        if j == STILL_LOBES or evidence[j] <= evidence[STILL_LOBES]:
            return fit
        v = fit.speed_mps(self.c)
        grid = (0.125 * lobe, 0.5 * self.speed_span_mps, 5, 5)
        searched = self.search_near(word, hop_ids, fit.t_s + ks[j] * lobe, v, lobe, known, grid)
        if searched is None or searched[2] != FOUND:
            return replace(fit, found=False)
        t_new, v_new, _, args = searched
        a_new = (self.c + v_new) / (self.c - v_new)
        return self.refinement_at(args, known, word, t_new, a_new, 0.0, True)

    def still_free_evidence(
        self, t_s: float, alpha: float, hop_index: int, others: list[EchoFit] | None = None
    ) -> NDArray[np.float64] | None:
        """The evidence for each grating lobe of an echo whose boundary ending hop
        ``hop_index`` is received at ``t_s`` (s) with time scale ``alpha``, on the input
        without its still water (:mod:`hil.estimation.still_lobe`): shape
        ``(2 STILL_LOBES + 1,)``, lobe ``k − STILL_LOBES`` at ``t_s + k/(α Δf)``, each the
        two-term model's largest ``|C_y|²`` over :data:`STILL_LOBE_POINTS` times across ±⅛
        lobe, summed over the first :data:`STILL_WINDOWS` windows of ``M`` hops (ending at
        ``hop_index``, ``M`` hops before, ...) whose terms ``y`` covers, with ``others``
        (echoes measured lately) and their copies taken out. None where fewer windows are
        covered, or the schedule's still water does not repeat in whole samples."""
        fits, still = self._still_fits, self._still
        if fits is None or still is None:
            return None
        self._still_up_to_date(still, fits)
        lobe = 1.0 / (alpha * self.spacing_hz)
        window_s = self.m_hops * self.hop_len_s / alpha
        shift = self._still_period_s * (1.0 - 1.0 / alpha)
        ks = np.arange(-STILL_LOBES, STILL_LOBES + 1)
        offsets = np.linspace(-0.125, 0.125, STILL_LOBE_POINTS) * lobe
        a = np.full(offsets.size, alpha)
        g = np.zeros(offsets.size)
        # The other echoes as the canceller leaves them: each less its copy (a still period
        # later, stretched), taken out of y as they are out of x.
        in_y = [*(others or []), *(self._still_copy(e) for e in others or [])]
        evidence = np.zeros((ks.size, offsets.size))
        used = 0
        for w in range(STILL_WINDOWS + 1):
            if used == STILL_WINDOWS:
                break
            hop = hop_index - w * self.m_hops
            powers = np.empty_like(evidence)
            for j, k in enumerate(ks):
                centre = t_s - w * window_s + k * lobe
                known_y = self.echo_rows(in_y, centre)
                t = centre + offsets
                direct = fits._sums(centre, alpha, hop, t, a, g, known_y)
                copy = fits._sums(centre + shift, alpha, hop, t + shift, a, g, known_y)
                if direct is None or copy is None:
                    break
                powers[j] = still_free_powers(direct[0], copy[0])
            else:
                evidence += powers
                used += 1
        if used < STILL_WINDOWS:
            return None
        best: NDArray[np.float64] = np.max(evidence, axis=1)
        return best

    def _still_copy(self, echo: EchoFit) -> EchoFit:
        """What the one-period canceller subtracts of ``echo``: the echo at the receive time
        a still period later less the time scale's stretch (``t + T_Q (1 − 1/α)``), with the
        opposite amplitude (:mod:`hil.estimation.still_lobe`)."""
        t = echo.t_s + self._still_period_s * (1.0 - 1.0 / echo.alpha)
        return replace(echo, t_s=t, amplitude=-echo.amplitude)

    def refinement_at(
        self, args: tuple[Any, ...], known: NDArray[np.complex128], word: Codeword, t: float,
        alpha: float, gamma: float, found: bool,
    ) -> Refinement:  # fmt: skip
        """The :class:`Refinement` of the fit ``(t, alpha, gamma)`` (the kernels' parameters:
        with a rate, ``t`` and ``alpha`` are the hops' centre's line) with its quality, its
        Cramér–Rao bounds and, with a rate, the boundary's time, time scale and the
        acceleration."""
        en0, coherence, tone_coherence, run_coherence, amplitude = echo_quality(
            args, known, word, self.n_tones, t, alpha, gamma
        )
        en0_db = 10.0 * math.log10(en0) if en0 > 0 else -math.inf
        bound = (
            crlb(word.b_rms, word.t_rms, word.f0, en0_db, self.c) if math.isfinite(en0_db) else None
        )
        accel = 0.0
        if gamma != 0.0:
            t, alpha = to_boundary(t, alpha, gamma, word.centre_s)
            accel = 2.0 * self.c * gamma / (alpha + 1.0) ** 2
        return Refinement(
            t, alpha, en0_db, bound, coherence, tone_coherence, run_coherence, found,
            amplitude, accel,
        )  # fmt: skip

    def _hop_powers(
        self, fit: Refinement, word: Codeword, hop_ids: NDArray[np.int64],
        known: NDArray[np.complex128],
    ) -> NDArray[np.float64] | None:  # fmt: skip
        """Each hop's power at the constant-speed ``fit`` (shape ``(M,)``, the hop's term
        over its squared amplitude), ``known`` taken out; None where the input does not cover
        the hops."""
        slots = self.hop_slots(hop_ids, word, fit.t_s, fit.alpha)
        if slots is None:
            return None
        args = (*self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s)
        per_hop = np.empty((1, hop_ids.shape[0]), np.complex128)
        candidate_sums(
            *args, np.array([fit.t_s]), np.array([fit.alpha]), np.zeros(1),
            np.empty(1, np.complex128), np.empty(1), np.empty(0), per_hop, known,
        )  # fmt: skip
        amp2 = word.hops[4]
        power: NDArray[np.float64] = np.abs(per_hop[0]) ** 2 / np.where(
            amp2 > 0, amp2 * amp2, np.inf
        )
        return power

    def _ended(
        self, fit: Refinement, word: Codeword, hop_ids: NDArray[np.int64],
        known: NDArray[np.complex128],
    ) -> bool:  # fmt: skip
        """Whether ``fit``'s echo ended within its window (:data:`ENDED_CHANCE`): the hops'
        terms ``H_i`` at the fit (on its curve where it accelerates), ``known`` taken out;
        False where the input does not cover the hops."""
        if self.m_hops < 3:
            return False
        t, alpha, gamma = fit.t_s, fit.alpha, 0.0
        if fit.accel_mps2 != 0.0:
            gamma = fit.rate(self.c)
            t, alpha = to_centre(t, alpha, gamma, word.centre_s)
        slots = self.hop_slots(hop_ids, word, t, alpha)
        if slots is None:
            return False
        b = self._end_buffers
        b[0][0], b[1][0], b[2][0] = t, alpha, gamma
        candidate_sums(
            *self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s, *b, known
        )  # fmt: skip
        h = b[6][0]
        # G_k > limit, with the residual RSS_k = total − lead_k ≥ 0 (Cauchy–Schwarz); lead_k
        # = |Σ H|²/Σ a² of the first M − k hops, k = M − 1 … 1 (compiled: ended_gain). The
        # total stays NumPy's dot: BLAS orders a long dot's additions its own way.
        total = float(np.dot(h.real * h.real + h.imag * h.imag, word.inv_amp2))
        return bool(ended_gain(h, word.inv_energy, total, self._end_m, self._end_limit))

    def _one_sided(
        self, fit: Refinement, word: Codeword, hop_ids: NDArray[np.int64],
        known: NDArray[np.complex128],
    ) -> bool:  # fmt: skip
        """Whether the constant-speed ``fit``'s hops hold its echo on one side of the window
        only (:data:`PARTIAL_LEVEL`): at least :data:`PARTIAL_HOPS` consecutive hops at one
        end below that level of the hops' mean power, none at the other end."""
        power = self._hop_powers(fit, word, hop_ids, known)
        if power is None:
            return False
        weak = power < PARTIAL_LEVEL * np.mean(power)
        lead = int(np.argmin(weak)) if not weak.all() else weak.size
        trail = int(np.argmin(weak[::-1])) if not weak.all() else weak.size
        return (lead >= PARTIAL_HOPS and trail == 0) or (trail >= PARTIAL_HOPS and lead == 0)

    def candidate_powers(
        self, args: tuple[Any, ...], known: NDArray[np.complex128], t: NDArray[np.float64],
        alpha: NDArray[np.float64], gamma: NDArray[np.float64],
    ) -> NDArray[np.float64]:  # fmt: skip
        """``|C|²`` of the candidates ``(t, alpha, gamma)`` (shape ``(C,)`` each)."""
        n = t.shape[0]
        c, model = np.empty(n, np.complex128), np.empty(n)
        candidate_sums(
            *args, t, alpha, gamma, c, model, np.empty(0), np.empty((n, 0), np.complex128), known
        )
        return np.abs(c) ** 2

    def search_near(
        self, word: Codeword, hop_ids: NDArray[np.int64], t0: float, v0: float, lobe: float,
        known: NDArray[np.complex128], grid: tuple[float, float, int, int] | None = None,
        gamma: float = 0.0,
    ) -> tuple[float, float, int, tuple[Any, ...]] | None:  # fmt: skip
        """The search around ``(t0, v0)`` over the hops ``hop_ids`` of ``word`` on ``grid``
        (``(half_t, half_v, n_t, n_v)``: ±s, ±m/s, points; default the full search's ±½ lobe,
        ± the speed span, :data:`TIME_POINTS` and :attr:`speed_points`), re-centred up to
        :data:`~hil.estimation.fit_steps.MAX_RECENTRES` times: the best point, the outcome and
        the kernels' arguments of its tables; None where the input does not cover the hops."""
        if grid is None:
            grid = (0.5 * lobe, self.speed_span_mps, TIME_POINTS, self.speed_points)
        best_t, best_v, outcome = t0, v0, RECENTRE
        args: tuple[Any, ...] = ()
        for _ in range(MAX_RECENTRES + 1):
            slots = self.hop_slots(hop_ids, word, best_t, (self.c + best_v) / (self.c - best_v))
            if slots is None:
                return None
            args = (*self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s)
            best_t, best_v, outcome = maximise(
                *args, known, gamma, self.c, best_t, best_v, *grid, FIT_PASSES
            )
            if outcome != RECENTRE:
                break
        return best_t, best_v, outcome, args

    def _search_from_fewer_hops(
        self, word: Codeword, hop_ids: NDArray[np.int64], t0: float, v0: float, lobe: float,
        known: NDArray[np.complex128],
    ) -> tuple[float, float, int, tuple[Any, ...]] | None:  # fmt: skip
        """:meth:`search_near` by way of the last :attr:`sub_hops` hops (:data:`SUB_HOPS`): their
        search's maximum is the centre of a search of all ``M`` hops over the fewer hops'
        main lobe (:meth:`narrow_grid`); the full search where either finds no maximum
        inside (NO_LOBE where the fewer hops find none within ±½ lobe). None where the input
        does not cover the hops."""
        if self.sub_hops == self.m_hops:
            return self.search_near(word, hop_ids, t0, v0, lobe, known)
        sub = self.sub_word(hop_ids[-1])
        sub_grid = (0.5 * lobe, self.speed_span_mps, TIME_POINTS, self.sub_speed_points)
        first = self.search_near(sub, hop_ids[-self.sub_hops :], t0, v0, lobe, known, sub_grid)
        if first is None:
            return None
        t1, v1, outcome, _ = first
        if outcome == FOUND:
            searched = self.search_near(word, hop_ids, t1, v1, lobe, known, self.narrow_grid(lobe))
            if searched is None or searched[2] == FOUND:
                return searched
        elif outcome == NO_LOBE:
            # No main lobe within ±½ lobe of the detection over the fewer hops: the caller's
            # NO_LOBE rules apply (the lobe check beside another echo), on all M hops' tables.
            slots = self.hop_slots(hop_ids, word, t0, (self.c + v0) / (self.c - v0))
            if slots is None:
                return None
            return (
                t0,
                v0,
                NO_LOBE,
                (*self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s),
            )
        return self.search_near(word, hop_ids, t0, v0, lobe, known)

    def narrow_grid(self, lobe: float) -> tuple[float, float, int, int]:
        """A grid of all ``M`` hops around a point already near their maximum (the fewer
        hops' maximum, or a neighbouring grating lobe's): ±⅛ grating lobe in 5 points, and
        ±½ of the fewer hops' speed resolution in steps of about half the ``M`` hops'."""
        n_v = 2 * int(math.ceil(0.5 * self.m_hops / self.sub_hops)) + 3
        half_v = 0.5 * self.v_res * self.m_hops / self.sub_hops
        return (0.125 * lobe, half_v, 5, n_v)

    def better_lobe(
        self, args: tuple[Any, ...], t_s: float, speed: float, lobe: float,
        known: NDArray[np.complex128], any_side: bool = False, gamma: float = 0.0,
    ) -> float | None:  # fmt: skip
        """The time (s) one grating lobe before or after ``t_s`` where the likelihood (at the
        rate ``gamma``, 1/s) is greater than at ``t_s`` (the greater of the two; with
        ``any_side`` the greater of the two whatever ``t_s``'s), or None."""
        alpha = (self.c + speed) / (self.c - speed)
        t = np.array([t_s - lobe, t_s, t_s + lobe])
        power = self.candidate_powers(args, known, t, np.full(3, alpha), np.full(3, gamma))
        side = 0 if power[0] >= power[2] else 2
        if power[side] > power[1] or any_side:
            return float(t[side])
        return None

    def _predicted(
        self, hop_index: int, t_s: float, speed: float, lobe: float
    ) -> tuple[float, float, float] | None:
        """Where a recent fit of the same echo puts this boundary: its time (s), time scale
        and rate (1/s), from a fit up to :data:`WARM_HOPS` hops earlier moved on by those hops
        (its time scale changing at its rate), if the detection agrees with it (within an
        eighth of a lobe, and the fit's speed, at the boundary or over the hops, within the
        speed span)."""
        for hop, t_fit, a_fit, gamma in reversed(self._recent):
            k = hop_index - hop
            if 1 <= k <= WARM_HOPS:
                a_pred = a_fit + gamma * k * self.hop_len_s / a_fit
                t_pred = t_fit + k * self.hop_len_s * 2.0 / (a_fit + a_pred)
                v_fit = self.c * (a_fit - 1.0) / (a_fit + 1.0)
                v_mean = v_fit - 0.5 * self.m_hops * self.hop_len_s * self.c * gamma / 2.0
                near = min(abs(v_fit - speed), abs(v_mean - speed)) <= self.speed_span_mps
                if abs(t_pred - t_s) <= 0.125 * lobe and near:
                    return t_pred, a_pred, gamma
        return None

    def correlation(
        self,
        t_s: float,
        alpha: float,
        hop_index: int,
        t_rx: NDArray[np.float64],
        alphas: NDArray[np.float64],
        rates: NDArray[np.float64] | None = None,
    ) -> NDArray[np.complex128] | None:
        """The correlation ``C(t_rx, α)`` of candidates near a detection ``(t_s, alpha)`` of
        the boundary ending hop ``hop_index`` (the function :meth:`refine` maximises as
        ``|C|²``): ``t_rx`` (s) and ``alphas`` of one shape, within ±½ grating lobe and ± the
        speed span of the detection; with ``rates`` (1/s, the same shape) the time scale
        changes at that rate about the hops' centre (``alphas`` are the centre's: the
        mapping of :func:`~hil.estimation.refine_kernels.candidate_sums`). None where the
        input does not cover the hops. For plots of the local ambiguity and for checks
        against a direct correlation."""
        t = np.ascontiguousarray(np.asarray(t_rx, dtype=np.float64).ravel())
        a = np.ascontiguousarray(np.asarray(alphas, dtype=np.float64).ravel())
        g = np.zeros(t.size) if rates is None else np.asarray(rates, dtype=np.float64).ravel()
        for name, arr in (("alphas", a), ("rates", g)):
            if arr.shape != t.shape:
                raise ConfigError(
                    name, f"shape {arr.shape}", f"the shape of t_rx, {np.shape(t_rx)}"
                )
        sums = self._sums(t_s, alpha, hop_index, t, a, np.ascontiguousarray(g))
        return None if sums is None else sums[0].reshape(np.shape(t_rx))

    def _sums(
        self, t_s: float, alpha: float, hop_index: int, t: NDArray[np.float64],
        alphas: NDArray[np.float64], rates: NDArray[np.float64],
        known: NDArray[np.complex128] = _NO_KNOWN,
    ) -> tuple[NDArray[np.complex128], NDArray[np.float64]] | None:  # fmt: skip
        """``C`` and the model's energy ``E_s`` of the candidates ``(t, alphas, rates)``
        (shape ``(n,)`` each, contiguous) near a detection ``(t_s, alpha)`` of the boundary
        ending hop ``hop_index``, without other echoes taken out; None where the input does
        not cover the hops."""
        word = self._codeword(hop_index)
        hop_ids = np.arange(hop_index - self.m_hops + 1, hop_index + 1, dtype=np.int64)
        slots = self.hop_slots(hop_ids, word, t_s, alpha)
        if slots is None:
            return None
        args = (*self.slot_tables, slots, *word.hops, self.fs_hz, self.hop_len_s)
        n = t.size
        c, e_s = np.empty(n, np.complex128), np.empty(n)
        candidate_sums(
            *args, t, alphas, rates, c, e_s, np.empty(0), np.empty((n, 0), np.complex128), known
        )
        return c, e_s

    @property
    def slot_tables(self) -> tuple[NDArray[Any], ...]:
        """The hops' correlation tables by slot (:meth:`hop_slots`), as the refinement
        kernels take them ahead of the slots (:func:`~hil.estimation.refine_kernels.
        candidate_sums`)."""
        return (self._prefix, self._energy, self._first, self._tail, self._alpha0, self._centre)

    def hop_slots(
        self, hop_ids: NDArray[np.int64], word: Codeword, t_s: float, alpha: float
    ) -> NDArray[np.int64] | None:
        """The table slot of each hop (shape ``(M,)``): a kept one made for this window, or
        one filled now (:func:`~hil.estimation.refine_kernels.assign_slots`); None where the
        input does not cover a hop's window."""
        fs = self.fs_hz
        _, f, dt_lo, dt_hi, _ = word.hops
        span = int(math.ceil(self.hop_len_s / alpha * fs)) + 2 * self._half + 2
        slots = np.empty(hop_ids.shape[0], dtype=np.int64)
        self._clock += 1
        ring = self._ring
        covered = assign_slots(
            self._hop, self._edge, self._alpha0, self._used, self._first, self._tail,
            self._centre, self._clock, hop_ids, float(t_s), dt_lo, dt_hi, f, float(alpha),
            REUSE_SLACK, self._alpha_tol, self._half, span, self._valid_from, ring.next_index,
            ring.array, ring.next_index - ring.available, fs, self.hop_len_s * fs,
            self._prefix, self._energy, slots,
        )  # fmt: skip
        return slots if covered else None

    def sub_word(self, hop_index: int) -> Codeword:
        """The last :attr:`sub_hops` hops of :meth:`_codeword`'s (the first search's)."""
        key = int(hop_index) % self.schedule.period_hops
        word = self._sub_words.get(key)
        if word is None:
            word = self._codeword(key).last(self.sub_hops)
            self._sub_words[key] = word
        return word

    def half_word(self, hop_index: int, first: bool) -> Codeword:
        """The first (``first``) or last ``⌊M/2⌋`` hops of :meth:`_codeword`'s, relative to
        its end boundary (:func:`~hil.estimation.refine_accel.halves_seed`)."""
        key = int(hop_index) % self.schedule.period_hops
        word = self._half_words.get((key, first))
        if word is None:
            whole, n = self._codeword(key), self.m_hops // 2
            word = whole.first(n) if first else whole.last(n)
            self._half_words[(key, first)] = word
        return word

    def _codeword(self, hop_index: int) -> Codeword:
        """The ``M`` hops ending with ``hop_index`` relative to their end boundary, from the
        schedule's :class:`~hil.estimation.codewords.CodewordBook` (each codeword made once
        per schedule, ``M`` and rate, from the first code period)."""
        return self._codewords[hop_index]
