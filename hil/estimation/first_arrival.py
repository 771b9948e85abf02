"""First-arrival range readout: the onset of the next tone at each hop boundary (tank ranging).

In a tank every echo arrives several times: the direct path, then its images in the surface,
the bottom and the walls, a few tenths of a millisecond later and about as strong. The
accumulated sums of GCAS integrate a whole hop, so their peak lands on the energy centroid of
those arrivals (+0.45 m in the built-in tank), not on the direct path. The direct path is the
first arrival, and at a hop boundary it is the first to switch to the next tone: this readout
times that switch.

For each of the ``M`` boundaries the GCAS detection used (receive times from its boundary time
``t_c`` and time scale ``α``; the tone after boundary ``m`` from the schedule):

1. **Clutter canceller**: ``d(t) = x(t) − σ x(t − P)``, ``P`` the code period (samples, an
   integer) and ``σ`` the sign the transmission repeats with after it (+1, or −1 where the
   hops' phase advances by π over a period: ``att``, ``tank-board``;
   :mod:`hil.estimation.still_period`; a period with another advance is taken as often as
   it needs to come back to 0 or π). So every time-invariant return
   (the direct blast, walls, volume reverberation of a still tank) cancels; the moving echo
   does not, it leaves a copy of itself shifted by ``δ = P (α − 1)/α`` (later for a closing
   target, earlier for an opening one, whose first onset is then corrected by ``−δ``).
2. **Next-tone channel**: ``b(t) = boxcar_w(d(t) e^{−j2π α f_next t})`` with a causal boxcar
   of ``w = 1/Δf`` (``Δf`` the tone spacing): it nulls every other tone of the echo while the
   window holds one tone only. Its change over one window, ``z(t) = b(t) − b(t − w)``,
   also removes what sounds the next tone steadily before the first arrival switches (late
   images of earlier boundaries: at image order 2 the target's echo through both end walls
   comes a hop late), so ``|z|`` stays at the noise floor until the first arrival switches,
   then ramps up over ``w`` exactly as ``b`` does.
3. **Onset**: the noncoherent mean of ``|z|²`` over the ``M`` boundaries, less the noise: its
   level in a window of :data:`BASELINE_S` before the search, or in the quietest such window
   before the centroid where a late image switching tones fills the first
   (:meth:`FirstArrivalReadout._noise_window`). From its maximum after ``t_c`` (or from an
   earlier rise above :data:`EARLY_FRACTION` of it: an arrival of its own), back to
   where it last rose from ``lo`` of that maximum (an image of opposite sign may pull it
   back under ``hi`` inside the ramp), a line through the stretch from there to the first
   ``hi`` crossing gives a first onset; the ramp's exact shape (the previous tone's partial
   window leaks while the window straddles the switch) is then fitted over the first
   arrival's own part of the ramp (:meth:`FirstArrivalReadout._fit_ramp`). A flat level
   above ``hi`` that is the previous boundary's late images switching tones (stronger on the
   boundaries whose next tone they leave than on the others, where only their switch leaks
   through the window) is stepped over: the ramp is searched again above it. Where those
   boundaries hold more than :data:`LATE_RATIO` times the others' power ahead of the first
   arrival, they are left out of the onset altogether
   (:meth:`FirstArrivalReadout._late_images_seen`: in the 12 × 6 × 4 m tank at image order 2
   the far end wall on both legs, an opening path 240 Hz off the direct path's tone grid,
   switches 0.4 ms ahead of the direct path at 8 m). A rise from
   ``lo`` to ``hi`` slower than :data:`SLOW_RISE` windows is a low level ahead of the ramp,
   or a first arrival weak against the images that join it (image order 3): the line is
   fitted on the ramp's steep part, from ``hi`` to twice its level, searched within one
   window where the rise is the next tone arriving to stay
   (:meth:`FirstArrivalReadout._new_tone_holds`: a late images' level passes), up to the top
   otherwise. Behind the canceller a closing target's first arrival comes with its
   sign-flipped copies δ later (0.33 ms at 1.5 m/s, under a window), which with its first
   images can hold its own ramp under ``hi``: where such a rise holds the next tone and the
   steep part's line starts after the ``lo`` crossing (no ramp crosses ``lo`` before its
   onset), the steep part is those later arrivals and the line is fitted from ``lo`` to
   ``hi`` (read late by a range cell otherwise: 0.13-0.20 m at 7.2-8.0 m in the built-in tank).
   That line's onset is where the Doppler is read (step 4). For the range, where
   the rise is the next tone arriving to stay, the ramp's model (a constant level beside it)
   is searched again from a quarter window before ``lo`` to the line's crossing, and that
   onset kept where the model explains at least :data:`COHERENT_FIT` of the channel on each
   boundary (a weak first arrival, not a late path's switch ahead of it); and where the noise
   level read before the search is more than :data:`NEAR_RATIO` times the level just before
   the ramp (the older late paths' leak; :meth:`FirstArrivalReadout._near_floor`), the onset
   is read again on that level (:meth:`FirstArrivalReadout._onset`).
4. **Doppler**: the direct path's complex amplitude at the ``M`` boundaries, fitted over its
   first :data:`DIRECT_S` on the ramp's model (the previous tone's leak divided out), gives
   its own time scale (:meth:`FirstArrivalReadout._direct_alpha`): GCAS's weighs the
   images in, each at its path's slower radial speed. Its score over speed has sidelobes
   (a few tones over ``M`` boundaries) that an image leaking into the first arrival can
   raise above the peak; the detections of the same echo a few hops back
   (:data:`DOPPLER_LAGS`) read other tone patterns with other sidelobes, so their scores are
   summed with this one to choose the lobe, and to place the peak on it where the direct
   path's speed has been steady (:data:`STEADY_MPS`; the present score alone places it
   otherwise). A direct-path speed more than
   :data:`DIRECT_BELOW_GCAS_MPS` below GCAS's is a phase ambiguity (no image is faster than
   the direct path) and refused. Where it is refused (or on the span's edge), GCAS
   reads the target moving at :data:`LATE_TAP_MIN_SPEED_MPS` or more and the late paths are
   there (their fitted power at least :data:`LATE_TAP_RATIO` times the direct path's), the
   direct path's amplitudes are read again on the input samples with the late paths'
   switches fitted as nuisance taps (:mod:`hil.estimation.late_taps`; no canceller only): at
   image order 3 in the built-in tank their switches, 0.1-1 ms ahead of it, leak through the
   next-tone window into its first :data:`DIRECT_S`. Where that reading is refused too (the
   same speed bound), the same echo's direct-path speed read up to :data:`HOLD_HOPS` hops
   back stands, inside the same span around GCAS's (:meth:`FirstArrivalReadout._held_alpha`);
   otherwise GCAS's is kept.

The range then comes from the first arrival instead of the centroid. Measured on the built-in
simulated tank run (12 × 4 × 2.5 m, own echoes, reverberation, direct blast, 1.5 m/s tow),
replayed: with ``gcas-bg`` (:mod:`hil.estimation.background`: an empty-tank background
subtracted, this readout without its canceller, ``cancel_period=False``) range bias
+0.002 m, RMSE 0.003 m, speed RMSE 0.010 m/s; at image order 2 no estimate of the scored
stretch wrong and 0.5 % of all more than 1 m off (docs/tank-run.md has the table against image
order, tank and beams).

Limits with its canceller: a target slower than about one carrier wavelength per code period
is mostly cancelled with the clutter (no onset found: the peak readout is kept), and an
opening target's copy one period back arrives first (its onset is the target a period ago,
corrected by one period's travel at the present speed); the readout needs the samples of
one code period plus ``M`` hops behind the boundary, and the detector's decision lag behind
the newest sample (:attr:`FirstArrivalReadout.history`, :meth:`~FirstArrivalReadout.allow_lag`);
it assumes first arrivals within ``max_spread_s`` before the centroid (default 0.3 hop). The
Doppler scores of two echoes within :data:`DOPPLER_GATE_S` of delay of each other (0.37 m) are
summed as one echo's; a speed changing faster than :data:`DOPPLER_SPEED_GATE_MPS` over the lags
is read on the present score alone.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation.detection import parabolic_offset
from hil.estimation.first_arrival_kernels import (
    doppler_score,
    ramp_residuals,
    ring_channel,
    warm_up,
    window_start_phasors,
)
from hil.estimation.late_taps import LEAD_S, DirectFit, direct_amplitudes
from hil.estimation.reverb_band import doppler_resolution_mps
from hil.estimation.row_buffer import RowBuffer
from hil.estimation.still_period import still_period
from hil.signals.schedule import HopSchedule, HopTable

#: GCAS range readouts: the peak of the accumulated sums, or the first arrival (this module).
RANGE_READOUTS = ("peak", "first-arrival")
#: Default bound on how far the first arrival can precede the peak (centroid), in hops: 3 ms
#: (2.2 m of range) at 10 ms hops. In a 12 × 6 × 4 m tank the side-wall images put the
#: centroid 1.3 m behind the direct path at 5 m; 1.5 ms missed those onsets.
MAX_SPREAD_HOPS = 0.3
#: The level before any arrival is measured over this long, s.
BASELINE_S = 0.4e-3
#: After the peak, the ramp's top is searched this long, s.
TOP_S = 1.0e-3
#: Fractions of the ramp's top between which the line is fitted (its zero crossing starts the
#: ramp fit; lower levels let noise at 0 dB per-sample SNR walk the line into the baseline).
LO_FRACTION = 0.03
HI_FRACTION = 0.12
#: The ramp's model is fitted up to this fraction of the top: the first arrival alone.
#: Measured on the built-in tank: up to 0.08 the bias stays +0.015 m; 0.12 gave +0.022 m and
#: 0.2 +0.068 m (the surface image, 0.27 ms after the direct path, enters the fit).
FIT_HI_FRACTION = 0.08
#: The fit's lower level stays this many standard deviations of the noise's amplitude above
#: the baseline (noise crossing a level set by the top alone gave onsets 0.2-0.7 m early at
#: 0 dB per-sample SNR).
NOISE_MARGIN = 4.0
#: The direct path's phase is read this far into its ramp, s: before the first image in a
#: tank 2.5 m deep (the surface image of a target 1.2 m down comes 0.27 ms after it).
DIRECT_S = 0.2e-3
#: Samples before the line's lower point that the ramp fit also uses (the leak before it).
FIT_LEAD = 24
#: The ramp fit searches onsets this many samples around the line's (whole samples), then
#: within a sample of the best in steps of FIT_STEP.
FIT_SPAN = 16
FIT_STEP = 0.125
#: Speed step of the direct path's Doppler search, m/s.
DIRECT_SPEED_STEP = 0.002
#: The direct path's Doppler is searched this far (in Doppler resolutions ``v_res``) from
#: GCAS's towards a slower target, and :data:`DIRECT_SPAN_FASTER` towards a faster one. Every
#: image is slower than the direct path (:data:`DIRECT_BELOW_GCAS_MPS`), so GCAS's
#: energy-weighted speed is the direct path's less what the images pull it down: in the
#: 12 x 6 x 4 m tank at image order 2 the far end wall on both legs (an opening path while the
#: target closes) pulls it down by up to 0.33 m/s (v_res/4) at 5.5-8 m. Measured with the
#: scores summed (:data:`DOPPLER_LAGS`): 0.3 v_res faster took that run's speed RMSE from
#: 0.049 to 0.010 m/s; 0.4 v_res let a sidelobe 0.32 m/s faster win for an opening target
#: behind the period canceller (90th percentile of its speed error 0.107 m/s against 0.072).
DIRECT_SPAN_SLOWER = 0.25
DIRECT_SPAN_FASTER = 0.3
#: The direct path has the largest radial speed of all arrivals (an image's is the carriage
#: speed times the cosine of its path's elevation), so its Doppler is not below GCAS's
#: energy-weighted one by more than this, m/s; a direct-path speed slower by more is a phase
#: ambiguity (measured at image order 2: -0.3 m/s outliers, v_res/4) and GCAS's is kept.
DIRECT_BELOW_GCAS_MPS = 0.05
#: An earlier rise above this fraction of the top's amplitude is an arrival of its own
#: (:meth:`FirstArrivalReadout.first_arrival`).
EARLY_FRACTION = 0.5
#: Hops before the previous one whose tones a boundary's next tone must differ from to be read
#: (:meth:`FirstArrivalReadout._clean_boundaries`): a late image up to this many hops behind its
#: direct path then leaves no early switch on the boundaries read. 0: every boundary where the
#: tone changes. Measured: 2 cleared more of the built-in tank's order-2 late images (estimates
#: more than 1 m off 6.6 -> 5.7 %, all outside the scored segment) but reads 3-4 of 10
#: boundaries, and at 0 dB per-sample SNR the 90th percentile of the range error rose from
#: 0.11 to 0.20 m.
LATE_HOPS = 0
#: Boundaries whose next tone is the tone two hops back are left out when the next-tone
#: channel before the first arrival holds more than this times the power on them as on the
#: others (:meth:`FirstArrivalReadout._late_images_seen`).
LATE_RATIO = 2.0
#: Fewest boundaries the onset is read on; with fewer clean ones, every boundary is read.
MIN_CLEAN = 3
#: The noise is read in the stretch of :data:`BASELINE_S` before the search unless that holds
#: more than this times the power of the quietest such stretch before the centroid (a late
#: image switching tones there); the quietest one alone reads noise low (it is the least of
#: several noisy means: at 0 dB per-sample SNR onsets came up to 1.2 m early).
QUIET_RATIO = 2.0
#: A ramp reaches this many times its ``hi`` crossing within one window of it; a stretch
#: that does not (with the top still more than a window on) is a pedestal
#: (:meth:`FirstArrivalReadout.first_arrival`).
PEDESTAL_RISE = 2.0
#: Pedestals stepped over at most, one above the other.
MAX_PEDESTALS = 2
#: An arrival of at least a fifth of the top crosses from ``lo`` to ``hi`` in under half a
#: window; a stretch between them longer than this many windows is a low level ahead of the
#: ramp (in the 12 x 6 x 4 m tank at image order 2, 0.15-0.4 m of range ahead of the direct
#: path), and the line is fitted on the ramp's steep part, from ``hi`` to twice its level
#: (within one window where the rise is the next tone arriving to stay: :data:`NEW_TONE_RATIO`;
#: searched up to the top, the line of a first arrival weak against its images runs into
#: their slow climb and crosses zero up to 1.2 ms early at image order 3).
#: Measured: 0.25 and 0.4 also took weak first arrivals of the built-in tank for it.
SLOW_RISE = 0.55
#: A pedestal holds at least this many times the power on the boundaries whose next tone the
#: previous boundary's late images leave as on the others (measured on the built-in tank at
#: image order 2, carriage at rest: 4-5 times; a first arrival: 0.8-1.2).
PEDESTAL_RATIO = 2.0
#: A rise is the next tone arriving to stay when the next-tone channel's power a window after
#: it has grown by at least this times the power of its change over that window
#: (:meth:`FirstArrivalReadout._new_tone_holds`): a lone arrival's ratio is 1 on average,
#: more where its images join it. Measured: a first arrival 1.6-12 (built-in tank, order 3,
#: scored stretch), the late images' level in the carriage's stop at order 2 0.02-0.97 (0.5
#: let one of those levels, at 0.58, read a target 1.5 m short).
NEW_TONE_RATIO = 1.0


#: An onset that stands still while its echo moves is not the target's first arrival
#: (:meth:`FirstArrivalReadout._standing`): at least STANDING_READINGS onsets up to MOVING_HOPS
#: hops back, from which the echo has moved STANDING_MOVE tolerances since, within
#: STANDING_TOLERANCE windows (``1/Δf``) of it. Measured on the built-in tank at tank-board's
#: 1 MS/s (window 0.2 ms; the tow at 1.5 m/s moves the delay 10 µs a hop): the far-wall path's
#: onsets scatter by ±24 µs about their place, the direct path's by ±3 µs about its track.
MOVING_HOPS = 12
STANDING_TOLERANCE = 0.15
STANDING_MOVE = 2.0
STANDING_READINGS = 3
#: An onset more than this many standing tolerances off the track its echo's kept onsets
#: agree on is refused (:meth:`FirstArrivalReadout._off_track`).
TRACK_JUMP = 3.0


#: The direct path's Doppler score is summed with the same echo's at the detections this many
#: hops before to choose its lobe (:meth:`FirstArrivalReadout._direct_alpha`): their boundaries
#: overlap the present ones less and less (M − 1 … M − 8 of M), so their tone patterns, and the
#: score's sidelobes, differ more. Measured (speed RMSE against the telemetry of the built-in
#: tank at order 1 and 2 and of the 12 x 6 x 4 m tank at order 2; 90th percentile of the speed
#: error of an opening target behind the period canceller): (1, 2, 4, 8) 0.0096, 0.0113,
#: 0.013, 0.083 m/s; 1 to 8 hops 0.0096, 0.0113, 0.013, 0.104; no sum (and 0.25 v_res
#: faster) 0.0095, 0.0113, 0.049, 0.088.
DOPPLER_LAGS = (1, 2, 4, 8)
#: A detection some hops back is the same echo when its delay, moved on at the present speed,
#: is within this of the present one, s (0.37 m of range at 1482 m/s: a first arrival read
#: 0.2 m off among good ones is still summed with them; measured on the 12 x 6 x 4 m tank at
#: image order 2: 0.3 ms left one such estimate 0.21 m/s off, speed RMSE 0.019 against 0.010).
DOPPLER_GATE_S = 0.5e-3
#: ... and when GCAS's speeds of the two differ by no more than this, m/s: a third of the
#: score's lobe spacing (0.3 m/s), so a speed that changed (a carriage braking at 2 m/s²
#: changes 0.16 m/s in 8 hops) does not move the lobe. Measured on the 12 x 6 x 4 m tank at
#: order 2 (speed RMSE over every estimate with a truth, ramps and stop included): none
#: 0.111 m/s, 0.1 m/s 0.105 (0.091 without the sum); 0.05 m/s left out enough of the scored
#: stretch's sums to raise its speed RMSE from 0.013 to 0.019.
DOPPLER_SPEED_GATE_MPS = 0.1
#: Where the direct path's speed read on the next-tone channel is refused, it is read again with
#: the late paths' switches fitted (:mod:`hil.estimation.late_taps`) when their taps hold at
#: least this times the direct path's power: the late paths are there and leak into its first
#: :data:`DIRECT_S` (with no late path the taps fitted anyway hold less: the test of
#: :mod:`hil.estimation.late_taps`). Measured on every refused reading of the seed-1 runs (the
#: recorded detections, :data:`LATE_TAP_MIN_SPEED_MPS` aside): order 3 0.78-366 (69 of 69 at
#: least 0.75), order 2 0.01-44 (61 of 79), 12 x 6 x 4 m order 2 0.17-325 (35 of 38), order 1
#: 0.03-3.4 (7 of 21, at rest and in the run-up; none of them read a speed). So on these runs
#: the speed bound, not this one, chooses where the second reading is tried: of order 3's 24
#: readings at 1 m/s or more (0.78-15.6) it refuses none.
LATE_TAP_RATIO = 0.75

#: The second reading is tried only for a target GCAS reads closing or opening at this speed or
#: more, m/s: a check on what is at hand, before the fit. Measured (seed-1 runs, the recorded
#: detections replayed, speed RMSE over every estimate with a truth / scored): with no bound
#: the second reading moved speeds of the carriage at rest, in the run-up and in its stop
#: 0.1-0.4 m/s further from the telemetry (0.25 m/s: 12 x 6 x 4 m tank, order 2, 0.105 ->
#: 0.108 m/s, as 0.5); 0.75 and 1 m/s leave the order-2 runs' estimates as without it and take
#: order 3 0.105 -> 0.096 m/s (scored 0.075 -> 0.046); 1.25 m/s scored 0.053 (these with a tap
#: on the fit's first sample allowed; left out, at 1 m/s: 0.095 and 0.045 m/s). At order 1
#: every refused reading is below it (at rest and in the run-up): the fit never runs there.
LATE_TAP_MIN_SPEED_MPS = 1.0
#: Where both readings of the direct path's speed are refused for a target GCAS reads at
#: :data:`LATE_TAP_MIN_SPEED_MPS` or more, the same echo's direct-path speed read up to this many
#: hops back is kept instead of GCAS's (:meth:`FirstArrivalReadout._held_alpha`): GCAS's weighs
#: the images in (at image order 3 in the built-in tank it reads 0.13-0.25 m/s slow there), and
#: in six hops (60 ms) a carriage braking at 2 m/s² changes by 0.12 m/s. Measured (the recorded
#: detections replayed, scored speed RMSE): seed 1, order 3 0.045 m/s with none, 0.031 with
#: 1 hop, 0.028 with 2 and 4 hops (8 of the 9 speeds it changes closer to the telemetry), the
#: same figures with 2 to 8 hops once the speed is placed on the summed score where steady
#: (:data:`STEADY_MPS`); seed 2, order 3 0.035 m/s with 2 hops, 0.025 with 4, 0.018 with 6
#: and 8 (three speeds 0.25 m/s slow at 6.2 m, refused three hops running, held); orders 1 and
#: 2 and the 12 x 6 x 4 m tank at order 2 (seed 1) read the same estimates with any of them.
HOLD_HOPS = 6
#: The noise level is read again just before the ramp (:meth:`FirstArrivalReadout._near_floor`)
#: as the least mean power over this many windows within the window before its ``lo``
#: crossing, where the level read before the search is more than :data:`NEAR_RATIO` times it.
#: Measured (seed-1 runs, the recorded detections replayed; range over the scored estimates):
#: order 3 range RMSE 0.066 -> 0.056 m, estimates more than the gate off 120 -> 93; order 2
#: 0.0077 -> 0.0076 m, 53 -> 17 more than the gate off (the stop's onsets read on the late
#: images' pedestal); 12 x 6 x 4 m order 2 0.0314 -> 0.0319 m; order 1 the same figures (8
#: estimates outside the scored stretch moved by less than 3 mm). Read at that onset, the
#: speed was worse at order 3 (0.028 -> 0.037 m/s): the speed is read at the line's.
NEAR_PART = 0.25
NEAR_RATIO = 2.0
#: Where a slow rise is the next tone arriving to stay (:data:`SLOW_RISE`), the ramp's model is
#: searched again from this many windows before the ``lo`` crossing, a constant level beside
#: it (:meth:`FirstArrivalReadout._onset`). Measured (order 3, with the near floor, range RMSE):
#: 0.056 m without this search; 0.25 window 0.048 m (0.050 m without the constant level);
#: without the level, 0.125 window 0.051 m.
WIDE_LEAD = 0.25
#: ... and that onset is kept where the ramp's model explains at least this fraction of the
#: channel's power on each boundary from it to the line's crossing: measured 0.62-0.78 at the
#: weak first arrivals of order 3 (built-in tank; one at 0.57), 0.29-0.57 at the far end wall's
#: switch ahead of the direct path in the 12 x 6 x 4 m tank at order 2, whose range RMSE is
#: 0.035 m with this check and 0.057 m without (0.032 and 0.052 m without the constant
#: level); 0.65: order 3 0.052 m (without the level).
COHERENT_FIT = 0.6
#: The direct path's speed is placed on the summed score of the same echo's last detections
#: (:data:`DOPPLER_LAGS`), not on the present score alone, where its speeds have been steady:
#: the median of those given 1 to :data:`STEADY_HOPS` hops back and that of those given
#: :data:`STEADY_HOPS` + 1 to 2 :data:`STEADY_HOPS` hops back (at least two each) differ by at
#: most :data:`STEADY_MPS`. A speed that changes over the lags moves a summed peak (a carriage
#: speeding up at 2 m/s² changes by 0.16 m/s over 8 hops): with the summed score everywhere,
#: order 1's speed RMSE over every estimate with a truth (the ramps included) rose from 0.059
#: to 0.074 m/s. Measured (scored speed RMSE, and over every estimate with a truth): order 3
#: 0.028 -> 0.013 m/s (0.092 -> 0.091), order 2 0.0113 -> 0.0106 (0.066 -> 0.067),
#: 12 x 6 x 4 m order 2 0.0130 -> 0.0109 (0.105 -> 0.106), order 1 0.0096 -> 0.0096 (0.059 ->
#: 0.060); 0.05 and 0.07 m/s read the scored speeds about the same (order 3 0.013 m/s) and
#: keep more of the ramps' lag (order 1 0.061-0.062 m/s over every estimate).
STEADY_HOPS = 4
STEADY_MPS = 0.03


def _mean(x: NDArray[np.float64], axis: int) -> NDArray[np.float64]:
    """``np.mean(x, axis=axis)`` computed as it does (the sum, then divided by the count)
    without its wrapper's overhead: the same values, bit for bit."""
    return np.asarray(np.add.reduce(x, axis=axis) / x.shape[axis], dtype=np.float64)


