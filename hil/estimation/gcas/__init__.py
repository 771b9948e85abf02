"""GCAS: group correlators and accumulated sum, streaming (SPEC §3).

Pipeline per input block (every stage carries its state; any chunking of the input gives the
same estimates as one call on the whole signal):

1. :class:`~hil.estimation.baseband.ComplexBaseband`: mix by ``f_c`` (absolute sample index),
   linear-phase FIR low-pass, decimate by ``R`` to ``fs_bb``; the group delay is compensated in
   every reported time.
2. :class:`~hil.estimation.unit_correlators.UnitCorrelatorBank`: ``u[n, d, k]`` for the
   ``D`` Doppler hypotheses of :func:`~hil.estimation.doppler_grid.doppler_grid` (uniform in
   speed over ±max_speed) and the ``K`` tones, ``ν[d, k] = α_d f_k − f_c``, window
   ``N_d = round(T_h fs_bb/α_d)``; ``U = |u|²``.
3. Group correlators ``G_d = Σ_k U[:, d, k]``, accumulated over ``M`` hops by the comb
   recursion ``Acc_d[n] = Acc_d[n − N_d] + G_d[n] − G_d[n − M N_d]`` (cost independent of
   ``M``). Per sample, ``d̂[n] = argmax_d w_d Acc_d[n]`` (``w_d``: reverberation-band weights).
4. Accumulated sums at ``d̂`` and its two neighbours, for every codeword ``j`` of the period::

       A[n, d, j] = Σ_{m<M} U[n − ℓ_{d,m}, d, c_{j−m}]                  (noncoherent)
       A[n, d, j] = |Σ_{m<M} u[n − ℓ_{d,m}, d, c_{j−m}] e^{−jθ_{j,m}(n)}|²   (coherent)

   with lags ``ℓ_{d,m} = round(m L_d)``, ``L_d = T_h fs_bb/α_d`` [R: the spec writes
   ``m N_d``; rounding each lag separately keeps the M terms aligned within half a sample
   instead of letting the rounding of ``N_d`` accumulate to ``m/2`` samples]. The coherent
   phase (derived in :meth:`~hil.estimation.gcas.readout.Readout._coherent_refine`,
   verified on noiseless echoes to < 0.01 rad by
   ``test_coherent_phase_model_matches_the_unit_correlators``): the unit correlator
   covering echo hop ``i`` (tone ``f``, start ``t_i``, start phase ``φ_i``) of
   ``s(α(t − τ0))`` has phase ``φ_i − 2π f (α τ0 + t_i) − 2π ν_d g + 2π (α − α_d) f c_i``
   (``g`` the filter delay, ``c_i`` the centre of the received hop); ``θ_{j,m}(n)`` below is
   its value at ``α = α_d`` and the integer-sample boundary of ``n`` (map diagnostics only).
   [R] With ``coherent=True`` detection, codeword and coarse time still come from the
   noncoherent sums (whose noise moments set the threshold); the coherent sum then refines
   each detection's boundary time and α on a fine grid of candidate ``(τ0, α)`` (±½ grating
   lobe ``1/(α Δf)``, ±1 Doppler step): at integer samples alone its ``1/B_w`` fine structure
   and the Doppler mismatch ``α − α_d`` (a phase ramp of ``2π f (α − α_d) m T_h`` over the
   terms) would pick neighbouring lobes.
5. The time–codeword map ``P[n, j] = A[n, d̂, j]`` (computed for every sample only when
   ``on_map`` is given: it costs ``J·M·K`` per sample and grows with ``M``).
6. Detection [R] (:mod:`hil.estimation.gcas.threshold`, :mod:`hil.estimation.detection`), in
   two steps so that the cost per sample does not depend on ``M``: candidates are the local
   maxima over ``±N_min/2`` of the group statistic ``g[n] = max_d w_d Acc_d[n]``; at each
   candidate the exact sums ``A`` are evaluated for ``n`` within ``±W``
   (``W = ⌈(M − 1)/4⌉ + 2``: the comb's integer lag puts its peak up to ``(M − 1)/4`` samples
   from the exact one) at ``d̂`` and its neighbours; ``s = max_j A[n, d̂, j]`` at its best
   ``n`` must exceed ``μ̂ + λσ̂`` (CFAR mode ``"bank"`` or ``"statistic"``) and the best
   codeword ``ρ`` times the runner-up. ``λ`` is set directly or from ``pfa`` per update.
   Reverberation band [R]: with ``reverb_speed_mps > 0`` every unit-correlator cell
   ``(d, k)`` whose frequency ``α_d f_k`` lies within ``[α(−v_r), α(v_r)]·f_k'`` (± half a
   main lobe) for ANY tone ``k'`` gets ``reverb_weight`` in ``G`` and in ``A``: a stationary
   echo of tone ``k'`` would otherwise appear as tone ``k`` at the ghost speed where
   ``α_d f_k = f_k'``.
7. Readout: parabolic interpolation of the peak in time and across ``d``; boundary receive time
   ``t_rx`` (window centred on the hop, group delay removed); ``ĵ = argmax_j``; ``t_tx`` the
   transmit end of hop ``ĵ`` plus the multiple of the code period that puts the delay in
   ``[0, τ_max]``, ``τ_max = 2 max_range/c`` (otherwise the detection is refused and counted);
   ``R = c (t_rx − t_tx)/2``, ``v = c (α̂ − 1)/(α̂ + 1)``; hop-index consistency is a soft
   flag (:attr:`GcasReceiver.last_detection`, :attr:`GcasReceiver.inconsistent_count`).

Searches (:mod:`hil.estimation.gcas.search`, one strategy object per receiver). Steps 2–6
above are the ``search="full"`` form (:mod:`~hil.estimation.gcas.search_full`): every unit
correlator at every baseband sample, the reference. The default ``search="two-stage"`` [R]
(:mod:`~hil.estimation.gcas.search_two_stage`) finds the same boundaries at a fraction of the
cost: coarse block correlators give the candidates and the hypothesis, exact codeword sums
are evaluated only around each candidate. Thresholds and readout are shared.

Modules: :mod:`~hil.estimation.gcas.options` (allowed values, validation),
:mod:`~hil.estimation.gcas.front_end` (baseband, Doppler hypotheses, reverberation band),
:mod:`~hil.estimation.gcas.sums` (the accumulated sums ``A``),
:mod:`~hil.estimation.gcas.threshold` (CFAR and runner-up tests),
:mod:`~hil.estimation.gcas.readout` (peak to estimate),
:mod:`~hil.estimation.gcas.hidden_echoes` (echoes the reverberation band hides, measured
where what they leak is near), the two searches behind
:mod:`~hil.estimation.gcas.search`, and :mod:`~hil.estimation.gcas.receiver` (the streaming
receiver that holds them).

Latency: a boundary is reported once ``N_min/2`` baseband samples past it have arrived (plus
the filter delay), within one hop.
"""

from hil.estimation.gcas.exact import NO_SAMPLE
from hil.estimation.gcas.receiver import GcasReceiver

__all__ = ["NO_SAMPLE", "GcasReceiver"]
