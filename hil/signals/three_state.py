"""Three-frequency-state HFC-CW code (seed §4.1; SPEC §2.1).

Three tones; a hop never repeats the previous tone [R], so each state has two successors and
every hop carries one bit: ``s_{n+1} = (s_n + 1 + b_n) mod 3``. A codeword is ``L_c``
consecutive bits; with the bit stream taken from a binary de Bruijn sequence of order ``L_c``
every codeword occurs once per period, and the tone sequence closes after ``2**L_c`` hops
(the sum of ``1 + b_n`` over a period is ``3·2**(L_c−1) ≡ 0 (mod 3)``). An m-sequence
(period ``2**L_c − 1``) is the alternative; its tone sequence closes after three bit periods.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.signals.binary_sequences import cyclic_words, de_bruijn, m_sequence

BitSource = Literal["debruijn", "mseq"]
N_STATES = 3


def transition(state: int | NDArray[np.int64], bit: int | NDArray[np.int64]) -> NDArray[np.int64]:
    """Next tone state: ``(s + 1 + b) mod 3``.

    >>> transition(0, 0).item(), transition(0, 1).item(), transition(2, 1).item()
    (1, 2, 1)
    """
    return np.asarray((np.asarray(state) + 1 + np.asarray(bit)) % N_STATES, dtype=np.int64)


def states_from_bits(bits: NDArray[np.int64], start_state: int = 0) -> NDArray[np.int64]:
    """Tone states ``s_0 .. s_{N−1}`` for bits ``b_0 .. b_{N−1}`` (``s_0 = start_state``).

    Hop ``n`` sounds tone ``s_n``; bit ``b_n`` decides the step to hop ``n + 1``.

    >>> states_from_bits(np.array([0, 0, 0, 1, 0, 1, 1, 1])).tolist()
    [0, 1, 2, 0, 2, 0, 2, 1]
    """
    if start_state not in (0, 1, 2):
        raise ConfigError("start_state", start_state, "0, 1 or 2")
    steps = 1 + np.asarray(bits, dtype=np.int64)
    cum = np.concatenate(([0], np.cumsum(steps)[:-1]))
    return np.asarray((start_state + cum) % N_STATES, dtype=np.int64)


@dataclass(frozen=True)
class ThreeStateCode:
    """A three-state HFC-CW code over one period of the tone sequence.

    Attributes
    ----------
    order:
        Codeword length L_c (bits).
    source:
        ``"debruijn"`` or ``"mseq"``.
    bits:
        One period of the bit stream, shape ``(2**L_c,)`` or ``(2**L_c − 1,)``.
    states:
        The tone index of every hop over one period of the *tone* sequence, shape ``(P,)``.
    """

    order: int
    source: BitSource
    bits: NDArray[np.int64]
    states: NDArray[np.int64]

    @property
    def period_hops(self) -> int:
        """Hops until the tone sequence repeats."""
        return int(self.states.shape[0])

    def codeword_table(self) -> list[dict[str, object]]:
        """The codewords ``cw1 … cw(2**L_c)``: name, bits, and where they occur.

        Codeword ``cw(v+1)`` is the ``L_c``-bit word with value ``v`` (first bit most
        significant) [R: the seed's own numbering is not known]. ``positions`` are the hops
        ``p`` of the tone period at which the word starts, i.e. where bits
        ``b_p … b_{p+L_c−1}`` equal it; ``tones`` are the ``L_c + 1`` tone states that the
        word spans from the first of those positions (empty if the word never occurs, as for
        the all-zero word of an m-sequence).
        """
        n_bits_period = self.bits.shape[0]
        reps = self.period_hops // n_bits_period
        tone_bits = np.tile(self.bits, reps)
        words = cyclic_words(tone_bits, self.order)
        table: list[dict[str, object]] = []
        for v in range(2**self.order):
            pos = np.flatnonzero(words == v)
            bits = [(v >> (self.order - 1 - i)) & 1 for i in range(self.order)]
            tones: list[int] = []
            if pos.size:
                span = (pos[0] + np.arange(self.order + 1)) % self.period_hops
                tones = self.states[span].tolist()
            table.append(
                {"name": f"cw{v + 1}", "bits": bits, "positions": pos.tolist(), "tones": tones}
            )
        return table


def three_state_code(
    order: int, source: BitSource = "debruijn", start_state: int = 0
) -> ThreeStateCode:
    """Build the three-state code with codeword length ``order`` = L_c.

    >>> c = three_state_code(3)
    >>> c.states.tolist(), c.period_hops
    ([0, 1, 2, 0, 2, 0, 2, 1], 8)
    >>> three_state_code(3, "mseq").period_hops  # 3 bit periods of 7
    21
    """
    if source == "debruijn":
        bits = de_bruijn(order)
    elif source == "mseq":
        bits = m_sequence(order)
    else:
        raise ConfigError("source", source, "'debruijn' or 'mseq'")
    # Repeat the bit period until the tone sequence returns to its start state (1 or 3 times).
    for reps in (1, 2, 3):
        tiled = np.tile(bits, reps)
        total = int(np.sum(1 + tiled))
        if total % N_STATES == 0:
            break
    states = states_from_bits(tiled, start_state)
    return ThreeStateCode(order=int(order), source=source, bits=bits, states=states)
