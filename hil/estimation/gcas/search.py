"""The interface of a GCAS search: what the receiver asks of the correlator search in use
(:class:`~hil.estimation.gcas.search_full.FullSearch` or
:class:`~hil.estimation.gcas.search_two_stage.TwoStageSearch`).

A search consumes the complex baseband and gives the peaks that passed the threshold and
runner-up tests (:class:`~hil.estimation.gcas.threshold.Peak`); the receiver reads them out.
Every index is an absolute baseband sample index
(:class:`~hil.estimation.baseband.ComplexBaseband`).
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from hil.estimation.gcas.threshold import Peak


class SearchStrategy(Protocol):
    """A correlator search behind :class:`~hil.estimation.gcas.GcasReceiver`."""

    def reset(self, b0: int) -> None:
        """Forget every accumulation; the next baseband sample is ``b0``."""
        ...

    def process(self, y: NDArray[np.complex128]) -> list[Peak]:
        """Consume the next baseband samples ``y`` (shape ``(n,)``); the peaks whose
        look-ahead has arrived with them, in time order."""
        ...

    def flush(self) -> list[Peak]:
        """End of input: the peaks still undecided. A peak cut by the end of the input has
        no reliable time or codeword, so one whose look-ahead never arrived stays undecided."""
        ...

    def next_decision_index(self, samples_seen: int) -> int:
        """The input sample count the stream must reach before the next peak can come out
        (``samples_seen`` when the search gives no such bound)."""
        ...

    @property
    def decision_lag(self) -> int:
        """Baseband samples a peak can lie behind the newest baseband sample when it comes
        out (the history its decision reads): how long a readout must keep the input."""
        ...

    def map_hypotheses(self, count: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """The last ``count`` baseband sample indices and the hypothesis chosen at each (the
        rows of the time–codeword map)."""
        ...

    def retained(self, count: int) -> NDArray[np.int64]:
        """The last (at most ``count``) sample indices whose M terms are all retained."""
        ...

    def terms(self, idx: NDArray[np.int64], dcol: NDArray[np.int64]) -> NDArray[Any]:
        """Unit-correlator values of the M terms ``u[n − ℓ_{d,m}, d, k]`` of samples ``idx``
        (shape ``(n,)``) at hypotheses ``dcol``, shape ``(n, M, K)``: complex when the
        receiver is coherent, else ``w·|u|²``."""
        ...

    def unit_values(self, n_star: int, d0: int, tone: NDArray[np.int64]) -> NDArray[np.complex128]:
        """``w·u[n* − ℓ_{d0,m}, d0, tone_m]`` for the M terms (shape ``(M,)``), complex."""
        ...

    def warm_up(self) -> None:
        """Run every compiled kernel the search calls once, so that none is loaded (or
        compiled) inside a live block; state afterwards is undefined until :meth:`reset`."""
        ...
