"""Image sources of a rectangular tank (Allen & Berkley 1979), to any reflection order.

The water fills ``0 <= x <= L``, ``0 <= y <= W``, ``-D <= z <= 0``. Along each axis an image
of a point ``p`` is ``(1 − 2 q) p + offset`` with a parity ``q`` in {0, 1} and a cell index
``m`` (any integer); it reflects ``|m − q|`` times on the low boundary and ``|m|`` times on
the high one:

- x: offset ``2 m L``; low = wall x=0, high = wall x=L;
- y: offset ``2 m W``; low = wall y=0, high = wall y=W;
- z: offset ``2 D (m − q)``; low = the bottom z=−D, high = the surface z=0.

The order of an image is the total number of reflections; its gain is the product of the
boundaries' pressure reflection coefficients, each to the power of its count (the surface's
−1 flips the sign once per surface bounce). Up to order ``N`` there are
``(2N + 1)(2N² + 2N + 3)/3`` images: 1, 7, 25, 63, 129 for N = 0 … 4.

An image is the linear map ``p ↦ sign ⊙ p + offset`` (``sign`` in {±1}³), so the image of a
moving point moves with it (velocity ``sign ⊙ v``), and a ray leaving the real point towards
``x`` leaves along ``sign ⊙ (x − image)``: :func:`departure_directions`.

>>> from sim_devices.acoustics.tank_box import Tank
>>> im = box_images(Tank(10.0, 4.0, 3.0, 0.9, 0.8, -1.0), 1)
>>> len(im), im.order.tolist()
(7, [0, 1, 1, 1, 1, 1, 1])
>>> im.positions((1.0, 2.0, -1.0))[1:3].tolist()
[[-1.0, 2.0, -1.0], [19.0, 2.0, -1.0]]
>>> [round(g, 2) for g in im.gain.tolist()]
[1.0, 0.9, 0.9, 0.9, 0.9, 0.8, -1.0]
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from sim_devices.acoustics.trajectory import FloatArray, as_point

if TYPE_CHECKING:
    from sim_devices.acoustics.tank_box import Tank

#: Boundary names in the column order of :attr:`ImageSet.counts`.
BOUNDARIES = ("wall x=0", "wall x=L", "wall y=0", "wall y=W", "bottom", "surface")

#: Highest image order accepted (the image count grows as N³: 129 at 4, 1561 at 10).
MAX_IMAGE_ORDER = 40


def check_order(order: int, field: str = "tank.image_order") -> int:
    """``order`` as an int after checking it is an integer in ``0 … MAX_IMAGE_ORDER``."""
    if isinstance(order, bool) or int(order) != order or not 0 <= order <= MAX_IMAGE_ORDER:
        raise ConfigError(
            field,
            order,
            f"an integer from 0 to {MAX_IMAGE_ORDER} (reflections)",
            "0 is the direct path only, 1 adds every single-bounce image",
        )
    return int(order)


@dataclass(frozen=True)
class ImageSet:
    """Images of a tank up to some order (``K`` of them), order 0 (the point itself) first.

    ``sign`` (K, 3) in {±1}; ``offset`` (K, 3) m; ``counts`` (K, 6) reflections on each of
    :data:`BOUNDARIES`; ``order`` (K,) their sum; ``gain`` (K,) the product of reflection
    coefficients (dimensionless, signed).
    """

    sign: FloatArray
    offset: FloatArray
    counts: NDArray[np.int64]
    order: NDArray[np.int64]
    gain: FloatArray

    def __len__(self) -> int:
        return int(self.order.shape[0])

    def positions(self, point: ArrayLike) -> FloatArray:
        """Image positions (m, shape ``(K, 3)``) of one point (m, shape ``(3,)``)."""
        p = as_point(point, "point")
        return self.sign * p + self.offset

    def label(self, k: int) -> str:
        """The boundaries image ``k`` reflects on, e.g. ``"wall x=0+surface×2"``; ``"direct"``."""
        parts = [
            name if c == 1 else f"{name}×{c}"
            for name, c in zip(BOUNDARIES, self.counts[k].tolist(), strict=True)
            if c
        ]
        return "+".join(parts) if parts else "direct"


def _axis_images(order: int) -> list[tuple[int, int, int, int]]:
    """(parity q, cell m, low count, high count) of one axis with at most ``order`` bounces."""
    out = []
    for m in range(-order, order + 1):
        for q in (0, 1):
            low, high = abs(m - q), abs(m)
            if low + high <= order:
                out.append((q, m, low, high))
    return out


def box_images(tank: Tank, order: int) -> ImageSet:
    """Every image of ``tank`` with at most ``order`` reflections (see the module docstring),
    sorted by order, then by the reflection counts (a fixed, documented order)."""
    n = check_order(order)
    axes = _axis_images(n)
    rows = []
    for ax, ay, az in itertools.product(axes, axes, axes):
        counts = (ax[2], ax[3], ay[2], ay[3], az[2], az[3])
        if sum(counts) <= n:
            rows.append((sum(counts), counts, (ax[0], ay[0], az[0]), (ax[1], ay[1], az[1])))
    rows.sort(key=lambda r: (r[0], tuple(-c for c in r[1]), r[2], r[3]))
    q = np.array([r[2] for r in rows], dtype=np.float64)
    m = np.array([r[3] for r in rows], dtype=np.float64)
    counts_arr = np.array([r[1] for r in rows], dtype=np.int64)
    size = np.array([tank.length_m, tank.width_m, tank.depth_m])
    offset = 2.0 * m * size
    offset[:, 2] = 2.0 * tank.depth_m * (m[:, 2] - q[:, 2])
    coeff = np.array(
        [
            tank.wall_reflection,
            tank.wall_reflection,
            tank.wall_reflection,
            tank.wall_reflection,
            tank.bottom_reflection,
            tank.surface_reflection,
        ]
    )
    gain = np.prod(coeff[None, :] ** counts_arr, axis=1)
    return ImageSet(
        sign=1.0 - 2.0 * q,
        offset=offset,
        counts=counts_arr,
        order=counts_arr.sum(axis=1),
        gain=gain,
    )


def image_count(order: int) -> int:
    """Number of images with at most ``order`` reflections: ``(2N+1)(2N²+2N+3)/3``.

    >>> [image_count(n) for n in range(5)]
    [1, 7, 25, 63, 129]
    """
    n = check_order(order)
    return (2 * n + 1) * (2 * n * n + 2 * n + 3) // 3


def departure_directions(images: ImageSet, source: ArrayLike, toward: ArrayLike) -> FloatArray:
    """Unit vectors (shape ``(K, 3)``) along which each image path leaves ``source`` (m) to
    reach ``toward`` (m): ``sign ⊙ (toward − image)`` normalised. By reciprocity this is also
    the direction each path arrives from at ``source`` when ``source`` receives."""
    d = images.sign * (as_point(toward, "toward") - images.positions(source))
    return d / np.sqrt(np.sum(d * d, axis=1))[:, None]
