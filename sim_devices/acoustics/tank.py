"""Tank model: a rectangular tank's boundaries and the target's echo paths through them.

The tank occupies ``0 <= x <= L``, ``0 <= y <= W``, ``-D <= z <= 0``: four walls, the bottom
``z = -D`` and the water surface ``z = 0`` (pressure release, reflection coefficient −1).

Echo paths, per round trip (:func:`echo_paths`). The target is a point scatterer: the field
that reaches it from the transmitter is the tank's Green's function, the sum over the images
of the transmitter (:mod:`sim_devices.acoustics.images`), and what it scatters reaches the
receiver through the same sum over the images of the receiver. The echo is the product of
the two sums: every pair (outgoing image ``i``, returning image ``j``), with gain
``R_i · R_j``, a product of ``order(i) + order(j)`` reflection coefficients.
``image_order = N`` keeps the pairs with at most N reflections *in all*
(``order(i) + order(j) <= N``): 1, 13, 85, 377, 1289 paths for N = 0 … 4.

Per round trip and not per leg, because the order is then the expansion order in the
reflection coefficients: a truncation at N keeps every term with N factors and none with
more, as pyroomacoustics' ``max_order`` does for a one-way path and as the tank's own echoes
(:mod:`~sim_devices.acoustics.tank_response`) do. A per-leg cut (N on each leg) would keep
the wall-out/wall-back echo (two reflections) but drop out-direct/back-via-two-walls, of the
same order and about as strong.

Each path is a :class:`~sim_devices.acoustics.delay.TwoWayPath` from an image of the
transmitter through the (real, moving) target to an image of the receiver; the images are
:class:`BoxImage` trajectories, so a moving transducer's images move with it. The sign
vectors of the two images (:attr:`EchoPath.tx_sign`, :attr:`EchoPath.rx_sign`) give the
directions in which the path leaves the transmitter and reaches the receiver, for their
directivity.

The direct blast is the transmitter-to-receiver leakage: a one-way path from a transmitter
``separation_m`` away from the receiver with spherical spreading and a coupling gain (dB).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from sim_devices.acoustics.images import box_images, check_order
from sim_devices.acoustics.tank_box import Tank
from sim_devices.acoustics.trajectory import FloatArray, Trajectory, as_point


class BoxImage:
    """The image of a trajectory in the tank's boundaries: ``sign ⊙ p(t) + offset`` (m),
    velocity ``sign ⊙ v(t)`` (see :mod:`sim_devices.acoustics.images`).

    >>> from sim_devices.acoustics.trajectory import Fixed
    >>> BoxImage(Fixed((1.0, 2.0, -1.0)), (-1, 1, 1), (0, 0, 0)).position(np.zeros(1))
    array([[-1.,  2., -1.]])
    """

    def __init__(self, inner: Trajectory, sign: ArrayLike, offset_m: ArrayLike) -> None:
        self._inner = inner
        self.sign = as_point(sign, "image.sign")
        self.offset = as_point(offset_m, "image.offset_m")
        #: A still trajectory's image is still (see :attr:`~.trajectory.Fixed.still`).
        self.still = bool(getattr(inner, "still", False))

    @property
    def max_speed_mps(self) -> float | None:
        return self._inner.max_speed_mps

    def position(self, t: ArrayLike) -> FloatArray:
        p = self._inner.position(t) * self.sign
        p += self.offset
        return p

    def velocity(self, t: ArrayLike) -> FloatArray:
        return self._inner.velocity(t) * self.sign


_UNIT = np.ones(3)


@dataclass(frozen=True)
class EchoPath:
    """One echo path: transmitter, target, receiver trajectories and a linear gain.

    ``tx_sign`` / ``rx_sign`` (shape ``(3,)``, ±1): the sign vectors of the transmitter's and
    receiver's images; the path leaves the transmitter along ``tx_sign ⊙ (target − tx)`` and
    reaches the receiver from ``rx_sign ⊙ (target − rx)`` (``tx``, ``rx`` the image
    positions). ``orders``: reflections on the outgoing and on the returning leg (their sum
    is at most the image order).
    """

    name: str
    tx: Trajectory
    target: Trajectory
    rx: Trajectory
    gain: float
    tx_sign: FloatArray = field(default_factory=lambda: _UNIT)
    rx_sign: FloatArray = field(default_factory=lambda: _UNIT)
    orders: tuple[int, int] = (0, 0)


def echo_path_count(order: int) -> int:
    """Number of echo paths of :func:`echo_paths` in a tank at ``order``.

    >>> [echo_path_count(n) for n in range(5)]
    [1, 13, 85, 377, 1289]
    """
    n = check_order(order)
    per_order = [1] + [4 * k * k + 2 for k in range(1, n + 1)]  # images with k reflections
    return sum(per_order[a] * per_order[b] for a in range(n + 1) for b in range(n + 1 - a))


def echo_paths(
    sonar: Trajectory, target: Trajectory, tank: Tank | None, order: int
) -> Iterator[EchoPath]:
    """The direct echo first, then in a tank every image pair with at most ``order``
    reflections in all (see the module docstring), outgoing image major.

    >>> from sim_devices.acoustics.trajectory import Fixed
    >>> t = Tank(10.0, 4.0, 3.0)
    >>> paths = list(echo_paths(Fixed((1, 2, -1)), Fixed((5, 2, -1)), t, 1))
    >>> len(paths), [p.name for p in paths][:3]
    (13, ['direct', 'out direct / back wall x=0', 'out direct / back wall x=L'])
    >>> two = list(echo_paths(Fixed((1, 2, -1)), Fixed((5, 2, -1)), t, 2))
    >>> len(two), [(p.gain, p.orders) for p in two if p.name == "out surface / back surface"]
    (85, [(1.0, (1, 1))])
    """
    n = check_order(order)
    if tank is None or n == 0:
        yield EchoPath("direct", sonar, target, sonar, 1.0)
        return
    images = box_images(tank, n)
    legs = [
        sonar if k == 0 else BoxImage(sonar, images.sign[k], images.offset[k])
        for k in range(len(images))
    ]
    for i in range(len(images)):
        for j in range(len(images)):
            if images.order[i] + images.order[j] > n:
                continue
            name = "direct" if i == j == 0 else f"out {images.label(i)} / back {images.label(j)}"
            yield EchoPath(
                name,
                legs[i],
                target,
                legs[j],
                float(images.gain[i] * images.gain[j]),
                images.sign[i],
                images.sign[j],
                (int(images.order[i]), int(images.order[j])),
            )


class Offset:
    """A trajectory displaced by a constant vector (m): the transmitter next to a receiver."""

    def __init__(self, inner: Trajectory, offset_m: ArrayLike) -> None:
        self._inner = inner
        self._d = as_point(offset_m, "direct_blast.offset_m")
        #: A still trajectory displaced is still (see :attr:`~.trajectory.Fixed.still`).
        self.still = bool(getattr(inner, "still", False))

    @property
    def max_speed_mps(self) -> float | None:
        return self._inner.max_speed_mps

    def position(self, t: ArrayLike) -> FloatArray:
        return self._inner.position(t) + self._d

    def velocity(self, t: ArrayLike) -> FloatArray:
        return self._inner.velocity(t)
