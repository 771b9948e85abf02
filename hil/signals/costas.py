"""Costas arrays for the frequency-coded CW comparison waveforms.

A Costas array of order ``n`` is a permutation ``a`` of ``0..n−1`` whose displacement vectors
``(h, a[i+h] − a[i])`` are all distinct: every row ``h`` of its difference triangle holds
distinct values. Its narrowband ambiguity function has no sidelobe above ``1/n``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError


def is_prime(p: int) -> bool:
    """Trial-division primality test for small integers.

    >>> [n for n in range(20) if is_prime(n)]
    [2, 3, 5, 7, 11, 13, 17, 19]
    """
    if p < 2:
        return False
    return all(p % d for d in range(2, int(p**0.5) + 1))


def primitive_roots(p: int) -> list[int]:
    """All primitive roots modulo the prime ``p``, ascending.

    >>> primitive_roots(11)
    [2, 6, 7, 8]
    """
    if not is_prime(p):
        raise ConfigError("prime", p, "a prime number", "Welch construction needs a prime p")
    if p == 2:
        return [1]
    phi = p - 1
    factors = [q for q in range(2, phi + 1) if phi % q == 0 and is_prime(q)]
    return [g for g in range(2, p) if all(pow(g, phi // q, p) != 1 for q in factors)]


def welch_costas(p: int, root: int | None = None, shift: int = 0) -> NDArray[np.int64]:
    """Welch (exponential) Costas array of order ``p − 1``: ``a_i = g^(i+shift) mod p − 1``.

    ``g`` is a primitive root of the prime ``p`` (default the smallest); ``shift`` rotates the
    array, which stays Costas. Values are in ``0..p−2``.

    >>> welch_costas(5).tolist()
    [1, 3, 2, 0]
    """
    roots = primitive_roots(p)
    g = roots[0] if root is None else int(root)
    if g not in roots:
        raise ConfigError("root", root, f"a primitive root of {p}: one of {roots}")
    i = np.arange(1 + shift, p + shift)
    return np.array([pow(g, int(k) % (p - 1), p) - 1 for k in i], dtype=np.int64)


def difference_triangle(perm: ArrayLike) -> list[NDArray[np.int64]]:
    """Rows ``h = 1..n−1`` of the difference triangle: ``a[i+h] − a[i]`` for ``i < n − h``."""
    a = np.asarray(perm, dtype=np.int64)
    return [a[h:] - a[:-h] for h in range(1, a.shape[0])]


def is_costas(perm: ArrayLike) -> bool:
    """True if ``perm`` is a permutation whose difference-triangle rows have distinct entries.

    >>> is_costas([1, 3, 2, 0]), is_costas([0, 1, 2, 3])
    (True, False)
    """
    a = np.asarray(perm, dtype=np.int64)
    if sorted(a.tolist()) != list(range(a.shape[0])):
        return False
    return all(np.unique(row).shape[0] == row.shape[0] for row in difference_triangle(a))
