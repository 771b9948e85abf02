"""Two echoes of one time scale in one detection's hops: a formation close in range
(:meth:`hil.estimation.refine.CoherentRefiner.refine`'s two-echo fit).

Two echoes at one speed whose delays differ by ``Δ`` less than about three grating lobes
(``1/(α Δf)``, 0.68 m on ``att``) share the detector's peak and the same hops: at either
delay each hop's term holds ``β₁ + β₂ g_i(Δ)``, ``g_i`` the other echo read on hop ``i``'s
tone (a phase ``2π f_i α Δ`` that differs from tone to tone). The one-echo fit then lands
on one of them (or between) with hops whose phases disagree from tone to tone: refused as
not one echo, coherent within each tone as multipath is. A whole number of grating lobes
apart the phases agree on every tone (the hops' terms are one echo's, ``β₁ + β₂ (1 −
k/(α Δf D))``) and only the hops' edges tell the two apart: the one-echo fit passes, on
either echo by turns.

The model here is the sum of two echoes of the exact schedule at delays ``t₁, t₂`` near
the detection, each with its own complex amplitude (linear: least squares of both
together, :func:`_joint_amplitudes`, as the one-echo fit's is) and its own time scale
within the speed span. It is fitted by alternating maximisation (each echo's delay, speed
and amplitude by the one-echo fit with the other taken out of the input, its grating lobe
checked, :data:`PAIR_ROUNDS` rounds: each round raises the pair's likelihood), started
from the one-echo fit and the largest correlation left within :data:`SEED_LOBES` grating
lobes of it once that fit is taken out, or from a pair measured lately.

The two are kept where

- each is one echo of the schedule with the other taken out
  (:meth:`~hil.estimation.refine.Refinement.is_echo`);
- the second echo explains significantly more than one echo does (:func:`pair_gain`): the
  energy the pair explains beyond the one-echo fit, in the hops' units, over the hops' own
  scatter about the pair (``RSS = Σ |H_i|²/a_i² − |Σ H_i|²/Σ a_i²`` at each echo's delay
  with the other taken out, the larger), ``G = (M − 2) gain / RSS``. For one echo in white
  noise the gain of a second complex amplitude is ``σ² N`` times an exponential variable
  and ``RSS/(M − 2)`` estimates ``σ² N``, so ``G`` is an ``F(2, 2(M − 2))`` variable
  (tail ``(1 + g/(M − 2))^{−(M − 2)}``); the second echo's delay is chosen among ``n``
  independent cells (the search's ``2 SEED_LOBES`` grating lobes of ``B/Δf`` main lobes
  each, a union bound): the limit puts the chance at :data:`PAIR_CHANCE`. The scatter is
  the hops' own, as :data:`~hil.estimation.refine.ENDED_CHANCE`'s test: reverberation and
  fading make a hop's term stray more than the fit's E/N0 says;
- the two do not cancel each other (:func:`interference`, :data:`LEAST_INTERFERENCE`).

Both are reported where their delays are at least :data:`RESOLVED_LOBES` main lobes ``1/B``
apart (``B`` the tones' span; 0.30 ms, 0.23 m on ``att``); closer, the pair is one
resolution cell (its hops are nearly one echo's, a second estimate would be the first
one's noise) and its stronger echo alone is reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from hil.estimation.codewords import Codeword
from hil.estimation.echo_fits import EchoFit, EchoTest, Refinement
from hil.estimation.refine_kernels import FOUND, candidate_sums

#: The second echo is looked for within this many grating lobes of the one-echo fit (two
#: echoes further apart each hold their own detector peak, and the one-echo fits with the
#: other taken out read them: :data:`~hil.estimation.refine.PARTNER_COHERENCE`).
SEED_LOBES = 3.0
#: The seed grid's step, main lobes ``1/B``.
SEED_STEP = 0.25
#: Rounds of the alternating fit.
PAIR_ROUNDS = 3
#: The fits' grid in each round: ± this many grating lobes in time and speed spans in speed.
ROUND_HALF_LOBES = 0.125
ROUND_HALF_SPANS = 0.5
#: Delays closer than this many main lobes ``1/B`` are one resolution cell.
RESOLVED_LOBES = 1.0
#: The chance that one echo in noise passes :func:`pair_gain`'s test.
PAIR_CHANCE = 1e-3
#: A pair is kept where what it explains together is at least this fraction of what its two
#: echoes hold alone (:func:`interference`). Two echoes a whole number of grating lobes
#: apart in opposite phase cancel on every hop but its edges, so a large such pair fits the
#: edges of whatever a hop holds: the refused fits of a target's leaks and a still echo's
#: ghosts (att: 24 m/s targets' leaks at 16.4 m/s, two echoes 1-2 lobes apart of 0.22-0.45
#: each where the one-echo fit reads 0.10-0.37; 0.17-0.36 of them; real pairs 0.3-2 m
#: apart 0.9-2). Half is where the two interfere destructively by more than their own
#: energy's half: such a pair is not told from a hop's edge structure.
LEAST_INTERFERENCE = 0.5
#: Lobe checks after a search (each may move the fit by one grating lobe; they stop where
#: neither neighbour is better): a detector's time can be several lobes off at an echo's
#: first boundary (att three-state, full search: 2.75 lobes, 1.8 ms). The one-echo fit's
#: (:class:`~hil.estimation.refine.CoherentRefiner`) and each echo's of a pair.
LOBE_MOVES = 4


class PairFitHost(Protocol):
    """What the pair fit reads of the refiner whose detection it fits
    (:class:`~hil.estimation.refine.CoherentRefiner`): its design and its one-echo search
    over the input it holds."""

    c: float  #: sound speed, m/s
    fs_hz: float  #: input rate, Hz
    hop_len_s: float  #: the hops' length, s
    m_hops: int  #: hops of a codeword
    speed_span_mps: float  #: the search's speed span about a detection, m/s
    main_lobe_s: float  #: the likelihood's main lobe in time, ``1/B`` (s)

    @property
    def slot_tables(self) -> tuple[NDArray[Any], ...]:
        """The hops' correlation tables, as the refinement kernels take them."""
        ...

    def hop_slots(
        self, hop_ids: NDArray[np.int64], word: Codeword, t_s: float, alpha: float
    ) -> NDArray[np.int64] | None:
        """Each hop's table slot for a window at ``(t_s, alpha)`` (None: input not held)."""
        ...

    def echo_rows(self, echoes: list[EchoFit], t_end: float) -> NDArray[np.complex128]:
        """The rows that take ``echoes`` out of the ``M`` hops ending at ``t_end`` (s)."""
        ...

    def search_near(
        self, word: Codeword, hop_ids: NDArray[np.int64], t0: float, v0: float, lobe: float,
        known: NDArray[np.complex128], grid: tuple[float, float, int, int] | None = None,
        gamma: float = 0.0,
    ) -> tuple[float, float, int, tuple[Any, ...]] | None:  # fmt: skip
        """The one-echo search around ``(t0 s, v0 m/s)`` with ``known`` taken out."""
        ...

    def candidate_powers(
        self, args: tuple[Any, ...], known: NDArray[np.complex128], t: NDArray[np.float64],
        alpha: NDArray[np.float64], gamma: NDArray[np.float64],
    ) -> NDArray[np.float64]:  # fmt: skip
        """``|C|²`` of the candidates ``(t, alpha, gamma)``."""
        ...

    def narrow_grid(self, lobe: float) -> tuple[float, float, int, int]:
        """A grid around a point already near the maximum."""
        ...

    def better_lobe(
        self, args: tuple[Any, ...], t_s: float, speed: float, lobe: float,
        known: NDArray[np.complex128], any_side: bool = False, gamma: float = 0.0,
    ) -> float | None:  # fmt: skip
        """A neighbouring grating lobe's time (s) where the likelihood is greater, or None."""
        ...

    def refinement_at(
        self, args: tuple[Any, ...], known: NDArray[np.complex128], word: Codeword, t: float,
        alpha: float, gamma: float, found: bool,
    ) -> Refinement:  # fmt: skip
        """The :class:`~hil.estimation.echo_fits.Refinement` of the fit ``(t, alpha, gamma)``."""
        ...


