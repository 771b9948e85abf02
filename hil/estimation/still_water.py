"""GCAS on the input less an adaptive background of the still water (receiver
``"gcas-still"``), for a sonar at rest: a tank, a pier, a mooring.

With a continuous transmission repeating every code period ``P`` (samples, an integer), every
return that does not move repeats too: walls, moorings, the bottom, the volume reverberation
of still scatterers. It repeats *up to the transmit's phase advance per period* ``Φ``
(``HopSchedule.period_phase_rad``): continuous-phase tones start each period ``Φ`` further
on, so the still water of one period is the last one's turned by ``Φ``. On ``att`` every hop
holds a whole number of cycles and a half (283.5–316.5), so ``Φ = π``: the still water
*changes sign* every period, and ``x[n] − x[n − P]`` doubles it. The stage therefore works on
the **still period** ``Q = L·P`` (:func:`~hil.estimation.still_period.still_period`), the
fewest whole code periods after which the phase advance is 0 or π, and its sign ``σ = ±1``
(``att``: ``Q = P``, ``σ = −1``), and learns the still part as it goes, with no
empty-water capture (which ``"gcas-bg"``, :mod:`hil.estimation.background`, needs)::

    m           = n div Q                     (the still period of sample n)
    b_before[n] = mean of σ^(m − j) x[n − jQ], j = 1 .. K   (the last K values at n mod Q)
    y[n]        = x[n] − σ^m b_before[n]

from EARLIER periods only, so an echo is never subtracted from itself. ``K`` is the option
``still_periods`` (default :data:`DEFAULT_STILL_PERIODS`). GCAS then runs on ``y`` as
``"gcas"`` does: refinement on, the reverberation band as GCAS sets it.

**A block mean of the last K periods**, not an exponential one: its memory is exactly K
periods, so a scatterer that appears (or a target that stops) is absorbed in K periods and one
that leaves is forgotten in K, where an exponential mean of time constant K periods still
holds 37 % of either after K periods (and 5 % after 3K); and its noise penalty is the simplest
to state. It holds K still periods (K·Q samples, 1.1 MB at K = 8 on ``att``). Until a phase's
mean holds :data:`WARMUP_PERIODS` periods (fewer where K is) nothing is subtracted there and
the input passes: GCAS's band then handles the still water as in ``"gcas"``. After that the
mean is over the periods held, up to K.

What the stage does (``att``: Q = P = 0.17 s, σ = −1, tones 28.35–31.65 kHz, c = 1500 m/s;
measured by ``tests/estimation_gcas/test_still_water.py``):

- **Still returns** are removed to numerical precision once the warm-up is held (a target at
  rest on ``att``: −207 dB; the simulator's volume reverberation of a sonar at rest: −83 to
  −97 dB, its float32 transmit).
- **Noise** is ``x``'s plus the mean of K independent values: power ``× (1 + 1/K)`` (1.1249 at
  K = 8 measured, +0.51 dB). While the mean holds j < K periods: ``× (1 + 1/j)``, +0.97 dB at
  the warm-up's j = 4.
- **A moving echo** moves ``2vQ/c`` of delay per period (1.36 ms at 6 m/s), turning its phase
  at 30 kHz by 41 cycles: the K values of it in the mean add with phases turned by that much
  each, so the mean holds on average (over speeds) ``1/K`` of its power, ``1/√K`` of its
  amplitude: measured 0.035, 0.042 and 0.130 of its power at 6, 10 and 25 m/s (K = 8). The
  echo itself passes whole (its projection on itself 1.00–1.07). What the mean holds is K
  sign-flipped **copies** of ``1/K`` (18 dB down at K = 8; 12 dB at the warm-up's 4) at the
  target's ranges and speeds of the last K periods (``vQ`` apart: 1.0 m at 6 m/s), which GCAS
  can fit like any echo: :mod:`hil.estimation.still_copies` drops the estimates that are such
  copies of estimates reported before.
- **A target slower than** about ``c / (2 Q f K)`` (0.018 m/s at K = 8) keeps its phase over
  the K periods and is partly absorbed and reshaped (at 0.01 m/s: +2.4 dB, at 0.05 m/s
  +0.8 dB of its power is left): it is inside GCAS's reverberation band, which reports
  nothing there anyway. A drifting scatterer is the same: cancelled only well below that
  speed, above it left to the band.
- **A target that stops** is absorbed after K periods (1.36 s at K = 8) and then gives no
  estimate; one that starts moving from rest leaves its resting echo in the mean for K
  periods, a sign-flipped still echo, which the band holds.
- **A gap** (``gap_before``): the phase continues (the absolute index keeps counting), the
  missing samples are not entered, and the mean stays that of the last K values received at
  each phase: the still water is as still after a dropped buffer. A moved sonar is not a gap:
  :meth:`StillWaterBackground.reset` forgets it.
- **A moving sonar's reverberation is not still**: its scatterers' delays change every period,
  as a moving target's do. The stage is for a sonar at rest (a tank, a pier, a mooring).
- **Cost**: 0.002 CPU s per second of input (K = 8; GCAS itself about 1 s).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.estimation.first_arrival import FirstArrivalReadout
from hil.estimation.input_stage import StagedGcas, StageParts, StageSetting
from hil.estimation.still_copies import CopyVeto
from hil.estimation.still_period import checked_still_period, still_period

#: ``still_periods`` unless given: 8 periods (1.36 s on ``att``) keep the noise penalty at
#: +0.51 dB and a moving echo's copies 18 dB down, and absorb a stopped target in 1.36 s.
DEFAULT_STILL_PERIODS = 8
#: Periods the mean must hold before it is subtracted (fewer where K is smaller): a moving
#: echo's copies in a mean of j periods are 1/j of it (0, −6, −9.5 dB at j = 1 .. 3), and
#: ``second-10db-weaker`` in reverberation (0 dB) subtracting from j = 1 on gave 87–118 false
#: estimates per 2 s trial (4 seeds), 59–97 of them in the periods 1–4; from j = 4 on 10–22
#: (before :mod:`hil.estimation.still_copies`).
WARMUP_PERIODS = 4
#: The most code periods a still period may hold, and the tolerance (rad) on its phase turn.
#: The largest ``still_periods`` (the stage holds K code periods of samples).
MAX_STILL_PERIODS = 64


def check_still_periods(value: Any) -> int:
    """``still_periods`` as an int, refused unless a whole number in 1 .. 64."""
    ok = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
    if not ok or not 1 <= int(value) <= MAX_STILL_PERIODS:
        raise ConfigError(
            "still_periods",
            value,
            f"a whole number of code periods in 1 .. {MAX_STILL_PERIODS}",
            f"e.g. still_periods={DEFAULT_STILL_PERIODS} (more: less noise and leak, slower "
            "to learn a new still return)",
        )
    return int(value)


class StillWaterBackground:
    """``y[n] = x[n] − σ^m · mean(the last K values at phase n mod Q, each times σ^(its m))``
    on a stream (``m = n div Q``; shape ``(n,)`` in and out, input units; module docstring).

    Works per still period: a block is cut at the period's edges and each piece is one
    vector operation over its phases, so any chunking gives the same output bit for bit.
    ``warmup`` (periods) is :data:`WARMUP_PERIODS` unless given (at most K).

    >>> s = StillWaterBackground(3, 2, warmup=1)
    >>> s.process(np.array([1.0, 2, 3, 3, 2, 1, 2, 2, 2]), first_index=0).tolist()
    [1.0, 2.0, 3.0, 2.0, 0.0, -2.0, 0.0, 0.0, 0.0]
    >>> s = StillWaterBackground(2, 2, sign=-1, warmup=1)  # the still water flips each period
    >>> s.process(np.array([1.0, 2, -1, -2, 1, 2, -1, -3]), first_index=0).tolist()
    [1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]
    """

    def __init__(
        self,
        period_samples: int,
        still_periods: int = DEFAULT_STILL_PERIODS,
        *,
        sign: int = 1,
        warmup: int | None = None,
    ) -> None:
        #: Still period Q (samples), its sign σ and the periods averaged K.
        self.period, self.sign = checked_still_period(period_samples, sign)
        self.still_periods = check_still_periods(still_periods)
        #: Periods a phase's mean must hold before it is subtracted (module docstring).
        wanted = WARMUP_PERIODS if warmup is None else max(1, int(warmup))
        self.warmup = min(self.still_periods, wanted)
        # The last K values received at each phase, shape (K, P): slot _slot[k] of column k
        # is written next; unfilled slots hold 0.0 so the column sum is the sum received.
        self._ring = np.zeros((self.still_periods, self.period))
        self._slot = np.zeros(self.period, dtype=np.int64)
        self._count = np.zeros(self.period, dtype=np.int64)

    def reset(self) -> None:
        """Forget the background: the next period passes unchanged."""
        self._ring[:] = 0.0
        self._slot[:] = 0
        self._count[:] = 0

    @property
    def background(self) -> NDArray[np.float64]:
        """The background the next period is less (shape ``(P,)``: the mean at each phase;
        0 where nothing was received)."""
        return self._mean(0, self.period)

    @property
    def periods_held(self) -> NDArray[np.int64]:
        """How many values each phase's mean is over (shape ``(P,)``, 0 .. K)."""
        return self._count.copy()

    def _mean(self, k0: int, k1: int) -> NDArray[np.float64]:
        """The mean held at phases ``k0 .. k1 − 1``, its slots summed in slot order (the
        same order whatever the chunking)."""
        total = self._ring[0, k0:k1].copy()
        for row in self._ring[1:, k0:k1]:
            total += row
        count = self._count[k0:k1]
        return np.divide(total, count, out=np.zeros_like(total), where=count >= self.warmup)

    def process(
        self, block: ArrayLike, *, first_index: int = 0, gap_before: int = 0
    ) -> NDArray[np.float64]:
        """``block`` (shape ``(n,)``, its first sample at absolute input index
        ``first_index``) less the background of the periods before each sample; then its
        samples enter the background. ``gap_before`` changes nothing here: the phase comes
        from ``first_index``, which counts the missing samples, and the missing samples are
        simply not entered (module docstring)."""
        x = np.asarray(block, dtype=np.float64).reshape(-1)
        p, k_max = self.period, self.still_periods
        y = np.empty_like(x)
        done = 0
        index = int(first_index)
        while done < x.size:  # one piece per still period: ceil(n / Q) + 1 at most
            m, phase = divmod(index + done, p)
            take = min(x.size - done, p - phase)
            now = x[done : done + take]
            # σ^m is ±1: multiplying by it is exact, so the sums do not depend on chunking.
            sign = -1.0 if self.sign < 0 and m % 2 else 1.0
            cols = slice(phase, phase + take)
            np.subtract(now, sign * self._mean(phase, phase + take), out=y[done : done + take])
            slots = self._slot[cols]
            self._ring[slots, np.arange(phase, phase + take)] = sign * now
            self._slot[cols] = (slots + 1) % k_max
            self._count[cols] = np.minimum(self._count[cols] + 1, k_max)
            done += take
        return y


