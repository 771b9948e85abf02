"""Random-cyclic-code HFC-CW (seed §4.2; SPEC §2.2).

``N_F`` tones and a cyclic code ``c_0 … c_{L−1}`` repeated forever. Constraints [R]: no
immediate repeat (wrap-around included) and every cyclic window of ``W`` hops distinct, so any
``W`` consecutive hops identify the position in the period. Codes are drawn at random under the
constraints from a seeded generator; optionally the candidate with the largest minimum
distance ``d_min`` (fewest coincidences between codewords) is kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError

IntArray = NDArray[np.int64]

# Node expansions per randomised depth-first attempt before restarting with fresh randomness.
_EXPANSIONS_PER_ATTEMPT = 20_000
_MAX_ATTEMPTS = 50
#: The most codes a search may draw (``candidates``): each costs about 0.3 ms (N_F = 4-8,
#: L = 17-64), so this many take about half a minute.
MAX_CANDIDATES = 100_000


def distinct_window_count(n_tones: int, window: int) -> int:
    """How many distinct no-repeat windows of ``window`` hops exist: ``N_F (N_F − 1)^(W−1)``.

    >>> distinct_window_count(4, 2), distinct_window_count(4, 3)
    (12, 36)
    """
    return n_tones * (n_tones - 1) ** (window - 1)


def validate_code_request(n_tones: int, length: int, window: int) -> None:
    """Refuse a code request that no search can satisfy, naming the field and what to do."""
    if not isinstance(n_tones, (int, np.integer)) or n_tones < 2:
        raise ConfigError(
            "n_tones", n_tones, "an integer >= 2", "a no-repeat code needs at least two tones"
        )
    if not isinstance(length, (int, np.integer)) or length < 2:
        raise ConfigError("code_length", length, "an integer >= 2")
    if n_tones == 2 and length % 2:
        raise ConfigError(
            "code_length",
            length,
            "even with 2 tones (the code must alternate, wrap-around included)",
            "use an even length or more tones",
        )
    if not isinstance(window, (int, np.integer)) or window < 1:
        raise ConfigError("window", window, "an integer >= 1")
    if window > length:
        raise ConfigError(
            "code_length", length, f">= the window W = {window} (a code holds its windows)",
            f"lengthen the code to >= {window} or shorten the window (--window)",
        )  # fmt: skip
    available = distinct_window_count(int(n_tones), int(window))
    if available < length:
        raise ConfigError(
            "window",
            window,
            f"large enough that N_F·(N_F−1)^(W−1) >= L = {length}; with N_F = {n_tones} and "
            f"W = {window} only {available} distinct windows exist",
            "increase the window W or the number of tones, or shorten the code",
        )


def cyclic_windows(code: ArrayLike, window: int) -> IntArray:
    """The ``window``-hop cyclic windows *ending* at each hop, shape ``(L, window)``.

    Row ``i`` holds ``c_{i−window+1} … c_i`` (indices mod L).

    >>> cyclic_windows([0, 1, 2], 2).tolist()
    [[2, 0], [0, 1], [1, 2]]
    """
    c = np.asarray(code, dtype=np.int64)
    n = c.shape[0]
    idx = (np.arange(n)[:, None] + np.arange(-window + 1, 1)[None, :]) % n
    return c[idx]


def has_unique_windows(code: ArrayLike, window: int) -> bool:
    """True if every cyclic window of ``window`` hops occurs once per period."""
    w = cyclic_windows(code, window)
    return bool(np.unique(w, axis=0).shape[0] == w.shape[0])


def has_no_repeat(code: ArrayLike) -> bool:
    """True if no hop repeats the previous tone, wrap-around included."""
    c = np.asarray(code)
    return bool(np.all(c != np.roll(c, 1)))


def coincidence_matrix(code: ArrayLike, m_hops: int) -> IntArray:
    """Coincidences between the M-hop codewords, shape ``(L, L)`` [R, SPEC §2.2].

    ``W^M[i, j]`` counts the positions ``m < M`` where the windows ending at hops ``i`` and
    ``j`` use the same tone: ``Σ_m [c_{i−m} = c_{j−m}]``. The diagonal is ``M``.

    >>> coincidence_matrix([0, 1, 2, 1], 2).tolist()
    [[2, 0, 1, 0], [0, 2, 0, 1], [1, 0, 2, 0], [0, 1, 0, 2]]
    """
    if m_hops < 1:
        raise ConfigError("M", m_hops, ">= 1 hop")
    c = np.asarray(code, dtype=np.int64)
    wins = cyclic_windows(c, m_hops)  # (L, M)
    n_tones = int(c.max()) + 1
    onehot = (wins[:, :, None] == np.arange(n_tones)[None, None, :]).astype(np.int64)
    return np.einsum("imk,jmk->ij", onehot, onehot)


def minimum_distance(code: ArrayLike, m_hops: int) -> int:
    """``d_min = M − max_{i≠j} W^M[i, j]``: hops by which any two codewords differ at least.

    >>> minimum_distance([0, 1, 2, 1], 2)
    1
    """
    w = coincidence_matrix(code, m_hops)
    off = w - np.diag(np.diag(w)) - np.eye(w.shape[0], dtype=np.int64)  # diagonal -> -1
    return int(m_hops - off.max()) if w.shape[0] > 1 else int(m_hops)


def is_orthogonal(code: ArrayLike, m_hops: int, d_min: int) -> bool:
    """The orthogonality check [R]: ``max_{i≠j} W^M[i, j] <= M − d_min``.

    A wrong codeword then collects at most ``(M − d_min)/M`` of the correct one's energy.
    """
    return minimum_distance(code, m_hops) >= d_min


def occupancy(code: ArrayLike, n_tones: int) -> NDArray[np.uint8]:
    """The time–frequency occupancy array, shape ``(N_F, L)``: one mark per column.

    Row ``k`` is tone ``k`` (lowest first), column ``n`` hop ``n``.

    >>> occupancy([0, 2, 1], 3).tolist()
    [[1, 0, 0], [0, 0, 1], [0, 1, 0]]
    """
    c = np.asarray(code, dtype=np.int64)
    out = np.zeros((n_tones, c.shape[0]), dtype=np.uint8)
    on = c >= 0
    out[c[on], np.flatnonzero(on)] = 1
    return out


@dataclass(frozen=True)
class RandomCyclicCode:
    """A random cyclic code and its figures of merit.

    Attributes: ``code`` (tone index per hop, shape ``(L,)``), ``n_tones``, ``window`` (W),
    ``seed`` (the integer seed of the search), ``m_hops`` (the M the distance refers to) and
    ``d_min`` (:func:`minimum_distance` at that M).
    """

    code: IntArray
    n_tones: int
    window: int
    seed: int
    m_hops: int
    d_min: int

    @property
    def length(self) -> int:
        """Code length L (hops per period)."""
        return int(self.code.shape[0])

    def coincidences(self, m_hops: int | None = None) -> IntArray:
        """:func:`coincidence_matrix` of this code (default M = ``m_hops``)."""
        return coincidence_matrix(self.code, self.m_hops if m_hops is None else m_hops)

    def occupancy(self) -> NDArray[np.uint8]:
        """:func:`occupancy` of this code."""
        return occupancy(self.code, self.n_tones)


def _search_one(
    n_tones: int, length: int, window: int, rng: np.random.Generator
) -> IntArray | None:
    """One randomised depth-first search with backtracking; None if the budget runs out."""
    code = np.empty(length, dtype=np.int64)
    seen: set[tuple[int, ...]] = set()
    # Per depth: the candidate tones still to try, in random order.
    options: list[list[int]] = [[] for _ in range(length)]
    options[0] = rng.permutation(n_tones).tolist()
    depth = 0
    expansions = 0
    pushed: list[tuple[int, ...] | None] = [None] * length
    while 0 <= depth < length:
        previous = pushed[depth]
        if previous is not None:
            seen.discard(previous)
            pushed[depth] = None
        if not options[depth]:
            depth -= 1
            continue
        expansions += 1
        if expansions > _EXPANSIONS_PER_ATTEMPT:
            return None
        tone = options[depth].pop()
        if depth > 0 and tone == code[depth - 1]:
            continue
        if depth == length - 1 and tone == code[0]:
            continue
        code[depth] = tone
        if depth >= window - 1:
            win = tuple(code[depth - window + 1 : depth + 1].tolist())
            if win in seen:
                continue
            seen.add(win)
            pushed[depth] = win
        if depth == length - 1:
            # The W − 1 windows that wrap around must be new as well.
            if has_unique_windows(code, window):
                return code.copy()
            continue
        depth += 1
        options[depth] = rng.permutation(n_tones).tolist()
    return None


def random_cyclic_code(
    n_tones: int,
    length: int,
    window: int,
    seed: int = 0,
    *,
    candidates: int = 1,
    m_hops: int | None = None,
) -> RandomCyclicCode:
    """Draw a random cyclic code under the constraints, reproducibly from ``seed``.

    Parameters
    ----------
    n_tones:
        Number of tones N_F (>= 2).
    length:
        Code length L, hops per period.
    window:
        W: every cyclic window of W hops is distinct.
    seed:
        Seed of the search (``numpy.random.default_rng``).
    candidates:
        Draw this many valid codes and keep the one with the largest ``d_min`` at ``m_hops``
        (ties: the first drawn).
    m_hops:
        The correlator length M for ``d_min``; default ``window``.

    Examples
    --------
    >>> c = random_cyclic_code(4, 17, 3, seed=1)
    >>> c.length, has_no_repeat(c.code), has_unique_windows(c.code, 3)
    (17, True, True)
    """
    validate_code_request(n_tones, length, window)
    if not 1 <= candidates <= MAX_CANDIDATES:
        raise ConfigError(
            "candidates",
            candidates,
            f"1 to {MAX_CANDIDATES} (each code drawn costs about 0.3 ms)",
            "draw fewer codes; the best d_min rarely improves after a few hundred",
        )
    m = int(window if m_hops is None else m_hops)
    if m < 1:
        raise ConfigError("M", m, ">= 1 hop")
    rng = np.random.default_rng(seed)
    best: RandomCyclicCode | None = None
    found = 0
    for _ in range(_MAX_ATTEMPTS * candidates):
        code = _search_one(int(n_tones), int(length), int(window), rng)
        if code is None:
            continue
        found += 1
        d = minimum_distance(code, m)
        if best is None or d > best.d_min:
            best = RandomCyclicCode(code, int(n_tones), int(window), int(seed), m, d)
        if found >= candidates:
            break
    if best is None:
        raise ConfigError(
            "window",
            window,
            f"a window for which a code exists; no code with N_F = {n_tones}, L = {length}, "
            f"W = {window} was found in {_MAX_ATTEMPTS} randomised searches",
            "increase W or N_F, shorten L, or try another --seed",
        )
    return best