@dataclass(frozen=True)
class PairFit:
    """Two echoes of one detection's hops: ``first`` (the nearer the one-echo fit) and
    ``second``, each refined with the other taken out; ``resolved`` where their delays are
    at least :data:`RESOLVED_LOBES` main lobes apart; ``gain`` the least of the two views'
    :func:`pair_gain`."""

    first: Refinement
    second: Refinement
    resolved: bool
    gain: float


def gain_limit(m_hops: int, cells: float, chance: float = PAIR_CHANCE) -> float:
    """The limit of :func:`pair_gain` for ``m_hops`` hops and a second echo chosen among
    ``cells`` independent cells: ``(M − 2)((cells/chance)^{1/(M − 2)} − 1)``."""
    q = float(m_hops - 2)
    return q * ((cells / chance) ** (1.0 / q) - 1.0)


def pair_gain(
    c: NDArray[np.complex128], cross: complex, model: NDArray[np.float64], one: float,
    rss: float, samples: float, m_hops: int,
) -> float:  # fmt: skip
    """``G``: what the second echo adds to the explained energy over the hops' own scatter
    (module docstring). ``c`` (shape ``(2,)``) each echo's correlation ``C`` with the input
    (the other echo in), ``cross`` the model's ``Σ s₂ s₁*`` (the second echo read at the
    first's delay), ``model`` (shape ``(2,)``) each echo's ``E_s``; the pair explains
    ``2 cᴴ A⁻¹ c`` of the input's energy (``A`` the models' Gram matrix: least squares of
    the two complex amplitudes), one echo ``one`` (its ``2|C|²/E_s``). ``rss`` the hops'
    scatter about the pair (``Σ |H_i|²/a_i² − |Σ H_i|²/Σ a_i²`` at an echo's delay with the
    other taken out), ``samples`` a hop's samples: the gain in the hops' units is
    ``samples/2`` times the energy's."""
    det = float(model[0] * model[1]) - abs(cross) ** 2
    if not (det > 0 and rss > 0):
        return -math.inf
    # 2 cᴴ A⁻¹ c with A = [[E₁, cross], [cross*, E₂]].
    quad = (
        model[1] * abs(c[0]) ** 2 + model[0] * abs(c[1]) ** 2
        - 2.0 * (np.conj(c[0]) * cross * c[1]).real
    )  # fmt: skip
    explained = 2.0 * float(quad) / det
    return 0.5 * samples * (explained - one) / (rss / (m_hops - 2))


