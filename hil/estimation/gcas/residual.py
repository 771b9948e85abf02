"""Successive cancellation: the input with the echoes measured lately taken out, searched
again by a second detector of the same design.

Why. GCAS's statistic is noncoherent: an echo's Doppler row stays high for about a hop on
either side of its boundary (a window ``τ`` off the boundary hears each term's tone for
``1 − τ/T_h`` of the hop and the next tone for the rest: ``(1 − τ/T_h)² + (τ/T_h)²`` of the
peak's power), and so do its ghosts' rows. A second echo in the same or a neighbouring
Doppler cell, or near the stronger one's ghost, is then no maximum of its own: 10 dB down
it is a tenth of the stronger echo's peak, on a slope several times steeper than its own.
The refinement (:mod:`hil.estimation.refine`) measures each echo's delay, time scale and
complex amplitude; written out at the input rate (:mod:`hil.estimation.echo_model`) and
taken out of the input, the measured echoes leave the others and the noise. Measured on
att (independent synthesis, M = 10, fits at most three hops old): the strong echo's power
falls by 27 dB at 0 dB per-sample SNR, by 19 dB at −10 dB.

Rules (:meth:`~hil.estimation.gcas.GcasReceiver.process`):

- The input is taken in stretches of :data:`STEP_HOPS` hops on a fixed grid of input
  samples. Once the first search has decided what a stretch brought, the echoes measured by
  then are written out over it and taken out, and the second search runs on what is left:
  the same stretches and the same fits whatever blocks the input comes in (chunks == whole).
- The second search runs while an echo has been measured within ``M + 1`` hops; with none
  it would search the first search's input again. It starts (again) when one is measured,
  on the ``M + 1`` hops of input before (the fits hold there too), so what the echo hid
  is found at once.
- Its detections are decided as the first search's, except that one where an echo measured
  lately puts its boundary is what is left of that echo (its estimate comes from the first
  search, or from following it) and is dropped unrefined
  (:meth:`~hil.estimation.refine.CoherentRefiner.continues_known`), and that none is taken
  for a measured echo's ghost unread (the ghosts went with their echoes).
- An echo it finds is measured, so it is taken out of the next stretches too: from then on
  it is followed where no detection brings it
  (:meth:`~hil.estimation.gcas.readout.Readout.decide_all`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from hil.estimation.baseband import ComplexBaseband
from hil.estimation.gcas.search import SearchStrategy
from hil.estimation.gcas.threshold import Peak

#: Length of the stretches the input is taken in, hops.
STEP_HOPS = 4.0


class ResidualSearch:
    """The second detector: its own baseband front end and search strategy (the first's
    design), fed the input less the measured echoes; ``hop_samples`` input samples per hop,
    ``m_hops`` the detector's ``M``."""

    def __init__(
        self, baseband: ComplexBaseband, strategy: SearchStrategy, m_hops: int,
        hop_samples: float,
    ) -> None:  # fmt: skip
        self.baseband, self.strategy = baseband, strategy
        #: Input samples per stretch (:data:`STEP_HOPS`).
        self.step = max(1, int(round(STEP_HOPS * hop_samples)))
        self._idle_limit = int(round((m_hops + 1) * hop_samples))
        #: Input samples before the stretch where it starts that it starts on: its ``M``
        #: hops and one for the front end to settle.
        self.lead = int(round((m_hops + 1) * hop_samples))
        self.reset()

    def reset(self) -> None:
        """Stop: nothing measured, nothing searched."""
        #: Whether the second search is running (an echo measured lately).
        self.running = False
        self._idle = 0

    def process(
        self, x: NDArray[np.float64], known: NDArray[np.float64] | None, first_index: int
    ) -> list[Peak]:
        """Search input samples ``x`` (shape ``(n,)``, the first at absolute index
        ``first_index``) less ``known``, what the measured echoes put there (shape ``(n,)``;
        None where none is measured lately); the peaks completed by them."""
        if known is None:
            if not self.running:
                return []
            self._idle += x.shape[0]
            if self._idle > self._idle_limit:
                self.reset()
                return []
            residual = x
        else:
            self._idle = 0
            if not self.running:
                self.baseband.reset(first_index)
                self.strategy.reset(self.baseband.next_output_index)
                self.running = True
            residual = x - known
        y = self.baseband.process(residual)
        return self.strategy.process(y) if y.shape[0] else []

    def flush(self) -> list[Peak]:
        """End of input: the candidates still waiting for their look-ahead."""
        return self.strategy.flush() if self.running else []

    def next_decision_index(self, samples_seen: int) -> int | None:
        """As :meth:`SearchStrategy.next_decision_index`; None where it is not running (it
        starts only after the first search has measured an echo, and then has ``M`` hops to
        fill)."""
        if not self.running:
            return None
        return self.strategy.next_decision_index(samples_seen)