def _mean_all(x: NDArray[np.float64]) -> float:
    """``np.mean(x)`` over every element, computed as it does (the sum, then divided by the
    count) without its wrapper's overhead: the same value, bit for bit."""
    return float(np.add.reduce(x, axis=None) / x.size)


def _std(x: NDArray[np.float64]) -> float:
    """``np.std(x)`` of a 1-D array (shape ``(n,)``), computed as it does (the mean as a
    length-1 array, the squared deviations summed, divided by ``n``, the root) without its
    wrapper's overhead: the same value, bit for bit."""
    n = x.size
    dev = x - np.add.reduce(x, axis=None, keepdims=True) / n
    np.square(dev, out=dev)
    return math.sqrt(float(np.add.reduce(dev, axis=None) / n))


def _nonzero(x: NDArray[np.bool_]) -> NDArray[np.intp]:
    """``np.flatnonzero(x)`` of a 1-D array (shape ``(n,)``) without its wrapper's overhead:
    the indices of its true elements, ascending."""
    return x.nonzero()[0]


def _median(values: list[float]) -> float:
    """``np.median(values)`` of a non-empty list, without its wrapper's overhead: the middle
    value, or the two middle ones summed and halved as it does (NaN where any is NaN)."""
    if any(v != v for v in values):
        return math.nan
    ordered = sorted(values)
    n = len(ordered)
    half = n // 2
    return ordered[half] if n % 2 else (ordered[half - 1] + ordered[half]) / 2.0