class StillWaterGcas(StagedGcas):
    """GCAS behind a :class:`StillWaterBackground` of the schedule's code period (module
    docstring). Options: ``still_periods`` (K, default :data:`DEFAULT_STILL_PERIODS`) and
    GCAS's (``reverb_speed_mps``, ``refine`` (on unless given), ...)."""

    name = "gcas-still"
    STAGE_OPTIONS = ("still_periods",)
    period_reason = "the still water repeats every period"
    refine_default = True

    def __init__(
        self,
        inner: Any,
        stage: StillWaterBackground,
        readout: FirstArrivalReadout | None = None,
    ) -> None:
        super().__init__(inner, stage, readout)
        #: The still-water background in front of GCAS.
        self.still_water = stage
        hop_samples = round(float(inner.hop_s) * self.fs_hz)
        #: The filter of the copies the background leaves (:mod:`hil.estimation.still_copies`).
        self.copies = CopyVeto(
            stage.period // hop_samples, stage.period / self.fs_hz, stage.still_periods,
            stage.warmup, int(inner.m_hops),
        )  # fmt: skip

    def process(self, block: ArrayLike, *, gap_before: int = 0) -> list[Estimate]:
        """GCAS's estimates on the input less the still water, less the background's copies
        of earlier echoes (shape ``(n,)`` real samples; ``gap_before`` samples went missing
        before the block)."""
        return self.copies.filter(super().process(block, gap_before=gap_before))

    def flush(self) -> list[Estimate]:
        """GCAS's held estimates, less the copies."""
        return self.copies.filter(super().flush())

    def reset(self) -> None:
        """Forget all state (background, GCAS, the copies' history)."""
        super().reset()
        self.copies.reset()

    @property
    def copies_dropped(self) -> int:
        """Estimates dropped as copies of earlier ones (:mod:`hil.estimation.still_copies`)."""
        return self.copies.dropped

    @classmethod
    def stage_from_options(cls, where: StageSetting, options: dict[str, Any]) -> StageParts:
        """The background of ``still_periods`` periods; every other option is GCAS's
        (GCAS reads its own range: the stage leaves one echo, not a tank's images)."""
        k = check_still_periods(options.pop("still_periods", DEFAULT_STILL_PERIODS))
        q, sign = still_period(where.schedule, where.period_samples)
        return StageParts(StillWaterBackground(q, k, sign=sign), None, options)
