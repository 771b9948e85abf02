"""The input with the still water taken out, for judging a fit's grating lobe beside it.

Still water (volume reverberation at rest, a wall, the direct blast) repeats with the still
period ``Q`` (samples) and its sign ``σ`` (:mod:`hil.estimation.still_period`). The one-period
canceller ``y[n] = x[n] − σ x[n − Q]`` takes it out exactly and leaves a moving echo as the
echo less its own copy a still period earlier: for an echo ``β s(α (t − t_rx) + T_b)`` of a
schedule ``s`` with ``s(u − T_Q) = σ s(u)`` (``T_Q = Q/f_s``),

    y(t) = β [s(α (t − t_rx) + T_b) − s(α (t − t_rx') + T_b)],  t_rx' = t_rx + T_Q (1 − 1/α),

the same echo model at a second receive time (``σ² = 1``). So the correlation of ``y`` with
that two-term model is ``C_y(t_rx, α) − C_y(t_rx', α)``, two evaluations of the refinement's
own correlation (:meth:`hil.estimation.refine.CoherentRefiner.correlation`) on ``y``: the
copy is modelled, so it never reads as a ghost. ``C_y`` takes each term over its full ``M``
hops; the copy over the window's own samples differs from that by the hops' edges moved by
``T_Q (1 − 1/α)`` (1.4 ms of a 100 ms window at 6 m/s on ``att``), the same at every
grating lobe.

Why a lobe decision on ``y`` and not a fit on ``y``: in open water ``y`` doubles the noise
and blinds some tones (``|1 − e^{j2π f (α − 1) T_Q}|``), so the refinement's fit on ``x``
keeps its Cramér–Rao accuracy within a lobe; what the still water spoils is only which lobe,
as it sits at the transmitted tones, above a weak echo, and leaks coherently into its fit
through the lobes' edges (att, a target 10 dB below another at 0 dB per-sample SNR in volume
reverberation at 0 dB SRR: runs of fits one or two lobes off at an E/N0 of 23-24 dB, above
the white-noise lobe threshold). The still part's share of a window is measured from
``w[n] = x[n] + σ x[n − Q]``: with still power ``S`` and the rest (noise, moving echoes) ``N``
per sample, ``E|w|² = 4S + 2N`` and ``E|y|² = 2N`` (:meth:`StillStreams.powers`;
``w² − y² = 4σ x[n] x[n − Q]``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from hil.estimation.row_buffer import RowBuffer
from hil.estimation.still_period import checked_still_period


class StillStreams:
    """The canceller's output ``y = x − σ x[n − Q]`` of a stream, made on demand from the
    input kept ``keep + Q`` samples back (the lobe decision reads it only where a fit beside
    still water is judged), and the running sums of ``x[n] x[n − Q]`` and ``y[n]²`` that give
    the still and the rest's powers over any span kept (:meth:`powers`, read at every fit).

    Parameters
    ----------
    period_samples:
        The still period ``Q``, samples (:func:`~hil.estimation.still_period.still_period`).
    sign:
        Its sign ``σ`` (+1 or −1).
    keep:
        Samples of ``y`` and of the sums readable behind the newest one.
    """

    def __init__(self, period_samples: int, sign: int, keep: int) -> None:
        self.period, self.sign = checked_still_period(period_samples, sign)
        self.keep = int(keep)
        self._x = RowBuffer(self.keep + self.period, (), np.float64)
        # Row n: Σ x[k] x[k − Q] and Σ y[k]² over k = reset .. n (zeros before the reset).
        self._sums = RowBuffer(self.keep + 1, (2,), np.float64)
        #: The first sample whose ``y`` has a sample a still period before it.
        self.valid_from = self.period

    @property
    def next_index(self) -> int:
        """Absolute index of the next input sample."""
        return self._x.next_index

    def reset(self, next_index: int) -> None:
        """Forget the history; the next sample is ``next_index``."""
        self._x.reset(next_index)
        self._sums.reset(next_index)
        self.valid_from = int(next_index) + self.period

    def push(self, x: NDArray[np.float64], first_index: int) -> None:
        """Append input samples ``x`` (shape ``(n,)``) from absolute index ``first_index``."""
        n = x.shape[0]
        ring, q = self._x, self.period
        ring.append(x, first_index)
        # The ring keeps keep + Q samples before the chunk, so x[n − Q] of all of it is there.
        before = ring.span(first_index - q, first_index - q + n)
        terms = np.empty((n + 1, 2))
        terms[0] = self._sums.span(first_index - 1, first_index)[0]
        terms[1:, 0] = x * before
        y = x - self.sign * before
        terms[1:, 1] = y * y
        # One cumulative sum from the last row on: the rows are the whole stream's sums, bit
        # for bit, however it is cut into chunks.
        self._sums.append(np.cumsum(terms, axis=0)[1:], first_index)

    def _kept(self, first: int, stop: int) -> bool:
        """Whether samples ``first .. stop − 1`` and those a still period before them are
        kept (before :attr:`valid_from` and after a reset, the latter read as 0)."""
        ring = self._x
        return ring.next_index - ring.available <= first - self.period and stop <= ring.next_index

    def canceller(self, first: int, stop: int) -> NDArray[np.float64]:
        """``y`` over samples ``first .. stop − 1`` (shape ``(stop − first,)``, a new array;
        before :attr:`valid_from` the missing samples count as 0). Raises ``IndexError``
        where they are not kept (at least ``keep`` behind the newest are) or not pushed."""
        if not self._kept(first, stop):
            ring = self._x
            raise IndexError(
                f"samples {first}..{stop - 1} of y: kept are "
                f"{ring.next_index - ring.available + self.period}..{ring.next_index - 1}"
                f" (at least the last {self.keep})"
            )
        x, q = self._x, self.period
        y: NDArray[np.float64] = x.span(first, stop) - self.sign * x.span(first - q, stop - q)
        return y

    def powers(self, first: int, stop: int) -> tuple[float, float]:
        """The still water's power ``S`` and the rest's ``N`` (noise and moving echoes), per
        sample over samples ``first .. stop − 1`` (input units squared):
        ``S = (Σw² − Σy²) / (4n) = σ Σ x[n] x[n − Q] / n`` (``w = x + σ x[n − Q]``, the
        still sum), ``N = Σy² / (2n)`` (module docstring), each the difference of two running
        sums (their rounding: about 1e-16 of the sums since the last reset); ``(0, 0)`` where
        the span is not all valid and kept."""
        n, sums = stop - first, self._sums
        origin = sums.next_index - sums.available
        if n <= 0 or first < self.valid_from or first - 1 < origin or stop > sums.next_index:
            return 0.0, 0.0
        run = sums.array
        s_sum, y_sum = (run[stop - 1 - origin] - run[first - 1 - origin]).tolist()
        return self.sign * s_sum / n, max(y_sum, 0.0) / (2.0 * n)


def still_free_powers(
    direct: NDArray[np.complex128], copy: NDArray[np.complex128]
) -> NDArray[np.float64]:
    """``|C_y(t_rx, α) − C_y(t_rx', α)|²`` of candidates (any shape, the same for both): the
    likelihood of the two-term echo model on ``y`` (module docstring).

    >>> still_free_powers(np.array([1 + 1j, 2.0]), np.array([1j, -1.0])).tolist()
    [1.0, 9.0]
    """
    out: NDArray[np.float64] = np.abs(direct - copy) ** 2
    return out


def canceller_gain(
    tones_hz: NDArray[np.float64], amp2: NDArray[np.float64], hop_s: float, delta_s: float
) -> float:
    """What the canceller keeps of an echo's SNR on the two-term model, against the input
    itself in white noise: ``1 − Re R(δ) / R(0)``, ``R(τ) = Σ_i a_i² (D − |τ|)₊ e^{j2π f_i τ}``
    over the hops (tones ``tones_hz`` Hz, squared amplitudes ``amp2``, shape ``(M,)`` each;
    hop length ``hop_s`` = ``D``, s), ``δ = T_Q (α − 1)`` the copy's offset in transmit time
    (s). The model ``m = s − s_δ`` has ``‖m‖² = 2 R(0) − 2 Re R(δ)`` and ``y``'s noise twice
    the input's, so the model's SNR is this fraction of the input's (0 to 2; hops of other
    tones are taken as orthogonal). Where every tone turns by about a whole cycle over ``δ``
    (``δ`` near a whole number of grating lobes, ``f δ`` near whole cycles: blind speeds,
    about every 4 m/s on ``att``) it falls toward 0.

    >>> round(canceller_gain(np.array([1000.0, 2000.0]), np.ones(2), 0.01, 0.0), 6)
    0.0
    >>> round(canceller_gain(np.array([1000.0, 3000.0]), np.ones(2), 0.01, 0.0005), 6)
    1.95
    >>> round(canceller_gain(np.array([1000.0, 2000.0]), np.ones(2), 0.01, 0.02), 6)
    1.0
    """
    overlap = np.clip(hop_s - abs(delta_s), 0.0, None)
    r_delta = np.sum(amp2 * overlap * np.cos(2.0 * np.pi * tones_hz * delta_s))
    r_zero = float(np.sum(amp2)) * hop_s
    return 1.0 - float(r_delta) / r_zero if r_zero > 0 else 0.0