def _line_fit(x: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[float, float]:
    """``np.polyfit(x, y, 1)`` of 1-D float arrays (shape ``(n,)``, ``n >= 2``): slope and
    intercept by the same steps (the Vandermonde columns scaled to unit norm, least squares
    by ``np.linalg.lstsq``, the scale divided out) without its wrapper's overhead: the same
    values, bit for bit, and its warning where the fit is poorly conditioned."""
    lhs = np.empty((x.size, 2))
    lhs[:, 0] = x
    lhs[:, 1] = 1.0
    scale = np.sqrt((lhs * lhs).sum(axis=0))
    lhs /= scale
    c, _, rank, _ = np.linalg.lstsq(lhs, y, x.size * _EPS)
    if rank != 2:
        warnings.warn("Polyfit may be poorly conditioned", np.exceptions.RankWarning, stacklevel=3)
    c = (c.T / scale).T
    return float(c[0]), float(c[1])


#: Machine epsilon of float64 (``np.polyfit``'s default ``rcond`` is ``n`` of it).
_EPS = float(np.finfo(np.float64).eps)


def _doppler_score_numpy(
    d_alpha: NDArray[np.float64],
    ft: NDArray[np.float64],
    q: NDArray[np.complex128],
    columns: tuple[NDArray[np.intp], ...],
) -> NDArray[np.float64]:
    """The direct path's Doppler score (:meth:`FirstArrivalReadout._direct_alpha`) as NumPy
    expressions: ``Σ_k |Σ_{m ∈ columns[k]} e^{−j2π Δα_g f_m t_m} q_m|²`` for each ``Δα_g``
    of ``d_alpha`` (shape ``(G,)``); ``ft`` (shape ``(M,)``): ``f_m t_m``; ``q`` (shape
    ``(M,)``): the amplitudes. Shape ``(G,)``."""
    rot = np.multiply(-2j * np.pi * d_alpha[:, None], ft[None, :])
    np.exp(rot, out=rot)  # (G, M)
    sums = np.zeros((d_alpha.size, len(columns)), dtype=np.complex128)
    for k, cols in enumerate(columns):
        sums[:, k] = (rot[:, cols] * q[cols]).sum(axis=1)
    power = np.abs(sums)
    np.square(power, out=power)
    return np.asarray(np.add.reduce(power, axis=1), dtype=np.float64)


def _doppler_score(
    d_alpha: NDArray[np.float64],
    ft: NDArray[np.float64],
    q: NDArray[np.complexfloating],
    pattern: _TonePattern,
) -> NDArray[np.float64]:
    """:func:`_doppler_score_numpy` of ``pattern``'s columns, by the compiled loop
    (:func:`~hil.estimation.first_arrival_kernels.doppler_score`, the same bits)."""
    q128: NDArray[np.complex128] = np.ascontiguousarray(q, dtype=np.complex128)
    b = np.ascontiguousarray((-2j * np.pi * d_alpha).imag)
    score = np.empty(d_alpha.size)
    doppler_score(
        b, np.ascontiguousarray(ft), q128, pattern.order, pattern.starts, score,
    )  # fmt: skip
    return score


def _hop_slice(table: HopTable, start: int, count: int) -> HopTable:
    """Hops ``start .. start + count − 1`` of ``table`` (positions in it, not hop indices)."""
    part = slice(start, start + count)
    return HopTable(
        index=table.index[part],
        start_s=table.start_s[part],
        duration_s=table.duration_s[part],
        tone_index=table.tone_index[part],
        freq_hz=table.freq_hz[part],
        chirp_hz_per_s=table.chirp_hz_per_s[part],
        phase_rad=table.phase_rad[part],
        amplitude=table.amplitude[part],
    )


@dataclass(frozen=True)
class _RampTables:
    """The ramp model's tables for the ``M`` boundaries of one detection (or those read):
    each boundary's predicted switch ``frac`` (samples past its sample), beat ``theta``
    (rad per sample), phase jump ``jump`` (rad), shape ``(M,)`` each, and ``geometric``
    (shape ``(M, w + 1)``, complex): ``Σ_{i<k} e^{jθ i}`` for ``k = 0 .. w``, that is
    ``(1 − r^k)/(1 − r)`` with ``r = e^{jθ}``, or ``k`` where ``θ = 0``."""

    frac: NDArray[np.float64]
    theta: NDArray[np.float64]
    jump: NDArray[np.float64]
    geometric: NDArray[np.complex128]

    def subset(self, keep: NDArray[np.bool_]) -> _RampTables:
        """The tables of the boundaries ``keep`` (shape ``(M,)``)."""
        return _RampTables(self.frac[keep], self.theta[keep], self.jump[keep], self.geometric[keep])


@dataclass(frozen=True)
class _Levels:
    """The next-tone power of one detection and the levels its ramp is read against:
    ``power`` (shape ``(L,)``), the mean power over the boundaries read; ``floor``, the level
    subtracted from it; ``amp`` (shape ``(L,)``), ``√(power − floor)``; ``k0``, the window
    index the search starts at; ``top_i``, ``top``, the top's index and amplitude;
    ``wobble``, the noise's amplitude margin; ``j_lo``, ``j_hi``, the ramp's last rise from
    ``lo`` and its first ``hi`` crossing (:meth:`FirstArrivalReadout._ramp_bounds` of the
    above, read once)."""

    power: NDArray[np.float64]
    floor: float
    amp: NDArray[np.float64]
    k0: int
    top_i: int
    top: float
    wobble: float
    j_lo: int
    j_hi: int

    @classmethod
    def read(
        cls, power: NDArray[np.float64], floor: float, amp: NDArray[np.float64], k0: int,
        top_i: int, top: float, wobble: float,
    ) -> _Levels:  # fmt: skip
        """The levels with their ramp's bounds found."""
        j_lo, j_hi = FirstArrivalReadout._ramp_bounds(amp, k0, top_i, top, wobble)
        return cls(power, floor, amp, k0, top_i, top, wobble, j_lo, j_hi)


@dataclass(frozen=True)
class _TonePattern:
    """What the readout needs of the tones of hops ``h − M .. h + 1`` of a detection at hop
    ``h`` (they repeat with the code, so one pattern serves every period): the boundaries
    read (``clean``) and those the previous boundary's late images leave (``leave``), shape
    ``(M,)`` each, newest first (read-only); and for the Doppler score over the next tones of
    the ``M`` boundaries (newest first): the columns of each distinct tone (``columns``,
    ascending tone order), the same as one array (``order``, shape ``(M,)``) with tone
    ``k``'s at ``order[starts[k] : starts[k + 1]]``, and whether any tone recurs
    (``recurs``)."""

    clean: NDArray[np.bool_]
    leave: NDArray[np.bool_]
    columns: tuple[NDArray[np.intp], ...]
    order: NDArray[np.int64]
    starts: NDArray[np.int64]
    recurs: bool


#: Tone patterns kept per readout (:class:`_TonePattern`); a code has at most one per hop of
#: its period, and a longer code only starts the cache again.
MAX_PATTERNS = 4096


@dataclass(frozen=True)
class DopplerScore:
    """The direct path's Doppler score of one detection: its hop index, its delay ``delay_s``
    (s, first arrival less the boundary's transmit time), its score divided by its maximum,
    shape ``(G,)``, at the speeds ``(k0 + i) ·`` :data:`DIRECT_SPEED_STEP` m/s, and GCAS's
    speed ``v_gcas_mps`` (m/s, closing positive)."""

    hop_index: int
    delay_s: float
    k0: int
    score: NDArray[np.float64]
    v_gcas_mps: float


@dataclass(frozen=True)
class FirstArrival:
    """The direct path at one hop boundary: receive time ``t_s`` (s) and time scale
    ``alpha`` (dimensionless)."""

    t_s: float
    alpha: float


class FirstArrivalReadout:
    """Times the first arrival at the hop boundaries of a GCAS detection.

    Parameters
    ----------
    schedule:
        The transmit schedule (equal hop lengths, tones on a common spacing).
    fs_hz:
        Input sample rate, Hz; ``schedule.period_s · fs_hz`` must be an integer.
    m_hops:
        Boundaries used per detection (GCAS's M).
    sound_speed_mps:
        c, m/s.
    max_spread_s:
        How far before the centroid the first arrival may be, s (default
        :data:`MAX_SPREAD_HOPS` hops).
    cancel_period:
        True (default): the readout's own clutter canceller ``x(t) − x(t − P)`` (step 1).
        False: the input is read as it comes, for an input whose still returns are already
        removed without leaving a copy of the moving echo (an empty-tank background
        subtracted: :mod:`hil.estimation.background`); the code period need not be a whole
        number of samples then.
    """

    def __init__(
        self,
        schedule: HopSchedule,
        fs_hz: float,
        m_hops: int,
        sound_speed_mps: float,
        max_spread_s: float | None = None,
        *,
        cancel_period: bool = True,
    ) -> None:
        if max_spread_s is None:
            max_spread_s = MAX_SPREAD_HOPS * schedule.hop_s
        period = schedule.period_samples(fs_hz) if cancel_period else 0
        sign = 1
        if period:
            period, sign = still_period(schedule, period)
        if period is None:
            raise ConfigError(
                "range_readout",
                "first-arrival",
                "a code period of a whole number of samples",
                f"period {schedule.period_s} s × {fs_hz} Hz = "
                f"{schedule.period_s * fs_hz:.4f} samples: the clutter canceller subtracts the "
                "period before; use the peak readout",
            )
        if not (math.isfinite(max_spread_s) and 0 < max_spread_s < schedule.hop_s / 2):
            raise ConfigError(
                "max_spread_s", max_spread_s, f"0 < spread < half a hop ({schedule.hop_s / 2} s)"
            )
        tones = np.sort(np.asarray(schedule.tones_hz, dtype=np.float64))
        spacing = float(np.min(np.diff(tones))) if tones.size > 1 else 1.0 / schedule.hop_s
        self.schedule = schedule
        self.fs_hz = float(fs_hz)
        self.m_hops = int(m_hops)
        #: The canceller's period, samples (0: no canceller), and the still water's sign
        #: from one period to the next (:func:`~hil.estimation.still_period.still_period`).
        self.period = int(period)
        self.sign = int(sign)
        self.boxcar = max(2, int(round(fs_hz / spacing)))
        self.max_spread_s = float(max_spread_s)
        self._pre = int(round((max_spread_s + BASELINE_S) * fs_hz)) + self.boxcar
        self._post = int(round(TOP_S * fs_hz))
        offs = np.arange(-self._pre, self._post)
        self._offsets = offs
        t_rel = offs / self.fs_hz
        self._base = (t_rel >= -max_spread_s - BASELINE_S) & (t_rel < -max_spread_s)
        #: The noise window's length and first index (fixed per readout).
        self._base_count = int(np.count_nonzero(self._base))
        self._base_start = int(np.flatnonzero(self._base)[0])
        #: The same window as a slice (the offsets ascend: it is one stretch).
        self._base_slice = slice(self._base_start, self._base_start + self._base_count)
        self._search_from = int(np.flatnonzero(t_rel >= -max_spread_s)[0])
        self._after = int(np.flatnonzero(t_rel >= 0.0)[0])
        #: Input samples kept behind the newest: one period plus the M boundaries' windows.
        self.history = self.period + int(math.ceil((m_hops + 1) * schedule.hop_s * fs_hz))
        #: The change over a window needs two windows before the first offset.
        self._lead = 2 * self.boxcar
        self.history += self._pre + self._post + self._lead
        self._offsets_ext = np.arange(-self._pre - self._lead, self._post)
        #: The sample counts 0 .. w a window's geometric sums are taken over, (1, w + 1).
        self._window_counts = np.arange(self.boxcar + 1)[None, :]
        #: :attr:`history` without the caller's decision lag (:meth:`allow_lag`).
        self._own_history = self.history
        self._ring = RowBuffer(self.history, (), np.float64)
        self._valid_from = 0
        self.sound_speed_mps = float(sound_speed_mps)
        # The compiled loops loaded now, not at a live run's first detection.
        warm_up()
        #: The hop length, s (a schedule property that checks every hop: read once).
        self._hop_s = float(schedule.hop_s)
        v_res = doppler_resolution_mps(schedule.tones_hz, self._hop_s, sound_speed_mps)
        n_slow = int(round(DIRECT_SPAN_SLOWER * v_res / DIRECT_SPEED_STEP))
        n_fast = int(round(DIRECT_SPAN_FASTER * v_res / DIRECT_SPEED_STEP))
        #: Speed steps from GCAS's searched towards a slower and a faster target.
        self._steps_slower = n_slow
        self._steps_faster = n_fast
        #: The direct-path Doppler scores of the last detections (:class:`DopplerScore`).
        self._scores: list[DopplerScore] = []
        #: Tone patterns seen (:meth:`_tone_pattern`), by the bytes of their tones.
        self._patterns: dict[bytes, _TonePattern] = {}
        #: The direct path's readings of the last hops: (hop index, delay (s), time scale).
        self._read_speeds: list[tuple[int, float, float]] = []
        #: The direct path's speeds as given (held ones too) of the last 2 STEADY_HOPS hops,
        #: as above (:meth:`_steady`).
        self._steady_speeds: list[tuple[int, float, float]] = []
        #: Every onset read in the last :data:`MOVING_HOPS` hops, refused ones too: (hop
        #: index, delay (s)) (:meth:`_standing`).
        self._onsets: list[tuple[int, float]] = []
        #: The onsets kept (given) in the last :data:`MOVING_HOPS` hops: (hop index, delay
        #: (s)) (:meth:`_off_track`).
        self._kept: list[tuple[int, float]] = []

    def allow_lag(self, samples: int) -> None:
        """Keep ``samples`` (input samples) more history: a detection reaches
        :meth:`first_arrival` up to that long after its boundary's samples were pushed (the
        caller's decision lag), and its windows must still be in the history. Forgets the
        history."""
        if samples < 0:
            raise ConfigError("samples", samples, ">= 0 (input samples of decision lag)")
        self.history = self._own_history + int(samples)
        self._ring = RowBuffer(self.history, (), np.float64)
        self.reset(0)

    def reset(self, input_index: int) -> None:
        """Forget the history; the next sample is ``input_index`` (after a gap)."""
        self._ring.reset(input_index)
        self._valid_from = int(input_index)
        self._scores.clear()
        self._read_speeds.clear()
        self._steady_speeds.clear()
        self._onsets.clear()
        self._kept.clear()

    def push(self, x: NDArray[np.float64], first_index: int) -> None:
        """Append input samples (shape ``(n,)``) starting at absolute index ``first_index``."""
        self._ring.append(x, first_index)

    def first_arrival(self, t_c: float, alpha: float, hop_index: int) -> FirstArrival | None:
        """The first arrival at the boundary that ends hop ``hop_index``, received at ``t_c``
        (s, input time base: the centroid) with time scale ``alpha``: its time and its own
        time scale (:meth:`_direct_alpha`); None where the history is missing (start, gaps)
        or no onset stands out."""
        fs = self.fs_hz
        sch = self.schedule
        m = self.m_hops
        # One look-up of every hop the readout needs (h − M − LATE_HOPS + 1 .. h + 1, at least
        # from h − M); each hop's values do not depend on the span asked for.
        first_hop = hop_index - m - max(LATE_HOPS - 1, 0)
        table = sch.hops(first_hop, hop_index + 2 - first_hop)
        tones = table.freq_hz
        hops = _hop_slice(table, hop_index - m + 2 - first_hop, m)  # hops h-M+2 .. h+1
        prev_hop = _hop_slice(table, hop_index - m + 1 - first_hop, 1)  # before the oldest
        f_next = hops.freq_hz[::-1]  # tone after boundary m (m = 0: after hop h)
        # Receive times of the boundaries, from their transmit spacing compressed by α.
        ends = hops.start_s[::-1]  # start of the hop after boundary m = its transmit time
        t_b = t_c - (ends[0] - ends) / alpha
        t_b_fs = t_b * fs  # receive times, samples
        n_b = np.rint(t_b_fs).astype(np.int64)  # np.round's own step at 0 decimals
        w = self.boxcar
        first = n_b - self._pre - self._lead - self.period
        held_from = max(self._valid_from, self._ring.next_index - self._ring.available)
        if first.min() < held_from or n_b.max() + self._post > self._ring.next_index:
            return None
        # d · e^{−j2π α f t} (t = idx / fs, idx the absolute sample index; d the input, less
        # or plus the period before behind the canceller) summed along each boundary's row of
        # L + lead samples; ``full``: the boxcar of w ending at extended index w, w + 1, ...
        # (M, L + w); ``box``: the boxcar's change over its own length (M, L): every steady
        # tone on the Δf grid (the previous tones, and the next tone as sounded by late images
        # of earlier boundaries) gives the same boxcar sum w samples apart and cancels, only
        # switches remain; ``p_all``: |box / w|², as |box · (1/w)|² (the same bits: see
        # _ramp_residuals). The kernel reads the rows from the history itself and its
        # operations are NumPy's (hil.estimation.first_arrival_kernels).
        coef = -2j * np.pi * alpha * f_next  # (M,), complex: its real parts are 0
        n_ext = self._offsets_ext.size
        row_first = n_b + self._offsets_ext[0]  # absolute index of each row's first sample
        full = np.empty((m, n_ext - w), dtype=np.complex128)
        box = np.empty((m, n_ext - 2 * w), dtype=np.complex128)
        p_all = np.empty((m, n_ext - 2 * w))
        ring_channel(
            self._ring.array, self._ring.position(row_first), self.period, self.sign, row_first,
            fs, np.ascontiguousarray(coef.imag), w, 1.0 / w, full, box, p_all,
        )  # fmt: skip
        pattern = self._tone_pattern(tones)  # clean, leave: read-only, shared
        clean = pattern.clean
        power = _mean(p_all[clean], axis=0)  # (L,)
        base = self._noise_window(power)
        amp = np.sqrt(np.maximum(power - _mean_all(power[base]), 0.0))
        top_i = self._after + int(amp[self._after :].argmax())
        leave = pattern.leave
        if self._late_images_seen(p_all, power, clean, leave, top_i):
            clean = clean & ~leave
            power = _mean(p_all[clean], axis=0)
            base = self._noise_window(power)
            amp = np.sqrt(np.maximum(power - _mean_all(power[base]), 0.0))
            top_i = self._after + int(amp[self._after :].argmax())
        top = float(amp[top_i])
        noise = math.sqrt(_mean_all(power[base]))
        if not top > 3.0 * noise:
            return None
        # The fit's levels: fractions of the top, but clear of the noise's own fluctuation.
        wobble = NOISE_MARGIN * _std(amp[base])
        # An earlier arrival of its own (the direct path more than two windows ahead of a
        # cluster of images that sums to the top: the change over a window falls back to the
        # noise between them) has its own ramp and top: the earliest rise above
        # EARLY_FRACTION of the top, and its top within two windows, before the change falls
        # back to ``lo`` (a later arrival rising there is another one, with its own ramp: the
        # carriage at rest in the built-in tank on tank-board, the direct path at 4.90 m and
        # its surface image on one leg 0.28 m behind it, 1.6 times as strong).
        k0 = self._search_from
        early = _nonzero(amp[k0:top_i] >= max(EARLY_FRACTION * top, 2.0 * wobble))
        if early.size:
            j_e = k0 + int(early[0])
            stop = min(top_i, j_e + 2 * w)
            fell = _nonzero(~(amp[j_e : stop + 1] >= max(LO_FRACTION * top, wobble)))
            if fell.size:
                stop = j_e + int(fell[0]) - 1
            top_i = j_e + int(amp[j_e : stop + 1].argmax())
            top = float(amp[top_i])
        floor = _mean_all(power[base])
        j_lo, j_hi = self._ramp_bounds(amp, k0, top_i, top, wobble)
        # A pedestal is not a ramp. The previous boundary's late images (at image order 2 the
        # far end wall and another boundary, 0.9 hop behind their direct path) switch tones
        # just before this boundary's first arrival: on the boundaries whose next tone they
        # leave (the tone two hops back) at their full amplitude, on the others by the leak of
        # the switch through the window, weaker. The first arrival switches every boundary
        # alike. So a stretch above ``hi`` that does not reach PEDESTAL_RISE times its
        # crossing level within a window (the top still farther), with PEDESTAL_RATIO times the
        # power on the boundaries leaving the tone as on the others, is read as a level and
        # the ramp searched again above it.
        for _ in range(MAX_PEDESTALS):
            if j_lo <= k0 or j_hi + w >= top_i or leave.all() or not leave.any():
                break
            ped = float(amp[j_hi : j_hi + w].max())
            if ped >= PEDESTAL_RISE * max(float(amp[j_hi]), wobble):
                break
            p_box = p_all[:, j_hi : j_hi + w]
            if _mean_all(p_box[leave]) < PEDESTAL_RATIO * _mean_all(p_box[~leave]):
                break
            floor += ped**2
            amp = np.sqrt(np.maximum(power - floor, 0.0))
            k0 = j_hi
            top = float(amp[top_i])
            j_lo, j_hi = self._ramp_bounds(amp, k0, top_i, top, wobble)
        frac = t_b_fs - n_b  # each boundary's predicted switch, samples past its n_b
        prev_f = np.concatenate([f_next[1:], prev_hop.freq_hz])
        ramp = self._ramp_tables(frac, alpha * (prev_f - f_next), self._phase_jumps(hops, prev_hop))
        copy_after = bool(self.period) and alpha > 1.0
        levels = _Levels(power, floor, amp, k0, top_i, top, wobble, j_lo, j_hi)
        onsets = self._onset(levels, full, box, clean, ramp, copy_after)
        if onsets is None:
            return None
        # The speed is read at the line's onset, the range at the onset searched for the
        # first arrival itself (:meth:`_onset`): on the new floor where the level just
        # before the ramp is lower than the noise read (:meth:`_near_floor`).
        rel_speed, rel = onsets
        near = self._near_floor(levels)
        if near is not None:
            amp_near = np.sqrt(np.maximum(power - near, 0.0))
            top_near = float(amp_near[top_i])
            on_near = _Levels.read(power, near, amp_near, k0, top_i, top_near, wobble)
            again = self._onset(on_near, full, box, clean, ramp, copy_after)
            if again is not None:
                rel = again[1]
        onset = float(t_b[0] + rel)
        # The canceller's copy of an opening target (δ < 0) arrives |δ| earlier.
        delta = sch.period_s * (alpha - 1.0) / alpha if self.period else 0.0
        # The direct path alone: its first DIRECT_S (before the first image).
        direct_alpha = None
        j0 = self._pre + int(math.ceil(rel_speed * fs))
        j1 = self._pre + int(round((rel_speed + DIRECT_S) * fs))
        if 0 <= j0 < j1 < box.shape[1]:
            n = np.arange(j0, j1 + 1)
            shape = self._ramp_shape(np.array([rel_speed * fs]), n, ramp)[0]  # (M, J)
            seen = np.asarray(box[:, j0 : j1 + 1], dtype=np.complex128) / w
            # Each boundary's complex amplitude by least squares on the model's shape: the
            # previous tone's leak, different at each boundary, is divided out.
            p = np.add.reduce(np.conj(shape) * seen, axis=1) / np.maximum(
                np.add.reduce(np.abs(shape) ** 2, axis=1), 1e-300
            )
            direct_alpha = self._direct_alpha(
                p, hops, n_b, alpha, hop_index, onset - ends[0], pattern
            )
            if direct_alpha is None and self._reads_late_taps(alpha):
                direct_alpha = self._second_reading(
                    table, hop_index, first_hop, t_b_fs + rel_speed * fs, alpha, hops, n_b,
                    onset - ends[0],
                )  # fmt: skip
            self._read_speeds = [r for r in self._read_speeds if 0 < hop_index - r[0] <= HOLD_HOPS]
            if direct_alpha is not None:
                self._read_speeds.append((int(hop_index), float(onset - ends[0]), direct_alpha))
            elif self._reads_late_taps(alpha):
                direct_alpha = self._held_alpha(hop_index, onset - ends[0], alpha)
        if direct_alpha is not None:
            kept = [r for r in self._steady_speeds if 0 < hop_index - r[0] < 2 * STEADY_HOPS]
            kept.append((int(hop_index), float(onset - ends[0]), direct_alpha))
            self._steady_speeds = kept
        read_alpha = alpha if direct_alpha is None else direct_alpha
        first_s = onset - min(0.0, delta)
        # Behind the canceller a path at rest in delay is cancelled with the still water.
        if not self.period:
            delay_s = first_s - ends[0]
            if self._standing(hop_index, delay_s, read_alpha) or self._off_track(
                hop_index, delay_s, read_alpha
            ):
                return None
        return FirstArrival(first_s, read_alpha)

    def _off_track(self, hop_index: int, delay_s: float, alpha: float) -> bool:
        """Whether the onset read at hop ``hop_index`` (``delay_s`` as in :meth:`_standing`)
        leaves the track the same echo's onsets kept: at least :data:`STANDING_READINGS`
        onsets read and kept up to :data:`MOVING_HOPS` hops back within
        :data:`DOPPLER_GATE_S` of it (the same echo), each moved on to this hop at time
        scale ``alpha``, agree within the standing tolerance and this one lies more than
        :data:`TRACK_JUMP` tolerances off them. Kept onsets are remembered.

        A first arrival moves with its echo; a path that comes ahead of it is read from the
        hop it first does (tank-board's far-wall path one hop late, its first readings:
        0.33 m short), before it has stood long enough for :meth:`_standing` to tell. The
        track is forgotten when no onset of it has been kept for :data:`MOVING_HOPS` hops."""
        tol = STANDING_TOLERANCE * self.boxcar / self.fs_hz
        step = 2.0 * (alpha - 1.0) / (alpha + 1.0) * self._hop_s  # delay lost per hop, s
        kept = [r for r in self._kept if 0 < hop_index - r[0] <= MOVING_HOPS]
        near = [d - step * (hop_index - h) for h, d in kept if abs(d - delay_s) <= DOPPLER_GATE_S]
        off = (
            len(near) >= STANDING_READINGS
            and max(near) - min(near) <= 2.0 * tol
            and abs(delay_s - _median(near)) > TRACK_JUMP * tol
        )
        self._kept = kept if off else [*kept, (int(hop_index), float(delay_s))]
        return off

    def _standing(self, hop_index: int, delay_s: float, alpha: float) -> bool:
        """Whether the onset read at hop ``hop_index`` (``delay_s``: the first arrival less
        the newest boundary's transmit time, s) stands still while the echo moves at time
        scale ``alpha``: at least :data:`STANDING_READINGS` onsets read
        :data:`MOVING_HOPS` hops back or fewer, far enough back that the echo has moved
        :data:`STANDING_MOVE` tolerances since, lie within :data:`STANDING_TOLERANCE` windows
        of it. The onset is remembered either way.

        A path whose length does not change with the target's place is at rest in delay: on
        the tank's axis the target's echo through the far end wall on one leg (twice the far
        wall's distance long). Where it arrives ahead of a later boundary's direct path it is
        read as the first arrival for as long as the target takes to cross it (tank-board's
        5 ms hop in the built-in tank: 0.2 s at 8.05-7.78 m, 0.26-0.33 m short); its
        Doppler is read at the target's, so only its standing delay tells it apart. Read
        without the canceller only: behind it such a path is cancelled with the still water."""
        tol = STANDING_TOLERANCE * self.boxcar / self.fs_hz
        rate = abs(2.0 * (alpha - 1.0) / (alpha + 1.0)) * self._hop_s  # delay moved per hop, s
        recent = [r for r in self._onsets if 0 < hop_index - r[0] <= MOVING_HOPS]
        self._onsets = [*recent, (int(hop_index), float(delay_s))]
        if rate <= 0.0:
            return False
        standing = sum(
            1
            for hop, delay in recent
            if rate * (hop_index - hop) >= STANDING_MOVE * tol and abs(delay - delay_s) <= tol
        )
        return standing >= STANDING_READINGS

    def _steady(self, hop_index: int, delay_s: float) -> bool:
        """Whether the direct path's speed of the same echo has been steady before hop
        ``hop_index`` (:data:`STEADY_MPS`): its readings (held ones too) 1 to
        :data:`STEADY_HOPS` hops back and :data:`STEADY_HOPS` + 1 to 2 :data:`STEADY_HOPS`
        back, at least two each, have medians at most :data:`STEADY_MPS` apart. The same
        echo: a reading whose delay, moved on by the range the echo covers at its own speed
        in those hops, is within :data:`DOPPLER_GATE_S` of ``delay_s`` (s, the first arrival
        less the newest boundary's transmit time)."""
        c = self.sound_speed_mps
        newer: list[float] = []
        older: list[float] = []
        for hop, delay, a in self._steady_speeds:
            lag = hop_index - hop
            if not 0 < lag <= 2 * STEADY_HOPS:
                continue
            v = c * (a - 1.0) / (a + 1.0)
            if abs(delay - 2.0 * v * lag * self._hop_s / c - delay_s) > DOPPLER_GATE_S:
                continue
            (newer if lag <= STEADY_HOPS else older).append(v)
        if len(newer) < 2 or len(older) < 2:
            return False
        return abs(_median(newer) - _median(older)) <= STEADY_MPS

    def _onset(
        self,
        levels: _Levels,
        full: NDArray[np.complex128],
        box: NDArray[np.complex128],
        clean: NDArray[np.bool_],
        ramp: _RampTables,
        copy_after: bool = False,
    ) -> tuple[float, float] | None:
        """The onset of the ramp that leads to the top, twice (s after each boundary's
        predicted switch; None where no clean onset stands out): the line's, and the first
        arrival's where the line is fitted on the ramp's steep part.

        ``levels``: the mean next-tone power over the boundaries read (``clean``, shape
        ``(M,)``) and the levels its ramp is read against (:class:`_Levels`); ``full``,
        ``box``: the next-tone channel and its change over a window (shapes ``(M, L + w)``,
        ``(M, L)``);
        ``ramp``: the boundaries' ramp tables; ``copy_after``: the canceller's sign-flipped
        copy of each arrival comes after it (a closing target behind the canceller).

        The line runs from ``lo`` to ``hi`` and the ramp's model is fitted within
        ``±FIT_SPAN`` samples of its zero crossing. A rise from ``lo`` to ``hi`` slower than
        :data:`SLOW_RISE` windows puts the line on the ramp's steep part; where that rise is
        the next tone arriving to stay, it is a weak first arrival whose images join it
        before it reaches ``hi`` (image order 3), and the model is fitted again, with a
        constant level, from a quarter window before ``lo`` up to the line's crossing: the
        second onset, kept where the model explains at least :data:`COHERENT_FIT` of the
        channel's power on each boundary from there to the line's crossing
        (:meth:`_explained`; a late path switching ahead of the first arrival, off the
        direct path's tone grid, does not fit its shape).
        """
        fs = self.fs_hz
        w = self.boxcar
        amp, k0, top_i, top = levels.amp, levels.k0, levels.top_i, levels.top
        j_lo, j_hi = levels.j_lo, levels.j_hi
        if j_lo <= k0:
            return None  # the ramp runs into the baseline: no clean onset
        # A slow rise from lo to hi is not the ramp itself (SLOW_RISE).
        j_a, j_b = j_lo, j_hi
        holds = False
        if j_hi - j_lo > SLOW_RISE * w:
            # The next tone arriving to stay (a weak first arrival under its images) has its
            # steep part within a window; a late images' level ahead of it does not.
            holds = self._new_tone_holds(full, clean, j_lo, top_i)
            stop = min(top_i, j_hi + w) if holds else top_i
            up = _nonzero(amp[j_hi : stop + 1] >= 2.0 * amp[j_hi])
            if up.size:
                j_a, j_b = j_hi, j_hi + max(2, int(up[0]))
        slope, icept = self._line(amp, j_a, j_b)
        if (
            copy_after
            and holds
            and j_a != j_lo
            and slope > 0
            and -icept / slope > self._offsets[j_lo] / fs
        ):
            # Behind the canceller a closing target's every arrival comes with its
            # sign-flipped copy a period back, delta later (0.33 ms at 1.5 m/s, under a
            # window): with the first images it can hold the first arrival's own ramp under
            # ``hi``, so its rise from ``lo`` to ``hi`` is slow though it holds the next
            # tone. A ramp crosses ``lo`` after its onset: a steep part whose line starts
            # after that crossing is those later arrivals, and the first arrival is the rise
            # from ``lo`` itself. (An opening target's copy comes first: not this case.)
            j_a, j_b = j_lo, j_hi
            slope, icept = self._line(amp, j_a, j_b)
        if not slope > 0:
            return None
        # The line is the start; the ramp's exact shape (the previous tone's partial window
        # leaks into the channel while the window straddles the switch) moves its zero
        # crossing by some 30 µs: fit that shape instead.
        excess = levels.power - levels.floor
        lo_fit = max(k0, j_lo - FIT_LEAD)
        above = _nonzero(amp[j_lo : j_hi + 1] >= FIT_HI_FRACTION * top)
        j_fit = j_lo + int(above[0]) if above.size else j_hi
        j_fit = max(j_fit, j_lo + 2)
        guess = -icept / slope
        if not -self.max_spread_s - BASELINE_S < guess < TOP_S:
            return None
        part = ramp.subset(clean)
        rel = self._fit_ramp(excess[lo_fit : j_fit + 1], lo_fit, guess, part)
        # ``rel`` is the onset after each boundary's predicted switch ``t_b`` (the model
        # places boundary m's switch at ``t_b[m] fs + rel fs``).
        if not holds or j_a == j_lo:
            return rel, rel
        # A weak first arrival under its images: the model searched from a quarter window
        # before ``lo`` to the line's crossing, a constant level beside it.
        first_s = (j_lo - int(WIDE_LEAD * w) - self._pre) / fs
        last_s = guess + FIT_SPAN / fs
        span = max(FIT_SPAN, int((last_s - first_s) * fs / 2) + 1)
        wide = self._fit_ramp(
            excess[lo_fit : j_fit + 1], lo_fit, (first_s + last_s) / 2, part, span, level=True
        )
        i_w = self._pre + int(round(wide * fs))
        i_g = max(self._pre + int(round(guess * fs)), i_w + 4)
        if i_g >= box.shape[1] or self._explained(box, clean, ramp, wide, i_w, i_g) < COHERENT_FIT:
            return rel, rel
        return rel, wide

    def _near_floor(self, levels: _Levels) -> float | None:
        """The noise level just before the ramp, where the one read (``levels.floor``) is
        more than :data:`NEAR_RATIO` times it; None otherwise. ``levels``: as
        :meth:`_onset`'s.

        The least mean of ``power`` over :data:`NEAR_PART` windows within the window before
        the ramp's ``lo`` crossing. The noise window lies before the search; the older late
        paths' leak there can be several times the level just before a weak first arrival
        (image order 3: 4 times at 8.3 m), which then falls under it and is read late."""
        w = self.boxcar
        j_lo = levels.j_lo
        part = max(2, int(round(NEAR_PART * w)))
        seg = levels.power[max(levels.k0, j_lo - w) : j_lo]
        if seg.size < part:
            return None
        c = np.empty(seg.size + 1)
        c[0] = 0.0
        np.cumsum(seg, out=c[1:])
        least = float((c[part:] - c[:-part]).min()) / part
        return least if levels.floor > NEAR_RATIO * least else None

    def _explained(
        self,
        box: NDArray[np.complex128],
        clean: NDArray[np.bool_],
        ramp: _RampTables,
        rel: float,
        i0: int,
        i1: int,
    ) -> float:
        """The fraction of the next-tone channel's change (``box``, shape ``(M, L)``) on the
        boundaries read (``clean``) at window indices ``i0 .. i1 − 1`` that one arrival's
        ramp model at onset ``rel`` (s, :meth:`_ramp_shape`) explains, its complex amplitude
        fitted on each boundary by least squares (dimensionless, 0..1)."""
        n = np.arange(i0, i1)
        shape = self._ramp_shape(np.array([rel * self.fs_hz]), n, ramp)[0][clean]  # (K, J)
        seen = box[clean][:, n] / self.boxcar
        gain = np.add.reduce(np.conj(shape) * seen, axis=1) / np.maximum(
            np.add.reduce(np.abs(shape) ** 2, axis=1), 1e-300
        )
        fitted = float(np.add.reduce(np.abs(gain[:, None] * shape) ** 2, axis=None))
        return fitted / max(float(np.add.reduce(np.abs(seen) ** 2, axis=None)), 1e-300)

    def _held_alpha(self, hop_index: int, delay_s: float, alpha: float) -> float | None:
        """The direct path's time scale read at the same echo up to :data:`HOLD_HOPS` hops
        before hop ``hop_index`` (the newest such reading), where this detection's readings
        are refused; None where there is none.

        The same echo: a reading whose delay, moved on by the range the echo covers at its own
        speed in those hops, is within :data:`DOPPLER_GATE_S` of ``delay_s`` (s, the first
        arrival less the newest boundary's transmit time). It is kept only inside the span
        the direct path's speed is searched in around GCAS's (time scale ``alpha``): not
        slower by more than :data:`DIRECT_BELOW_GCAS_MPS`, not faster by more than
        :data:`DIRECT_SPAN_FASTER` ``v_res``. Only readings are kept for this (a held speed is
        not held again), so a held speed is at most :data:`HOLD_HOPS` hops old."""
        c = self.sound_speed_mps
        v_gcas = c * (alpha - 1.0) / (alpha + 1.0)
        sign = float(np.sign(alpha - 1.0))
        faster = self._steps_faster * DIRECT_SPEED_STEP
        for hop, delay, a in reversed(self._read_speeds):
            if not 0 < hop_index - hop <= HOLD_HOPS:
                continue
            v = c * (a - 1.0) / (a + 1.0)
            moved = 2.0 * v * (hop_index - hop) * self._hop_s / c
            if abs(delay - moved - delay_s) > DOPPLER_GATE_S:
                continue
            rel = sign * (v - v_gcas)
            if -DIRECT_BELOW_GCAS_MPS <= rel <= faster:
                return a
        return None

    def _reads_late_taps(self, alpha: float) -> bool:
        """Whether a refused direct-path speed is read again with the late paths fitted
        (:meth:`_second_reading`): with no canceller only (its copy one period back is not in
        the tap model), for a target GCAS reads moving at :data:`LATE_TAP_MIN_SPEED_MPS` or
        more (``alpha``: GCAS's time scale)."""
        v_gcas = self.sound_speed_mps * (alpha - 1.0) / (alpha + 1.0)
        return not self.period and abs(v_gcas) >= LATE_TAP_MIN_SPEED_MPS

    def _second_reading(
        self,
        table: HopTable,
        hop_index: int,
        first_hop: int,
        onset_n: NDArray[np.float64],
        alpha: float,
        hops: HopTable,
        n_b: NDArray[np.int64],
        delay_s: float,
    ) -> float | None:
        """The direct path's time scale read again on the input samples with the late paths'
        switches fitted (:meth:`_late_tap_fit`), where the late taps hold at least
        :data:`LATE_TAP_RATIO` times the direct path's power; None otherwise (GCAS's is
        kept). Where it is read, its Doppler score takes the first reading's place among the
        scores the next detections sum with. ``table``: the hops from ``first_hop``;
        ``onset_n``: each boundary's switch, absolute samples (shape ``(M,)``); ``delay_s``:
        the first arrival less the newest boundary's transmit time, s."""
        fit = self._late_tap_fit(table, hop_index - first_hop, onset_n, alpha)
        if fit.late_ratio < LATE_TAP_RATIO:
            return None
        last = self._scores[-1] if self._scores else None
        if last is not None and (last.hop_index, last.delay_s) == (hop_index, delay_s):
            self._scores.pop()
        pattern = self._tone_pattern(table.freq_hz)
        return self._direct_alpha(fit.amplitude, hops, n_b, alpha, hop_index, delay_s, pattern)

    def _late_tap_fit(
        self, table: HopTable, h: int, onset: NDArray[np.float64], alpha: float
    ) -> DirectFit:
        """The direct path's complex amplitude at the ``M`` boundaries (shape ``(M,)``) by
        :func:`hil.estimation.late_taps.direct_amplitudes` on the input samples: its first
        :data:`DIRECT_S` after ``onset`` (absolute samples, shape ``(M,)``) and
        :data:`~hil.estimation.late_taps.LEAD_S` before, the late paths' switches fitted.
        ``table``: the hops from ``h − M`` (``h``: the row of hop ``hop_index``, the newest
        boundary's) to ``h + 1``."""
        fs = self.fs_hz
        m = self.m_hops
        lead = int(round(LEAD_S * fs))
        first = np.ceil(onset).astype(np.int64) - lead
        idx = first[:, None] + np.arange(lead + int(round(DIRECT_S * fs)) + 1)[None, :]
        y = self._ring.rows(idx)
        tones = table.freq_hz[h - m : h + 2][::-1]  # tone of hop h + 1 − k at row k
        freqs = np.stack([tones[2 : m + 2], tones[1 : m + 1], tones[:m]])  # (3, M)
        jump_cn = self._phase_jumps(
            _hop_slice(table, h - m + 2, m), _hop_slice(table, h - m + 1, 1)
        )
        jump_pc = self._phase_jumps(_hop_slice(table, h - m + 1, m), _hop_slice(table, h - m, 1))
        return direct_amplitudes(
            y, first, onset, freqs, np.stack([jump_pc, jump_cn]), alpha, fs, lead
        )

    def _line(self, amp: NDArray[np.float64], j_a: int, j_b: int) -> tuple[float, float]:
        """Slope (per s) and intercept of the least-squares line through ``amp`` (shape
        ``(L,)``) at window indices ``j_a .. j_b``, against their offsets in s: its zero
        crossing ``−intercept / slope`` is an onset, s after boundary 0's sample."""
        tt = self._offsets[j_a : j_b + 1] / self.fs_hz
        return _line_fit(tt, amp[j_a : j_b + 1])

    @staticmethod
    def _ramp_bounds(
        amp: NDArray[np.float64], k0: int, top_i: int, top: float, wobble: float
    ) -> tuple[int, int]:
        """The ramp that leads to the top (index ``top_i`` of ``amp``, shape ``(L,)``): its
        last rise from ``lo`` and its first ``hi`` crossing (indices; fractions of ``top``, at
        least ``wobble`` apart and above the noise), searched after ``k0``.

        The ramp starts where the power last left the noise before the top: an image of
        opposite sign can pull the sum back below ``hi`` inside the ramp, so the stretch is
        followed down to ``lo``, and ``hi`` is its first crossing."""
        lo_level = max(LO_FRACTION * top, wobble)
        hi_level = max(HI_FRACTION * top, lo_level + wobble)
        # Where ``amp`` last fails ``>= lo`` before ``top_i`` (NaN fails too), searched after k0.
        below = _nonzero(~(amp[k0:top_i] >= lo_level))
        j = k0 + int(below[-1]) + 1 if below.size else k0
        above_hi = _nonzero(amp[j : top_i + 1] >= hi_level)
        j_hi = j + int(above_hi[0]) if above_hi.size else top_i
        below = below[below < j_hi - k0]
        j = k0 + int(below[-1]) + 1 if below.size else k0
        return min(j, j_hi - 2), j_hi

    def _new_tone_holds(
        self,
        full: NDArray[np.complex128],
        clean: NDArray[np.bool_],
        j_lo: int,
        top_i: int,
    ) -> bool:
        """Whether the rise that crosses ``lo`` at window index ``j_lo`` is the next tone
        arriving to stay, on the boundaries read (``clean``, shape ``(M,)``).

        ``full`` (shape ``(M, L + w)``, complex): the next-tone channel ``b``, its window
        ending at window index ``j`` in column ``j + w``. A first arrival switches to the next
        tone and keeps sounding it: ``|b|²`` a window after its onset (one and a half windows
        after ``j_lo − w/4``, at most at the top ``top_i``) exceeds ``|b|²`` half a window
        before it by about the power of the change over that window, ``|z|²`` (more where
        images join it), mean over the boundaries: :data:`NEW_TONE_RATIO` times at least. The
        previous boundary's late images switch between two other tones: on most boundaries
        only their switch leaks through the window and ``b`` returns to its level (on those
        whose next tone they leave, it falls), so their level's ratio is near 0."""
        w = self.boxcar
        j_on = j_lo - w // 4
        before = np.abs(full[clean, j_on - w // 2 + w]) ** 2
        after = np.abs(full[clean, min(j_on + w + w // 2, top_i) + w]) ** 2
        change = np.abs(full[clean, min(j_on + w, top_i) + w] - full[clean, min(j_on + w, top_i)])
        grown = _mean_all(after - before)
        return grown > NEW_TONE_RATIO * _mean_all(change**2)

    def _late_images_seen(
        self,
        p_all: NDArray[np.float64],
        power: NDArray[np.float64],
        clean: NDArray[np.bool_],
        leave: NDArray[np.bool_],
        top_i: int,
    ) -> bool:
        """Whether the previous boundary's late images sound this boundary's next tone ahead
        of its first arrival: on the boundaries read (``clean``, shape ``(M,)``) whose next
        tone is the tone two hops back (``leave``), the next-tone channel's power (``p_all``,
        shape ``(M, L)``; ``power``, its mean over ``clean``, shape ``(L,)``) between the
        search's start and the first arrival (half a window before the first rise to
        :data:`EARLY_FRACTION` of the top ``top_i``) is more than :data:`LATE_RATIO` times
        that on the others (at least :data:`MIN_CLEAN` of them). A first arrival switches
        every boundary alike."""
        late = clean & leave
        other = clean & ~leave
        # Before the first arrival: half a window before the first rise to EARLY_FRACTION
        # of the top (an arrival's ramp takes a window to its top).
        strong = _nonzero(power[self._search_from : top_i + 1] >= EARLY_FRACTION**2 * power[top_i])
        stop = self._search_from + int(strong[0]) - self.boxcar // 2
        if not late.any() or np.count_nonzero(other) < MIN_CLEAN or stop <= self._search_from:
            return False
        pre = slice(self._search_from, stop)
        return _mean_all(p_all[late, pre]) > LATE_RATIO * _mean_all(p_all[other, pre])

    def _tone_pattern(self, tones: NDArray[np.float64]) -> _TonePattern:
        """The :class:`_TonePattern` of ``tones``: the tones of the hops
        :meth:`first_arrival` looks up for a detection at hop ``h`` (Hz, oldest first, from
        hop ``h − M − max(LATE_HOPS − 1, 0)`` to ``h + 1``), computed once per pattern."""
        key = tones.tobytes()
        pattern = self._patterns.get(key)
        if pattern is not None:
            return pattern
        lead = max(LATE_HOPS - 1, 0)  # hops in ``tones`` before hop h − M
        clean = self._clean_boundaries(tones[lead + 1 - LATE_HOPS :])
        leave = self._late_leaving(tones[lead:])
        next_tones = tones[lead + 2 : lead + 2 + self.m_hops][::-1]  # after boundary m
        distinct, group = np.unique(next_tones, return_inverse=True)
        columns = tuple(np.flatnonzero(group == j) for j in range(distinct.size))
        clean.setflags(write=False)
        leave.setflags(write=False)
        order = np.concatenate(columns).astype(np.int64)
        starts = np.cumsum([0] + [c.size for c in columns]).astype(np.int64)
        recurs = bool(np.bincount(group).max() >= 2)
        pattern = _TonePattern(clean, leave, columns, order, starts, recurs)
        if len(self._patterns) >= MAX_PATTERNS:
            self._patterns.clear()
        self._patterns[key] = pattern
        return pattern

    def _late_leaving(self, tones: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which of the ``M`` boundaries (newest first) have the tone two hops back as their
        next tone: there the previous boundary's late images leave the next tone (shape
        ``(M,)``). ``tones``: the tones of hops ``h − M .. h + 1`` (Hz, oldest first, shape
        ``(M + 2,)``)."""
        m = self.m_hops
        nxt = tones[2:][::-1]  # next tone of boundary j (j = 0: after hop h)
        two_back = tones[:m][::-1]  # tone of hop h − j − 1
        return np.asarray(np.abs(two_back - nxt) < 0.5, dtype=bool)

    def _clean_boundaries(self, tones: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which of the ``M`` boundaries (newest first) the onset is read on: those whose next
        tone was sounded neither in the hop it follows nor in the :data:`LATE_HOPS` before (all of
        them where fewer than :data:`MIN_CLEAN` are left). Shape ``(M,)``. ``tones``: the tones
        of hops ``h − M − LATE_HOPS + 1 .. h + 1`` (Hz, oldest first, shape
        ``(M + LATE_HOPS + 1,)``).

        A tank's late images (the far end wall on one leg comes 0.9 hop after the direct path
        in the built-in tank at 5 m) switch tones a fraction of a hop before a later
        boundary's direct path: where the tone they leave is that boundary's next tone, the
        next-tone channel changes there too, and an onset read on it is up to a hop early.
        """
        m, k = self.m_hops, LATE_HOPS
        nxt = tones[k + 1 :][::-1]  # next tone of boundary j (j = 0: after hop h)
        # Tone of hop h − j − i for boundary j, i = 0 (the hop it follows) .. K: (K + 1, M).
        before = np.stack([tones[k - i : k - i + m][::-1] for i in range(k + 1)])
        clean = np.all(np.abs(before - nxt[None, :]) > 0.5, axis=0)
        if np.count_nonzero(clean) < MIN_CLEAN:
            return np.ones(m, dtype=bool)
        return np.asarray(clean, dtype=bool)

    def _noise_window(self, power: NDArray[np.float64]) -> slice:
        """Where the noise level is read in ``power`` (shape ``(L,)``): the stretch of
        :data:`BASELINE_S` before the search, or the quietest such stretch before the
        centroid where the first holds more than :data:`QUIET_RATIO` times its power. Late
        images of earlier boundaries switch tones before the first arrival too (at image
        order 2 the target's echo through both end walls comes a hop late): a noise level
        read on one hides the onset."""
        n = self._base_count
        k_start = self._base_start
        seg = power[k_start : self._after]
        c = np.empty(seg.size + 1)
        c[0] = 0.0
        np.cumsum(seg, out=c[1:])
        sums = c[n:] - c[:-n]  # power summed over each stretch
        k = int(sums.argmin())
        fixed = _mean_all(power[self._base_slice])
        if fixed <= QUIET_RATIO * sums[k] / n:
            return self._base_slice
        return slice(k_start + k, k_start + k + n)

    @staticmethod
    def _phase_jumps(hops: HopTable, prev_hop: HopTable) -> NDArray[np.float64]:
        """Phase step of the transmit signal at each boundary (rad, shape ``(M,)``): the next
        hop's start phase less the previous hop's end phase (0 for phase-continuous codes)."""
        start = hops.phase_rad[::-1]  # next hop of boundary m
        prev_start = np.concatenate([start[1:], prev_hop.phase_rad])
        prev_end = prev_start + 2.0 * np.pi * np.concatenate(
            [hops.freq_hz[::-1][1:], prev_hop.freq_hz]
        ) * np.concatenate([hops.duration_s[::-1][1:], prev_hop.duration_s])
        return np.asarray(start - prev_end, dtype=np.float64)

    def _ramp_tables(
        self,
        frac: NDArray[np.float64],
        beat_hz: NDArray[np.float64],
        jump: NDArray[np.float64],
    ) -> _RampTables:
        """The ramp model's per-boundary tables of one detection (:class:`_RampTables`) from
        each boundary's predicted switch ``frac`` (samples past its sample), beat ``beat_hz``
        (``α(f_prev − f_next)``, Hz) and phase jump ``jump`` (rad), each shape ``(M,)``."""
        k = self._window_counts  # 0 .. w, (1, w + 1)
        theta = 2.0 * np.pi * beat_hz / self.fs_hz  # (M,)
        ratio = np.exp(1j * theta)
        # Σ_{i=a}^{a+k−1} e^{jθ(i−o)} = e^{jθa} e^{−jθo} (1 − r^k)/(1 − r), r = e^{jθ}
        # (k terms where θ = 0): the last factor for every k = 0 .. w, once per detection.
        one_minus = 1.0 - ratio
        steady = np.abs(one_minus) < 1e-12
        geometric = ratio[:, None] ** k  # r^k, (M, w + 1)
        np.subtract(1.0, geometric, out=geometric)  # 1 − r^k
        if not steady.any():  # no θ = 0 (the usual detection): the quotient in place
            geometric /= one_minus[:, None]
            return _RampTables(frac, theta, jump, geometric)
        denom = np.where(steady, 1.0, one_minus)[:, None]
        geometric = np.where(steady[:, None], k, geometric / denom)
        return _RampTables(frac, theta, jump, np.asarray(geometric, dtype=np.complex128))

    def _fit_ramp(
        self,
        excess: NDArray[np.float64],
        first: int,
        guess_s: float,
        ramp: _RampTables,
        span: int = FIT_SPAN,
        *,
        level: bool = False,
    ) -> float:
        """The onset (s after boundary 0's sample) whose model ramp fits ``excess`` best.

        ``excess`` (shape ``(L,)``): the mean next-tone power less the noise, at window
        indices ``first …``; ``ramp``: the boundaries' tables (:meth:`_ramp_tables`). The
        model's residual (:meth:`_ramp_residuals`; with ``level``, a constant level fitted
        beside the ramp) is searched on whole samples within ``±span`` of ``guess_s``, then
        in steps of ``FIT_STEP`` within a sample of the best, and refined by a parabola
        (``guess_s`` itself where the best is on the span's edge).
        """
        fs = self.fs_hz
        n = first + np.arange(excess.size)  # window indices (L,)
        start = self._window_start_phasors(ramp, n)
        coarse = guess_s * fs + np.arange(-span, span + 1, dtype=np.float64)
        resid = self._ramp_residuals(coarse, excess, n, ramp, start, level)
        k = int(resid.argmin())
        if k in (0, coarse.size - 1):
            return guess_s  # no minimum inside the span: the line stands
        fine = coarse[k] + np.arange(-1.0, 1.0 + FIT_STEP / 2, FIT_STEP)
        resid = self._ramp_residuals(fine, excess, n, ramp, start, level)
        k = int(resid.argmin())
        best = float(fine[k])
        if 0 < k < fine.size - 1:
            best += FIT_STEP * parabolic_offset(-resid[k - 1], -resid[k], -resid[k + 1])
        return best / fs

    def _ramp_residuals(
        self,
        grid: NDArray[np.float64],
        excess: NDArray[np.float64],
        n: NDArray[np.int64],
        ramp: _RampTables,
        start: NDArray[np.complex128],
        level: bool = False,
    ) -> NDArray[np.float64]:
        """Least-squares residual of the model ramp for each onset of ``grid`` (samples after
        boundary 0's sample, shape ``(C,)``) against ``excess`` at window indices ``n`` (shape
        ``(L,)`` each; ``start`` from :meth:`_window_start_phasors`).

        The model for one arrival of unit amplitude at onset ``o`` (window index): the boxcar
        of ``1`` after ``o`` and of the previous tone, ``e^{j(2π beat (i − o)/fs − jump)}``,
        before it; its mean power over the boundaries, scaled by least squares (with
        ``level``, beside a constant level: both less their means).
        """
        # The model's window sums (_ramp_shape with times_w) times 1/w instead of divided by
        # w: NumPy divides a complex by a real w as the product with 1/w, so every nonzero
        # part is the same bits (a zero may change sign, which |·| ignores). The kernel does
        # in one loop what NumPy's expressions would: each onset on each boundary and the
        # beat's phasor there, |shape|², its mean over the boundaries, the scale and the
        # residual (hil.estimation.first_arrival_kernels).
        out = np.empty(grid.size)
        ramp_residuals(
            grid, self._pre, ramp.frac, ramp.theta, ramp.jump, n, self.boxcar,
            ramp.geometric, start[0], 1.0 / self.boxcar, excess, level, out,
        )  # fmt: skip
        return out

    def _window_start_phasors(
        self, ramp: _RampTables, n: NDArray[np.int64]
    ) -> NDArray[np.complex128]:
        """``e^{jθa}`` of each boundary's beat at the first sample ``a = n − w + 1`` of the
        window ending at each index of ``n`` (shape ``(L,)``): shape ``(1, M, L)``."""
        start = np.empty((ramp.theta.size, n.size), dtype=np.complex128)
        window_start_phasors(ramp.theta, n, self.boxcar, start)
        return start[None, :, :]

    def _ramp_shape(
        self,
        grid: NDArray[np.float64],
        n: NDArray[np.int64],
        ramp: _RampTables,
        start: NDArray[np.complex128] | None = None,
        *,
        times_w: bool = False,
    ) -> NDArray[np.complex128]:
        """The next-tone channel of one arrival of unit amplitude switching at each onset of
        ``grid`` (samples after each boundary's predicted switch, shape ``(C,)``), at window
        indices ``n`` (shape ``(L,)``): shape ``(C, M, L)``, complex. ``start``: the
        boundaries' :meth:`_window_start_phasors` at ``n`` when already computed;
        ``times_w``: the window's sum, not yet divided by ``w``.

        At onset ``o`` (window index) the boxcar holds ``1`` for each sample after ``o`` and
        the previous tone, ``e^{j(2π beat (i − o)/fs − jump)}``, for each one before it; over
        the window's ``w`` samples, divided by ``w``.
        """
        w = self.boxcar
        theta = ramp.theta
        o = (self._pre + grid)[:, None, None] + ramp.frac[None, :, None]  # (C, M, 1)
        # Samples at or after o in each window, in integers (ceil(o) is a whole number).
        n_next = n[None, None, :] + (1 - np.ceil(o).astype(np.int64))
        np.maximum(n_next, 0, out=n_next)
        np.minimum(n_next, w, out=n_next)  # (C, M, L)
        # The geometric sums of the previous tone's w − n_next samples before o in the
        # window, from the table (flat index of row m, column w − n_next).
        row_ends = (np.arange(theta.size, dtype=np.int64) * (w + 1) + w)[None, :, None]
        sums = ramp.geometric.take(row_ends - n_next)  # (C, M, L)
        if start is None:
            start = self._window_start_phasors(ramp, n)
        at_o = np.exp(-1j * (theta[None, :, None] * o + ramp.jump[None, :, None]))  # (C, M, 1)
        # (n_next + start · at_o · sums) / w, each step into one buffer.
        shape = np.multiply(start, at_o)
        shape *= sums
        shape += n_next
        if not times_w:
            shape /= w
        return shape

    def _direct_alpha(
        self,
        p: NDArray[np.complexfloating],
        hops: HopTable,
        n_b: NDArray[np.int64],
        alpha: float,
        hop_index: int,
        delay_s: float,
        pattern: _TonePattern,
    ) -> float | None:
        """The direct path's time scale from its phase at the ``M`` boundaries, its score
        summed with the same echo's at the last detections (``pattern``: the tones'
        :class:`_TonePattern`).

        ``p`` (shape ``(M,)``) holds the first arrival's complex amplitude in the next-tone
        channel, demodulated at ``α f``, fitted over its first :data:`DIRECT_S` (before any
        image arrives) on the ramp's model (:meth:`_ramp_shape`). Once the known
        transmit phase of each hop (start phase ``φ_m`` at start time ``T_m``) is removed, its
        phase is ``θ_k + 2π f_m Δα t_m``: ``θ_k`` one unknown per tone (the delay, the copy of
        the canceller, the target's reflection), ``Δα`` what GCAS's time scale lacks. GCAS's
        comes from the whole hop, so every image weighs in, each at its path's own radial
        speed (the cosine of its elevation: 5 % slow in the built-in tank); this one is the
        direct path's. The score of a speed ``v`` (its ``Δα``) is
        ``Σ_k |Σ_{m: tone k} p_m e^{−j2π f_m Δα t_m}|²`` over the speeds on a fixed grid of
        :data:`DIRECT_SPEED_STEP` from :data:`DIRECT_SPAN_SLOWER` ``v_res`` slower than GCAS's
        speed to :data:`DIRECT_SPAN_FASTER` ``v_res`` faster
        (:func:`~hil.estimation.reverb_band.doppler_resolution_mps`; the boundaries are a hop
        apart, so the phase repeats every ``v_res``).

        With a few tones over ``M`` boundaries that score has sidelobes 0.3-0.6 m/s from its
        peak, as high as 0.4-0.9 of it once an image leaks into the first arrival. The next
        detection reads a different tone pattern, so its sidelobes fall elsewhere while the
        direct path's speed stays: the score (divided by its maximum) is summed with those of
        the same echo :data:`DOPPLER_LAGS` hops back (:meth:`_summed_score`) to choose the
        lobe; the peak on that lobe (refined by a parabola) is the speed, of the summed score
        where the direct path's speed has been steady (:meth:`_steady`), of the present score
        alone otherwise.
        None where no tone recurs or the peak is on the span's edge.
        """
        fs = self.fs_hz
        f = hops.freq_hz[::-1]
        start = hops.start_s[::-1]
        known = np.exp(-1j * (hops.phase_rad[::-1] - 2.0 * np.pi * f * start))
        q = p * known
        if not pattern.recurs:
            return None
        t_m = (n_b - n_b[-1]) / fs  # relative: a common shift is a per-tone phase
        c = self.sound_speed_mps
        sign = float(np.sign(alpha - 1.0))
        v_gcas = c * (alpha - 1.0) / (alpha + 1.0)
        # Speeds on a grid common to every detection (integer steps of DIRECT_SPEED_STEP),
        # slower and faster taken along the motion (an opening target's are negated).
        below = self._steps_slower
        above = self._steps_slower if sign == 0.0 else self._steps_faster
        lo, hi = (-below, above) if sign >= 0.0 else (-above, below)
        k0 = int(round(v_gcas / DIRECT_SPEED_STEP)) + lo
        speeds = (k0 + np.arange(hi - lo + 1)) * DIRECT_SPEED_STEP  # (G,) m/s
        d_alpha = (c + speeds) / (c - speeds) - alpha  # (G,)
        score = _doppler_score(d_alpha, f * t_m, q, pattern)
        own = DopplerScore(
            int(hop_index), float(delay_s), k0, score / max(score.max(), 1e-300), v_gcas
        )
        total = self._summed_score(own, v_gcas)
        self._scores.append(own)
        # The summed score chooses the lobe; the present one alone places the peak on it
        # unless the direct path's speed has been steady (a speed that changes over the lags
        # would move a summed peak).
        g = int(total.argmax())
        own_score = total if self._steady(hop_index, delay_s) else own.score
        while 0 < g < own_score.size - 1 and max(own_score[g - 1], own_score[g + 1]) > own_score[g]:
            g = g - 1 if own_score[g - 1] > own_score[g + 1] else g + 1
        if g in (0, d_alpha.size - 1):
            return None  # the peak is outside the span: keep GCAS's
        if sign * (speeds[g] - v_gcas) < -DIRECT_BELOW_GCAS_MPS:
            return None  # slower than every image: an ambiguity of the phase (see the bound)
        # Between grid speeds: the parabola through the peak and its neighbours.
        v = speeds[g] + DIRECT_SPEED_STEP * parabolic_offset(
            own_score[g - 1], own_score[g], own_score[g + 1]
        )
        return float((c + v) / (c - v))

    def _summed_score(self, own: DopplerScore, v_mps: float) -> NDArray[np.float64]:
        """``own.score`` plus the scores of the same echo :data:`DOPPLER_LAGS` hops back, on
        ``own``'s speeds (shape ``(G,)``).

        The same echo at the same speed: a detection one of :data:`DOPPLER_LAGS` hops back
        whose delay, moved on by the range the echo covers at ``v_mps`` (m/s, closing
        positive) in those hops, is within :data:`DOPPLER_GATE_S` of ``own``'s, and whose
        GCAS speed is within :data:`DOPPLER_SPEED_GATE_MPS` of ``own``'s. The scores kept are
        pruned to those hops."""
        hop_s = self._hop_s
        c = self.sound_speed_mps
        self._scores = [
            s for s in self._scores if 0 < own.hop_index - s.hop_index <= max(DOPPLER_LAGS)
        ]
        total = own.score.copy()
        n = own.score.size
        for s in self._scores:
            if own.hop_index - s.hop_index not in DOPPLER_LAGS:
                continue
            moved = 2.0 * v_mps * (own.hop_index - s.hop_index) * hop_s / c
            if abs(s.delay_s - moved - own.delay_s) > DOPPLER_GATE_S:
                continue
            if abs(own.v_gcas_mps - s.v_gcas_mps) > DOPPLER_SPEED_GATE_MPS:
                continue
            a = max(own.k0, s.k0)
            b = min(own.k0 + n, s.k0 + s.score.size)
            if a < b:
                total[a - own.k0 : b - own.k0] += s.score[a - s.k0 : b - s.k0]
        return total