def interference(c: NDArray[np.complex128], cross: complex, model: NDArray[np.float64]) -> float:
    """What the pair explains together (``2 cᴴ A⁻¹ c``) over the sum of what each of its
    least-squares echoes holds alone (``½ |β_k|² E_k``, ``β = 2 A⁻¹ c``); ``c``, ``cross``
    and ``model`` as :func:`pair_gain`'s. 1 for echoes whose models do not overlap, up to 2
    for two in phase a grating lobe apart, and near 0 where the two cancel each other on
    all but their hops' edges (:data:`LEAST_INTERFERENCE`); 0 where the two are one
    model."""
    det = float(model[0] * model[1]) - abs(cross) ** 2
    if not det > 0:
        return 0.0
    b1 = 2.0 * (model[1] * c[0] - cross * c[1]) / det
    b2 = 2.0 * (model[0] * c[1] - np.conj(cross) * c[0]) / det
    alone = 0.5 * (abs(b1) ** 2 * model[0] + abs(b2) ** 2 * model[1])
    together = float((np.conj(b1) * c[0] + np.conj(b2) * c[1]).real)
    return together / alone if alone > 0 else 0.0


def hop_scatter(terms: NDArray[np.complex128], amp2: NDArray[np.float64]) -> float:
    """``Σ |H_i|²/a_i² − |Σ H_i|²/Σ a_i²`` of hops' terms ``terms`` (shape ``(M,)``) with
    squared amplitudes ``amp2``: their scatter about one echo (silent hops left out)."""
    live = amp2 > 0
    h, a2 = terms[live], amp2[live]
    return float(np.sum((h.real**2 + h.imag**2) / a2)) - abs(complex(np.sum(h))) ** 2 / float(
        np.sum(a2)
    )


