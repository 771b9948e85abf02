"""The shared receiver interface and estimate record.

A receiver consumes real samples block by block and emits one :class:`Estimate` per detected
hop boundary (or per sweep/pulse for the comparison waveforms). Receivers are block-wise with
explicit state (DESIGN principle 7): for any chunking of the input, the concatenated output of
:meth:`Receiver.process` followed by :meth:`Receiver.flush` equals that of one call on the
whole signal.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

ESTIMATE_FIELDS: tuple[str, ...] = (
    "t_s",
    "range_m",
    "speed_mps",
    "hop_index",
    "score",
    "snr_db",
    "alpha",
    "t_tx_s",
    "codeword",
    "receiver",
    "crlb_range_m",
    "crlb_speed_mps",
    "track_id",
)


_NAN = object()


@dataclass(frozen=True)
class Estimate:
    """One range/speed estimate.

    Attributes
    ----------
    t_s:
        Receive time of the detected hop boundary, s from the first sample of the input
        (sample ``n`` is at ``n / fs``).
    range_m:
        Range at the bounce instant, ``c (t_rx − t_tx) / 2``, m.
    speed_mps:
        Radial speed, m/s, positive closing, from the Doppler estimate
        ``v = c (α − 1)/(α + 1)``.
    hop_index:
        Global index (in the transmit schedule) of the hop whose *end* boundary was received
        at ``t_s``: the boundary between transmit hops ``hop_index`` and ``hop_index + 1``.
        Consecutive detections of one target advance it by one.
    score:
        Detection statistic of the receiver (dimensionless; larger is more confident); NaN
        for an echo measured without a detection of its own (GCAS with the refinement
        follows an echo measured lately to its next boundary where another echo's ghost
        or response hides its peak: :meth:`hil.estimation.gcas.readout.Readout.decide_all`).
    snr_db:
        Estimated output SNR of the detection, dB; NaN where ``score`` is.
    alpha:
        Estimated Doppler time-scale factor α = (c + v)/(c − v).
    t_tx_s:
        Transmit time of that boundary, s, in the same time base as ``t_s``.
    codeword:
        Index of the detected codeword within the code period (``hop_index mod P``).
    receiver:
        Name of the receiver that produced it (``"gcas"``, ``"jifs"``, ``"stft"``,
        ``"mfbank"``, ``"fmcw"``).
    crlb_range_m, crlb_speed_mps:
        Cramér–Rao bounds (standard deviations, m and m/s) of this estimate's range and speed
        at the E/N0 its own echo had (:mod:`hil.estimation.crlb`), where the receiver
        measured it (GCAS's coherent refinement); NaN otherwise.
    track_id:
        Identity of the confirmed track the estimate belongs to (0, 1, 2, … in order of
        confirmation, :mod:`hil.estimation.tracking`); ``-1`` for none (its track not yet
        confirmed, no tracker, or a recording made before tracks were kept).
    """

    t_s: float
    range_m: float
    speed_mps: float
    hop_index: int
    score: float
    snr_db: float
    alpha: float
    t_tx_s: float
    codeword: int
    receiver: str
    crlb_range_m: float = math.nan
    crlb_speed_mps: float = math.nan
    track_id: int = -1

    def __eq__(self, other: object) -> bool:
        """Field-by-field equality where NaN equals NaN: an estimate without a bound (or
        with a NaN SNR) read back from a recording is the same result."""
        if not isinstance(other, Estimate):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def _key(self) -> tuple[Any, ...]:
        """The fields, each NaN as one marker (so NaN matches NaN)."""
        return tuple(
            _NAN if isinstance(v, float) and math.isnan(v) else v
            for v in (getattr(self, name) for name in ESTIMATE_FIELDS)
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary with the fields in :data:`ESTIMATE_FIELDS` order.

        Every field is a scalar, so the values are read as they are, not deep-copied
        (``dataclasses.asdict``: 13 µs an estimate against 1 µs, the same dictionary)."""
        return {k: getattr(self, k) for k in ESTIMATE_FIELDS}


@runtime_checkable
class Receiver(Protocol):
    """A block-wise estimator with explicit state.

    ``fs_hz`` is the input sample rate. ``samples_seen`` counts the samples consumed so far
    (gaps included), so ``samples_seen / fs_hz`` is the time of the next input sample.
    """

    name: str
    fs_hz: float

    @property
    def samples_seen(self) -> int:
        """Samples consumed so far."""
        ...

    @property
    def next_decision_index(self) -> int:
        """Input sample index (counted as :attr:`samples_seen`) the stream must reach before
        the receiver can emit its next estimate: a live loop waits for it rather than calling
        the receiver on every block (no estimate comes out earlier). A receiver that may emit
        on any block gives :attr:`samples_seen`."""
        ...

    def process(self, block: NDArray[np.floating], *, gap_before: int = 0) -> list[Estimate]:
        """Consume ``block`` (shape ``(n,)``, real samples) and return new estimates.

        ``gap_before`` is the number of samples missing between the previous block and this
        one (flagged by the caller from sample indices); the receiver advances its time base
        by that many samples and restarts its accumulation cleanly, so no estimate straddles
        a gap.
        """
        ...

    def flush(self) -> list[Estimate]:
        """End of input: return estimates still held back (e.g. awaiting a look-ahead)."""
        ...

    def reset(self) -> None:
        """Forget all state; the next sample is sample 0 again."""
        ...


#: What a receiver refused, by reason (:meth:`CountsRefusals.refusals`' keys), as a user reads
#: it; the order of the CLI's ``refused:`` line.
REFUSAL_REASONS: dict[str, str] = {
    "not_one_echo": "not one echo of the schedule (ghosts, sidelobes, noise)",
    "clutter": "diffuse reverberation (clutter)",
    "in_band": "on the reverberation band's edge",
    "beyond_span": "beyond the Doppler span",
    "beyond_max_range": "beyond the maximum range",
    "unmeasured": "whose hops reach before the input's start or a gap",
    "same_echo": "of an echo already reported at that boundary",
    "ended": "of an echo that ended before their boundary",
}


@runtime_checkable
class CountsRefusals(Protocol):
    """A receiver that counts the detections it refused instead of reporting them."""

    def refusals(self) -> dict[str, int]:
        """Detections refused since the last reset, by reason (keys of
        :data:`REFUSAL_REASONS`; every key present, 0 for none)."""
        ...


class Notice(Protocol):
    """Something a receiver says of what it refused (an echo beyond its Doppler span,
    clutter): when (``t_s``, s of input time, the detection's boundary), a line for a person
    and JSON-ready fields with a ``"notice"`` key."""

    @property
    def t_s(self) -> float: ...

    def text(self) -> str: ...

    def to_dict(self) -> dict[str, object]: ...


@runtime_checkable
class SaysNotices(Protocol):
    """A receiver that says what it refused, beside counting it (GCAS with its refinement:
    :mod:`hil.estimation.gcas.beyond_span`, :mod:`hil.estimation.gcas.clutter_seen`)."""

    def notices(self) -> Sequence[Notice]:
        """The notices since the last reset, in the order seen."""
        ...


def refusal_text(counts: dict[str, int]) -> str:
    """``counts`` (:meth:`CountsRefusals.refusals`) as one line; empty where none.

    >>> refusal_text({"not_one_echo": 0, "clutter": 1, "in_band": 2})
    "refused: 1 diffuse reverberation (clutter), 2 on the reverberation band's edge"
    """
    parts = [f"{counts[key]} {text}" for key, text in REFUSAL_REASONS.items() if counts.get(key, 0)]
    return "refused: " + ", ".join(parts) if parts else ""
