"""A one-code-period clutter canceller in front of GCAS: the tank's still returns removed
before detection (receiver ``"gcas-mti"``).

In a tank the loudest returns do not move: the walls, the surface and bottom around the
transducer, the late reverberant tail, the direct blast. With a continuous transmission that
repeats every code period ``P`` (samples, an integer), every time-invariant return repeats
too, so

    y[n] = x[n] − x[n − P]

removes them all (a moving-target indicator). GCAS then detects on ``y``. A moving echo does
not cancel: it leaves itself and, one period later in range (``P · v`` farther for a closing
target), a sign-flipped copy of itself. GCAS's first-arrival readout
(:mod:`hil.estimation.first_arrival`) times the earliest arrival, which for a closing target
is the echo itself; its own canceller then sees ``y − y(t − P)``, the same echo first.

The first period after the start, and after every gap, has no period to cancel with: the
canceller outputs zeros there (no detection, rather than detections of the walls), and GCAS
restarts its accumulation after them as after a gap. A target at rest cancels with the
clutter. The noise power doubles (+3 dB).

:class:`ClutterCancelledGcas` is a :class:`~hil.estimation.gcas.GcasReceiver` with the
canceller in front (:class:`~hil.estimation.input_stage.StagedGcas`); it takes GCAS's options
and delegates everything else to it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.estimation.first_arrival import FirstArrivalReadout
from hil.estimation.input_stage import StagedGcas, StageParts, StageSetting
from hil.estimation.still_period import checked_still_period, still_period


class PeriodCanceller:
    """``y[n] = x[n] − σ x[n − P]`` on a stream, with zeros for the ``P`` samples after the
    start and after each gap (shape ``(n,)`` in and out; any chunking gives the same output).
    ``P`` and ``σ`` are the transmit's still period and its sign
    (:func:`~hil.estimation.still_period.still_period`: the still water at ``n`` is ``σ``
    times that at ``n − P``).

    >>> c = PeriodCanceller(3)
    >>> c.process(np.array([1.0, 2, 3, 1, 2, 4])).tolist()
    [0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    >>> c.process(np.array([5.0]), gap_before=2).tolist()
    [0.0]
    >>> PeriodCanceller(2, sign=-1).process(np.array([1.0, 2, -1, -2, 1, 3])).tolist()
    [0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    """

    def __init__(self, period_samples: int, sign: int = 1) -> None:
        #: The still period (samples) and the still water's sign from one period to the next.
        self.period, self.sign = checked_still_period(period_samples, sign)
        # The last P input samples as a ring: sample n sits at n mod P.
        self._ring = np.zeros(self.period)
        self._pos = 0  # ring slot of the next sample
        self._valid = 0  # how many held samples are real (not before the start or a gap)

    def reset(self) -> None:
        """Forget the history: the next ``P`` outputs are zeros."""
        self._ring[:] = 0.0
        self._valid = 0

    def process(
        self, block: ArrayLike, *, first_index: int = 0, gap_before: int = 0
    ) -> NDArray[np.float64]:
        """The cancelled samples of ``block`` (``gap_before`` samples went missing before
        it: the history restarts). ``first_index`` (the absolute index of ``block[0]``) is
        not needed: the ring keeps its own phase, so the output depends only on the order
        of the samples and the gaps."""
        x = np.asarray(block, dtype=np.float64).reshape(-1)
        if gap_before:
            self.reset()
        p = self.period
        y = np.empty_like(x)
        done = 0
        while done < x.size:  # at most ceil(n / P) + 1 slices: no per-sample loop
            take = min(x.size - done, p - self._pos)
            now = x[done : done + take]
            before = self._ring[self._pos : self._pos + take]  # a view: P samples earlier
            if self.sign > 0:
                np.subtract(now, before, out=y[done : done + take])
            else:
                np.add(now, before, out=y[done : done + take])
            before[:] = now
            self._pos = (self._pos + take) % p
            done += take
        # Outputs whose sample one period earlier is not real input are blanked.
        blank = max(0, min(x.size, p - self._valid))
        y[:blank] = 0.0
        self._valid = min(p, self._valid + x.size)
        return y


class ClutterCancelledGcas(StagedGcas):
    """GCAS behind a :class:`PeriodCanceller` of the schedule's code period (see the module
    docstring). Options: GCAS's (``range_readout``, ``reverb_speed_mps``, ...); ``refine``
    is False unless given (the canceller leaves two copies of a moving echo)."""

    name = "gcas-mti"
    period_reason = "the canceller subtracts the period before"

    def __init__(
        self, inner: Any, stage: PeriodCanceller, readout: FirstArrivalReadout | None = None
    ) -> None:
        super().__init__(inner, stage, readout)
        #: The canceller in front of GCAS.
        self.canceller = stage

    @classmethod
    def stage_from_options(cls, where: StageSetting, options: dict[str, Any]) -> StageParts:
        """The canceller of the still period (one code period, or its sign-flipped copy:
        :func:`~hil.estimation.still_period.still_period`); every option is GCAS's. GCAS's
        first-arrival readout (``range_readout``) runs its own canceller on the cancelled
        stream."""
        period, sign = still_period(where.schedule, where.period_samples)
        return StageParts(PeriodCanceller(period, sign), None, options)