def fit_pair(
    ref: PairFitHost, fit: Refinement, word: Codeword, hop_ids: NDArray[np.int64],
    hop_index: int, lobe: float, known: NDArray[np.complex128], test: EchoTest,
    seeds: tuple[EchoFit, EchoFit] | None = None,
) -> PairFit | None:  # fmt: skip
    """Two echoes of one time scale near the refused one-echo ``fit`` of the boundary ending
    hop ``hop_index`` (hops ``hop_ids`` of ``word``; ``lobe`` the grating lobe, s;
    ``known`` the other echoes' rows), each one echo by ``test`` with the other taken out
    and together explaining the hops better than one (module docstring); None otherwise,
    or where the input does not cover the hops. ``seeds``: the pair's echoes measured lately
    (a warm start, instead of the seed search: each carried to this boundary, and taken out
    of the other's input as measured, its amplitude on its own codeword's phase)."""
    if seeds is None:
        second = _seed(ref, fit, word, hop_ids, hop_index, lobe, known)
        if second is None:
            return None
        places = [(fit.t_s, fit.alpha), (second, fit.alpha)]
    else:
        places = [(_carried(e, hop_index, ref.hop_len_s), e.alpha) for e in seeds]
    amplitudes = _joint_amplitudes(ref, word, hop_ids, hop_index, places, known)
    if amplitudes is None:
        return None
    echoes = [EchoFit(hop_index, t, a, b) for (t, a), b in zip(places, amplitudes, strict=True)]
    fits: list[Refinement | None] = [None, None]
    for _ in range(PAIR_ROUNDS):
        for k in (1, 0):
            rows = _with(known, ref.echo_rows([echoes[1 - k]], echoes[k].t_s))
            got = _fit_one(ref, word, hop_ids, echoes[k], lobe, rows)
            if got is None:
                return None
            fits[k] = got
            echoes[k] = EchoFit(hop_index, got.t_s, got.alpha, got.amplitude)
    first, second_fit = fits
    assert first is not None and second_fit is not None
    if abs(first.t_s - second_fit.t_s) > SEED_LOBES * lobe:
        return None  # one of them left the detection's neighbourhood (another echo's)
    if not (first.is_echo(test) and second_fit.is_echo(test)):
        return None
    gain, together = _gain(ref, word, hop_ids, hop_index, fit, first, second_fit, known)
    cells = 2.0 * SEED_LOBES * lobe / ref.main_lobe_s
    if not (gain > gain_limit(ref.m_hops, cells) and together >= LEAST_INTERFERENCE):
        return None
    main = ref.main_lobe_s
    resolved = abs(first.t_s - second_fit.t_s) >= RESOLVED_LOBES * main
    return PairFit(first, second_fit, resolved, gain)


def _carried(echo: EchoFit, hop_index: int, hop_s: float) -> float:
    """Where ``echo``'s fit puts the boundary ending hop ``hop_index``, s."""
    return echo.t_s + (hop_index - echo.hop_index) * hop_s / echo.alpha


