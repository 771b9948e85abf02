"""What a coherent fit of a detection yields (:class:`Refinement`, with its
:class:`Coherence`), what it must reach to be one echo of the schedule (:class:`EchoTest`),
and what the refiner keeps of an echo it measured (:class:`EchoFit`): the values
:mod:`hil.estimation.refine` and :mod:`hil.estimation.refine_pair` exchange."""

from __future__ import annotations

import math
from dataclasses import dataclass

from hil.estimation.crlb import Crlb


@dataclass(frozen=True)
class EchoFit:
    """A fit kept to take its echo out of other detections' input: the boundary ending hop
    ``hop_index`` received at ``t_s`` (s), the time scale ``alpha`` and the fitted complex
    amplitude ``amplitude`` (``β``: the input is ``Re(β s)`` for the model ``s`` of the
    codeword's first code period)."""

    hop_index: int
    t_s: float
    alpha: float
    amplitude: complex
    #: The time scale's rate, 1/s (an accelerating fit's; 0 for a constant speed).
    rate: float = 0.0
    #: The largest detector statistic (above its noise mean) of a detection read as this echo's
    #: ghost (:meth:`~hil.estimation.refine.CoherentRefiner.ghost_of_known`; 0 before any), by the
    #: ghost's hop offset from the echo's, modulo a code period (shape ``(period_hops,)``).
    ghost_strength: tuple[float, ...] = ()
    #: The fit's E/N0, dB (:attr:`Refinement.e_over_n0_db`).
    e_over_n0_db: float = math.inf
    #: The latest hop at which this echo was looked for where the fit puts it, without a
    #: detection (:meth:`~hil.estimation.refine.CoherentRefiner.due`; its own hop before any).
    followed: int = -1
    #: The first hop before this fit's at which the echo was neither fitted nor looked for
    #: (this fit's detection came after a boundary that none brought; -1: none): looked for
    #: where this fit puts it (:meth:`~hil.estimation.refine.CoherentRefiner.due`).
    gap: int = -1
    #: Whether the echo is taken out of the second search's input
    #: (:meth:`~hil.estimation.refine.CoherentRefiner.known_input`): measured from a detection of
    #: the first search (or followed on from such a fit). An echo the second search found is not:
    #: that search goes on detecting it.
    cancelled: bool = True
    #: Measured as one of two echoes in one detection's hops (:mod:`hil.estimation.
    #: refine_pair`): the next detection of the pair starts from both.
    pair: bool = False
    #: This fit or an earlier one of its echo reached
    #: :attr:`~hil.estimation.refine.CoherentRefiner.follow_db`: the echo is followed on while its
    #: fits pass the echo test (:meth:`~hil.estimation.refine.CoherentRefiner.due`).
    held: bool = False
    #: A still echo measured at rest (:meth:`~hil.estimation.refine.CoherentRefiner.refine_still`):
    #: where it is, it stays, so it is taken out of other detections' input for
    #: :data:`~hil.estimation.refine.STILL_KNOWN_HOPS`.
    still: bool = False

    def boundary_s(self, hop_index: int, hop_len_s: float) -> float:
        """Where this fit puts the boundary ending hop ``hop_index`` (s of receive time),
        its echo carried on at the fitted delay and time scale; ``hop_len_s`` the nominal
        hop length (s)."""
        return self.t_s + (hop_index - self.hop_index) * hop_len_s / self.alpha

    def speed(self, sound_speed_mps: float) -> float:
        """Radial speed, m/s (closing positive)."""
        return sound_speed_mps * (self.alpha - 1.0) / (self.alpha + 1.0)


@dataclass(frozen=True)
class Coherence:
    """The hops' coherence at a fit (``measured``) and what one echo of the fit's SNR would
    give (``expected``), both in ``(0, 1]`` (:func:`~hil.estimation.fit_steps.echo_quality`)."""

    measured: float
    expected: float

    @property
    def fraction(self) -> float:
        """``measured / expected``: about 1 for one echo of the schedule."""
        return self.measured / self.expected if self.expected > 0 else 0.0


@dataclass(frozen=True)
class Refinement:
    """A refined detection: boundary receive time ``t_s`` (s), time scale ``alpha``, the
    E/N0 collected over the ``M`` hops (dB), its Cramér–Rao bounds (:class:`Crlb`; None
    where the E/N0 is not finite: no noise, or no echo), the
    coherence of the hops' terms over all hops, within each tone and over runs of consecutive
    hops (:func:`~hil.estimation.fit_steps.echo_quality`),
    and whether the search found its maximum inside (else ``t_s`` and ``alpha`` are the
    detection's own)."""

    t_s: float
    alpha: float
    e_over_n0_db: float
    bound: Crlb | None
    coherence: Coherence
    tone_coherence: Coherence
    run_coherence: Coherence
    found: bool
    #: The fitted complex amplitude ``β = 2C/E_s`` (the input is ``Re(β s)`` for the model
    #: ``s`` of the codeword's first code period); 0 where the windows are empty.
    amplitude: complex = 0j
    #: The radial acceleration fitted over the ``M`` hops, m/s² (closing speed growing
    #: positive); 0 where a constant speed explains them (``alpha`` is the boundary's).
    accel_mps2: float = 0.0
    #: The fit's echo ended within the window: its last hops hold none
    #: (:data:`~hil.estimation.refine.ENDED_CHANCE`). Not an estimate of the boundary, and not
    #: remembered.
    ended: bool = False
    #: The other echo of a resolved pair of one time scale (:mod:`hil.estimation.refine_pair`):
    #: this fit and it are two echoes of the detection's hops, each refined with the other
    #: taken out; None for one echo.
    second: Refinement | None = None

    def speed_mps(self, sound_speed_mps: float) -> float:
        """The fit's radial speed, m/s (closing positive)."""
        return sound_speed_mps * (self.alpha - 1.0) / (self.alpha + 1.0)

    def rate(self, sound_speed_mps: float) -> float:
        """The time scale's rate of change, 1/s per receive second (from the acceleration)."""
        return self.accel_mps2 * (self.alpha + 1.0) ** 2 / (2.0 * sound_speed_mps)

    def is_echo(self, test: EchoTest) -> bool:
        """Whether the fit is one echo of the schedule by ``test``: a maximum inside the
        search that collects at least ``test.min_e_over_n0_db`` and whose coherence over all
        hops is at least ``test.fraction`` of one echo's at its SNR, or over runs of
        consecutive hops at least ``test.run_fraction`` of it (an accelerating echo). The
        coherence within each tone is reported, not tested: a still echo's ghost read at the
        tone spacing's speed is as coherent within each tone as one echo."""
        return (
            self.found
            and self.e_over_n0_db >= test.min_e_over_n0_db
            and (
                self.coherence.fraction >= test.fraction
                or self.run_coherence.fraction >= test.run_fraction
            )
        )


@dataclass(frozen=True)
class EchoTest:
    """What a fit must reach to be one echo of the schedule (:meth:`Refinement.is_echo`):
    coherence fractions over all hops and over runs of consecutive hops, and the E/N0 (dB)
    it collects once the other echoes measured lately are taken out (what they leaked into
    a detection is not an echo of its own)."""

    fraction: float
    run_fraction: float
    min_e_over_n0_db: float
