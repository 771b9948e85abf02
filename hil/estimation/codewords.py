"""The codewords the coherent refinement fits (:mod:`hil.estimation.refine`): the ``M`` hops
ending at a boundary, relative to it, and their window's moments, made once per schedule.

A codeword's moments (its window's rms bandwidth, rms duration and mean frequency, for the
Cramér–Rao bounds) are measured from the sampled waveform, one FFT each: about 2 ms, and a
receiver's refiner makes every codeword of the code period when it is built, most of the
build's cost. They depend on the schedule, ``M`` and the input rate only, so
:meth:`CodewordBook.of` keeps one book per ``(M, rate)`` with the schedule
(:meth:`~hil.signals.schedule.HopSchedule.derived`): every refiner built from the same
schedule object reads the same codewords, made once.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from hil.estimation.crlb import rms_bandwidth, rms_duration
from hil.signals.schedule import HopSchedule


@dataclass(frozen=True)
class Codeword:
    """The ``M`` hops ending at a boundary ``T_b``, as :func:`~hil.estimation.refine_kernels.
    candidate_sums` takes them: ``hops = (k, f, dt_lo, dt_hi, amp2)`` (shape ``(M,)`` each;
    the transmit phasor ``a_i e^{−j(φ_i + 2π f_i (T_b − T_i))}``, tones in Hz, the hops'
    edges relative to ``T_b`` in s, squared amplitudes), and the window's ``B_rms`` (Hz),
    ``T_rms`` (s) and mean frequency (Hz) measured from the waveform
    (:mod:`hil.estimation.crlb`). Shared by every refiner of a schedule
    (:class:`CodewordBook`): its arrays are read, never written."""

    hops: tuple[NDArray[np.complex128], NDArray[np.float64], NDArray[np.float64],
                NDArray[np.float64], NDArray[np.float64]]  # fmt: skip
    b_rms: float
    t_rms: float
    f0: float
    tones: NDArray[np.int64]  # each hop's tone index in the schedule, shape (M,)

    @functools.cached_property
    def inv_amp2(self) -> NDArray[np.float64]:
        """``1/a_i²`` per hop (0 for a silent hop), shape ``(M,)``."""
        amp2 = self.hops[4]
        return np.divide(1.0, amp2, out=np.zeros_like(amp2), where=amp2 > 0)

    @functools.cached_property
    def inv_energy(self) -> NDArray[np.float64]:
        """``1/Σ_{j≤i} a_j²`` (0 while the hops so far are silent), shape ``(M,)``."""
        energy = np.cumsum(self.hops[4])
        return np.divide(1.0, energy, out=np.zeros_like(energy), where=energy > 0)

    @property
    def centre_s(self) -> float:
        """The hops' transmit centre relative to their end boundary, s (negative)."""
        return 0.5 * float(self.hops[2][0] + self.hops[3][-1])

    def last(self, n: int) -> Codeword:
        """The last ``n`` hops of this codeword, for a search over fewer hops (the window's
        bandwidth, duration and mean frequency are the whole codeword's: a search does not
        use them)."""
        k, f, dt_lo, dt_hi, amp2 = self.hops
        hops = (
            k[-n:].copy(),
            f[-n:].copy(),
            dt_lo[-n:].copy(),
            dt_hi[-n:].copy(),
            amp2[-n:].copy(),
        )
        return Codeword(hops, self.b_rms, self.t_rms, self.f0, self.tones[-n:].copy())

    def first(self, n: int) -> Codeword:
        """The first ``n`` hops of this codeword, their edges still relative to its end
        boundary (a search over them fits the line through that boundary that is their
        hops' tangent; :meth:`last`'s caveat)."""
        k, f, dt_lo, dt_hi, amp2 = self.hops
        hops = (k[:n].copy(), f[:n].copy(), dt_lo[:n].copy(), dt_hi[:n].copy(), amp2[:n].copy())
        return Codeword(hops, self.b_rms, self.t_rms, self.f0, self.tones[:n].copy())

    @classmethod
    def of(cls, schedule: HopSchedule, hop_index: int, m_hops: int, fs_hz: float) -> Codeword:
        """The codeword of the ``m_hops`` hops ending with hop ``hop_index`` of ``schedule``,
        its moments measured at ``fs_hz`` (Hz), made afresh (:class:`CodewordBook` keeps
        them)."""
        hops = schedule.hops(hop_index - m_hops + 1, m_hops)
        t_b = float(hops.start_s[-1] + hops.duration_s[-1])
        dt_lo = hops.start_s - t_b
        f = hops.freq_hz
        k = hops.amplitude * np.exp(-1j * (hops.phase_rad - 2 * np.pi * f * dt_lo))
        t = float(hops.start_s[0]) + np.arange(int(round(-dt_lo[0] * fs_hz))) / fs_hz
        s = schedule.evaluate_analytic(t)
        b_rms, f0 = rms_bandwidth(s, fs_hz)
        return cls(
            (k, f, dt_lo, dt_lo + hops.duration_s, hops.amplitude**2),
            b_rms, rms_duration(s, fs_hz), abs(f0), hops.tone_index.astype(np.int64),
        )  # fmt: skip


class CodewordBook:
    """Every ``M``-hop codeword of one schedule at one input rate, each made on its first use
    and kept: ``book[hop_index]`` is the codeword ending with that hop, made from the first
    code period (the same hops a period later differ by a common phase only, which ``|C|``
    does not see), so the figures never depend on which period a codeword was first met in.

    Build it with :meth:`of`, which keeps one book per ``(M, rate)`` with the schedule: the
    refiners of every receiver built from that schedule object share it.

    >>> from hil.signals.schedule import HopSchedule
    >>> s = HopSchedule.from_segments("demo", [1000.0, 1500.0, 2000.0], [0, 2, 1], 0.01)
    >>> book = CodewordBook.of(s, 2, 8000.0)
    >>> book is CodewordBook.of(s, 2, 8000.0), book[4] is book[1]
    (True, True)
    >>> book[1].tones.tolist(), round(book[1].t_rms * 1e3, 3)  # two hops of 10 ms: 20/√12 ms
    ([0, 2], 5.774)
    """

    def __init__(self, schedule: HopSchedule, m_hops: int, fs_hz: float) -> None:
        self.schedule, self.m_hops, self.fs_hz = schedule, int(m_hops), float(fs_hz)
        self._words: dict[int, Codeword] = {}

    @classmethod
    def of(cls, schedule: HopSchedule, m_hops: int, fs_hz: float) -> CodewordBook:
        """The book of ``m_hops``-hop codewords at ``fs_hz`` (Hz) kept with ``schedule``, made
        on the first call for that ``M`` and rate."""
        m, fs = int(m_hops), float(fs_hz)
        return schedule.derived((cls, m, fs), lambda: cls(schedule, m, fs))

    def __getitem__(self, hop_index: int) -> Codeword:
        key = int(hop_index) % self.schedule.period_hops
        word = self._words.get(key)
        if word is None:
            word = self._words[key] = Codeword.of(self.schedule, key, self.m_hops, self.fs_hz)
        return word