def _with(known: NDArray[np.complex128], rows: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """``known`` and ``rows`` together (shape ``(5, Q + Q')``)."""
    return np.ascontiguousarray(np.concatenate([known, rows], axis=1))


def _fit_one(
    ref: PairFitHost, word: Codeword, hop_ids: NDArray[np.int64], start: EchoFit,
    lobe: float, rows: NDArray[np.complex128],
) -> Refinement | None:  # fmt: skip
    """The one-echo fit near ``start``'s delay and speed with ``rows`` taken out: a grid of
    ±:data:`ROUND_HALF_LOBES` lobe and ±:data:`ROUND_HALF_SPANS` speed spans, re-centred
    and fitted (:meth:`PairFitHost.search_near`), the full ±½ lobe
    search where its maximum is on that grid's edge in time, then moved to a neighbouring
    grating lobe where that is greater (up to
    :data:`LOBE_MOVES` times); None where the input does not cover
    the hops or no maximum is inside."""
    v0 = start.speed(ref.c)
    grid = (ROUND_HALF_LOBES * lobe, ROUND_HALF_SPANS * ref.speed_span_mps, 5, 5)
    searched = ref.search_near(word, hop_ids, start.t_s, v0, lobe, rows, grid)
    if searched is not None and searched[2] != FOUND:
        searched = ref.search_near(word, hop_ids, start.t_s, v0, lobe, rows)
    if searched is None or searched[2] != FOUND:
        return None
    t, v, _, args = searched
    for _ in range(LOBE_MOVES):
        # The grating lobe: a lobe of the other echo's neighbour keeps most of its hops'
        # terms (a lobe apart they differ by the hops' edges only), so the likelihood's own
        # neighbours decide, as for one echo.
        moved = ref.better_lobe(args, t, v, lobe, rows)
        if moved is None:
            break
        searched = ref.search_near(word, hop_ids, moved, v, lobe, rows, ref.narrow_grid(lobe))
        if searched is None or searched[2] != FOUND:
            return None
        t, v, _, args = searched
    alpha = (ref.c + v) / (ref.c - v)
    return ref.refinement_at(args, rows, word, t, alpha, 0.0, True)


def _joint_amplitudes(
    ref: PairFitHost,
    word: Codeword,
    hop_ids: NDArray[np.int64],
    hop_index: int,
    places: list[tuple[float, float]],
    known: NDArray[np.complex128],
) -> tuple[complex, complex] | None:
    """The two echoes' complex amplitudes at ``places`` (``(t, α)`` each, s) by least
    squares together, ``β = 2 A⁻¹ c`` (``c`` each one's ``C``, ``A`` the models' Gram
    matrix, its cross term what a unit echo at the second place puts into the first's
    ``C``); None where the input does not cover the hops or the two are one model."""
    (t1, a1), (t2, a2) = places
    slots = ref.hop_slots(hop_ids, word, t1, a1)
    if slots is None:
        return None
    args = (*ref.slot_tables, slots, *word.hops, ref.fs_hz, ref.hop_len_s)
    c1, e1, _ = _sums(args, known, t1, a1, ref.m_hops)
    unit = _with(known, ref.echo_rows([EchoFit(hop_index, t2, a2, 2.0 + 0j)], t1))
    cross = c1 - _sums(args, unit, t1, a1, ref.m_hops)[0]  # Σ s₂ s₁* (a unit β is 2)
    slots = ref.hop_slots(hop_ids, word, t2, a2)
    if slots is None:
        return None
    args = (*ref.slot_tables, slots, *word.hops, ref.fs_hz, ref.hop_len_s)
    c2, e2, _ = _sums(args, known, t2, a2, ref.m_hops)
    det = e1 * e2 - abs(cross) ** 2
    if not det > 0:
        return None
    # A = [[E₁, cross], [cross*, E₂]]; β = 2 A⁻¹ c.
    b1 = 2.0 * (e2 * c1 - cross * c2) / det
    b2 = 2.0 * (e1 * c2 - np.conj(cross) * c1) / det
    return complex(b1), complex(b2)


def _seed(
    ref: PairFitHost,
    fit: Refinement,
    word: Codeword,
    hop_ids: NDArray[np.int64],
    hop_index: int,
    lobe: float,
    known: NDArray[np.complex128],
) -> float | None:
    """Where the second echo starts: the largest ``|C|²`` at ``fit``'s time scale within
    :data:`SEED_LOBES` grating lobes of it (steps of :data:`SEED_STEP` main lobes), ``fit``
    taken out, farther than half a main lobe from it (s); None where the input does not
    cover the hops."""
    main = ref.main_lobe_s
    own = EchoFit(hop_index, fit.t_s, fit.alpha, fit.amplitude)
    rows = _with(known, ref.echo_rows([own], fit.t_s))
    best_p, best_t = -1.0, math.nan
    # Tables are made around each grating lobe's centre (a window reaches about ±¾ lobe
    # from where its tables were made).
    n_side = int(math.ceil(SEED_LOBES))
    per_lobe = int(math.ceil(lobe / (SEED_STEP * main)))
    offsets = (np.arange(per_lobe) + 0.5) / per_lobe - 0.5  # lobes, within ±½
    for j in range(-n_side, n_side + 1):
        centre = fit.t_s + j * lobe
        t = np.ascontiguousarray(centre + lobe * offsets)
        keep = (np.abs(t - fit.t_s) >= 0.5 * main) & (np.abs(t - fit.t_s) <= SEED_LOBES * lobe)
        if not keep.any():
            continue
        t = np.ascontiguousarray(t[keep])
        slots = ref.hop_slots(hop_ids, word, centre, fit.alpha)
        if slots is None:
            return None
        args = (*ref.slot_tables, slots, *word.hops, ref.fs_hz, ref.hop_len_s)
        p = ref.candidate_powers(args, rows, t, np.full(t.size, fit.alpha), np.zeros(t.size))
        i = int(np.argmax(p))
        if p[i] > best_p:
            best_p, best_t = float(p[i]), float(t[i])
    if best_p < 0:
        return None
    return best_t


def _gain(
    ref: PairFitHost, word: Codeword, hop_ids: NDArray[np.int64], hop_index: int,
    one: Refinement, first: Refinement, second: Refinement, known: NDArray[np.complex128],
) -> tuple[float, float]:  # fmt: skip
    """:func:`pair_gain` and :func:`interference` of the pair ``first``, ``second`` (the
    gain over the one-echo fit ``one``):
    each echo's ``C`` with the other in and taken out (their difference is the other's
    fitted amplitude times the models' cross term), the scatter of each one's hops with the
    other taken out (the larger of the two)."""
    fits = (first, second)
    echoes = [EchoFit(hop_index, f.t_s, f.alpha, f.amplitude) for f in fits]
    c = np.empty(2, np.complex128)
    model = np.empty(2)
    cross = []
    rss = 0.0
    for k, f in enumerate(fits):
        slots = ref.hop_slots(hop_ids, word, f.t_s, f.alpha)
        if slots is None:
            return -math.inf, 0.0
        args = (*ref.slot_tables, slots, *word.hops, ref.fs_hz, ref.hop_len_s)
        other = echoes[1 - k]
        rows = _with(known, ref.echo_rows([other], f.t_s))
        c[k], model[k], _ = _sums(args, known, f.t_s, f.alpha, ref.m_hops)
        c_out, _, terms = _sums(args, rows, f.t_s, f.alpha, ref.m_hops)
        # C_k − C_k(other out) = ½ β_other Σ s_other s_k*.
        cross.append(2.0 * (c[k] - c_out) / other.amplitude if other.amplitude != 0 else 0j)
        rss = max(rss, hop_scatter(terms, word.hops[4]))
    slots = ref.hop_slots(hop_ids, word, one.t_s, one.alpha)
    if slots is None:
        return -math.inf, 0.0
    args = (*ref.slot_tables, slots, *word.hops, ref.fs_hz, ref.hop_len_s)
    c_one, e_one, _ = _sums(args, known, one.t_s, one.alpha, ref.m_hops)
    explained_one = 2.0 * abs(c_one) ** 2 / e_one if e_one > 0 else 0.0
    # Σ s₂ s₁*, read from either side (the second's, conjugated).
    g = 0.5 * (cross[0] + np.conj(cross[1]))
    samples = float(model[0]) / float(np.sum(word.hops[4]))
    gain = pair_gain(c, complex(g), model, explained_one, rss, samples, ref.m_hops)
    return gain, interference(c, complex(g), model)


def _sums(
    args: tuple[Any, ...], known: NDArray[np.complex128], t: float, alpha: float, m_hops: int
) -> tuple[complex, float, NDArray[np.complex128]]:
    """``C``, the model's ``E_s`` and each hop's term (shape ``(M,)``) at ``(t, alpha)``
    with ``known`` taken out."""
    per_hop = np.empty((1, m_hops), np.complex128)
    c, model = np.empty(1, np.complex128), np.empty(1)
    candidate_sums(
        *args, np.array([t]), np.array([alpha]), np.zeros(1), c, model, np.empty(1), per_hop,
        known,
    )  # fmt: skip
    return complex(c[0]), float(model[0]), per_hop[0]
