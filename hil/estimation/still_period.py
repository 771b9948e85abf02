"""Where the still water repeats: the still period of a transmit, and its sign.

A still return (the direct blast, a wall, volume reverberation at rest) is the transmit
delayed and scaled, so it repeats as the transmit does. A code period ``P`` (samples) of an
HFC-CW schedule repeats the hops' frequencies, but not necessarily their phase: each hop
carries the phase its tone reached at the end of the one before, and over one period the
phase advances by ``Φ`` (:attr:`~hil.signals.schedule.HopSchedule.period_phase_rad`). Where
``Φ`` is 0 the still water repeats every period; where it is π it repeats with the opposite
sign (``att`` and ``tank-board``: each hop holds a whole number of cycles and a half, 8.5
cycles over 17 hops), and ``x[n] − x[n − P]`` doubles it instead of cancelling it.

So every stage that takes the still water out (the one-period canceller of ``gcas-mti`` and of
the first-arrival readout, the empty-tank background of ``gcas-bg`` and its capture, the
running background of ``gcas-still``) works on the **still period** ``Q = L·P`` (the fewest
``L`` whose phase advance ``L·Φ`` is 0 or π) and its **sign** ``σ``: the still water at ``n``
is ``σ`` times that at ``n − Q``.
"""

from __future__ import annotations

import math

from hil.errors import ConfigError
from hil.signals.schedule import HopSchedule

#: The most code periods a still period may span.
MAX_CODE_PERIODS = 16
#: How close to 0 or π (rad) the phase advance of a still period must be.
PHASE_TOLERANCE_RAD = 1e-6


def still_period(schedule: HopSchedule, period_samples: int) -> tuple[int, int]:
    """The still period ``Q`` (samples) and its sign ``σ`` of a transmit whose code period is
    ``period_samples``: ``Q = L·P`` for the fewest ``L`` (1 .. :data:`MAX_CODE_PERIODS`) whose
    phase advance ``L·Φ`` is 0 (σ = +1) or π (σ = −1) to :data:`PHASE_TOLERANCE_RAD`.

    >>> from hil.signals.schedule import HopSchedule
    >>> still_period(HopSchedule.from_segments("d", [1000.0, 2000.0], [0, 1], 0.001), 20)
    (20, 1)
    >>> still_period(HopSchedule.from_segments("d", [1000.0, 1500.0], [0, 1], 0.001), 20)
    (20, -1)
    >>> still_period(HopSchedule.from_segments("d", [1000.0, 1250.0], [0, 1], 0.001), 20)
    (40, -1)
    """
    phi = float(schedule.period_phase_rad)
    for periods in range(1, MAX_CODE_PERIODS + 1):
        turn = math.remainder(periods * phi, 2.0 * math.pi)  # in [−π, π]
        if abs(turn) <= PHASE_TOLERANCE_RAD:
            return periods * int(period_samples), 1
        if math.pi - abs(turn) <= PHASE_TOLERANCE_RAD:
            return periods * int(period_samples), -1
    raise ConfigError(
        "waveform",
        f"period_phase_rad = {phi!r}",
        f"a transmit whose phase advance per code period, times 1 .. {MAX_CODE_PERIODS}, is "
        "0 or π (the still water then repeats, up to its sign)",
        "a still-water stage (period canceller, background, gcas-still) cannot follow it: "
        "use gcas (its reverberation band)",
    )


def checked_still_period(period_samples: int, sign: int) -> tuple[int, int]:
    """``(period_samples, sign)`` as ints, refused unless a whole number of samples ``>= 1``
    and a sign of ``+1`` or ``-1`` (what every still-water stage is built from).

    >>> checked_still_period(17000, -1)
    (17000, -1)
    """
    if isinstance(period_samples, bool) or int(period_samples) != period_samples:
        raise ConfigError("period_samples", period_samples, "an integer number of samples")
    if period_samples < 1:
        raise ConfigError("period_samples", period_samples, ">= 1 sample")
    if isinstance(sign, bool) or sign not in (1, -1):
        raise ConfigError("sign", sign, "+1 or -1 (the still water's sign per period)")
    return int(period_samples), int(sign)
