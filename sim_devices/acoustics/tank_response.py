"""The tank's own echoes: transmitter → boundaries → receiver, and the diffuse late tail.

Without any target a hydrophone in a tank hears the transmitter through every boundary
path. For a transmitter and a receiver at rest this is a fixed impulse response ``h`` (in
µPa per unit source amplitude at 1 m), convolved with the transmit signal
(:class:`TankEchoes`):

- **specular part**: every image of the transmitter with 1 … N reflections
  (:func:`~sim_devices.acoustics.images.box_images`, order 0 is the direct blast's job),
  amplitude ``R_k · D_tx(u_k) · D_rx(u_k') · 10^(−α r_k / 20000) / r_k`` at delay
  ``r_k / c`` (``r_k`` the image-to-receiver distance, m; ``D`` the transducers' pressure
  responses in the path's departure and arrival directions; ``α`` the absorption, dB/km),
  placed with the band-limited Kaiser-sinc kernel of
  :mod:`~sim_devices.acoustics.fractional_delay` (32 taps);
- **diffuse tail** (optional): seeded Gaussian noise from the first delay at which the
  order-N image set is incomplete (the nearest order-(N+1) image) to ``tail_s``, with the
  statistical energy envelope of a diffuse field (Polack): per sample variance

      σ²(t) = (4π c / (V fs)) · f(t) · ⟨b_tx⟩ ⟨b_rx⟩ · 10^(−6 t / T60) · 10^(−α c t / 10000)

  ``V`` the volume (m³), ``⟨b⟩`` each transducer's mean intensity response over all
  directions (a diffuse field comes from everywhere), ``T60`` from the boundaries'
  absorption ``α_k = 1 − R_k²`` by Eyring (default) or Sabine (:func:`t60_s`), and ``f(t)``
  the fraction of the images arriving around ``t`` (2 ms bins) that the order-N set lacks:
  the tail is the energy of the images left out, not a second copy of those kept. ``4π c
  t² dt / V`` images arrive in ``dt`` (one per tank volume), each with energy ``1/(c t)²``,
  hence the ``4π c / V``.

The convolution runs in fixed frames of absolute sample index (overlap-add, FFT), so the
stream is the same for any read sizes.

Example: the two reverberation times of a 6 × 3 × 2 m tank (walls 0.9, bottom 0.8).

>>> from sim_devices.acoustics.tank import Tank
>>> tank = Tank(6.0, 3.0, 2.0, 0.9, 0.8, -1.0)
>>> round(t60_s(tank, 1480.0, "sabine"), 4), round(t60_s(tank, 1480.0, "eyring"), 4)
(0.1009, 0.0913)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from hil.errors import ConfigError
from sim_devices.acoustics.directivity import Transducer
from sim_devices.acoustics.fixed_convolver import FixedResponseConvolver
from sim_devices.acoustics.fractional_delay import kaiser_sinc
from sim_devices.acoustics.images import box_images, check_order
from sim_devices.acoustics.tank import Tank
from sim_devices.acoustics.trajectory import FloatArray, as_point

#: Half-length (taps each side) and Kaiser β of the kernel that places each image.
KERNEL_HALF = 16
KERNEL_BETA = 9.0
#: Width of the bins (s) in which the tail's missing-image fraction f(t) is counted.
TAIL_BIN_S = 2e-3
#: T60 formulas :func:`t60_s` knows.
T60_FORMULAS = ("eyring", "sabine")


def boundary_areas(tank: Tank) -> tuple[FloatArray, FloatArray]:
    """Areas (m², shape ``(6,)``) and energy absorption coefficients ``1 − R²`` of the
    boundaries in the order of :data:`~sim_devices.acoustics.images.BOUNDARIES`."""
    L, W, D = tank.length_m, tank.width_m, tank.depth_m
    areas = np.array([W * D, W * D, L * D, L * D, L * W, L * W])
    r = np.array([tank.wall_reflection] * 4 + [tank.bottom_reflection, tank.surface_reflection])
    return areas, 1.0 - r * r


def t60_s(tank: Tank, sound_speed_mps: float, formula: str = "eyring") -> float:
    """Reverberation time (s, 60 dB of energy decay) of ``tank``.

    Sabine ``T60 = 24 ln 10 · V / (c Σ S_k α_k)``; Eyring ``T60 = 24 ln 10 · V / (−c S
    ln(1 − ᾱ))`` with ``ᾱ = Σ S_k α_k / S``. ``inf`` when nothing absorbs.
    """
    if formula not in T60_FORMULAS:
        raise ConfigError("tank.t60_formula", formula, f"one of {', '.join(T60_FORMULAS)}")
    areas, alpha = boundary_areas(tank)
    volume = tank.length_m * tank.width_m * tank.depth_m
    absorbed = float(np.sum(areas * alpha))
    if absorbed <= 0.0:
        return math.inf
    k = 24.0 * math.log(10.0) * volume / float(sound_speed_mps)
    if formula == "sabine":
        return k / absorbed
    mean_alpha = absorbed / float(np.sum(areas))
    if mean_alpha >= 1.0:
        return 0.0
    return k / (-float(np.sum(areas)) * math.log1p(-mean_alpha))


@dataclass(frozen=True)
class TankEchoSettings:
    """What of the tank's own sound to synthesise (units in the names).

    ``order``: reflections of the specular paths (1 … 40; 0 means none); ``tail``: add the
    diffuse late tail; ``t60_formula``: ``"eyring"`` or ``"sabine"``; ``tail_s``: length of
    the response (s; default: the T60, at most ``max_tail_s``); ``seed``: the tail's noise.
    """

    order: int = 3
    tail: bool = True
    t60_formula: str = "eyring"
    tail_s: float | None = None
    max_tail_s: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        check_order(self.order, "tank.own_echo_order")
        if self.t60_formula not in T60_FORMULAS:
            raise ConfigError(
                "tank.t60_formula", self.t60_formula, f"one of {', '.join(T60_FORMULAS)}"
            )
        for name in ("tail_s", "max_tail_s"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and 0 < v <= 10.0):
                raise ConfigError(f"tank.{name}", v, "> 0 and <= 10 s")


@dataclass(frozen=True)
class SpecularPaths:
    """The specular tx → boundaries → rx paths: delay (s), amplitude (per unit source
    amplitude at 1 m), order and image index, each shape ``(K,)``, sorted by delay."""

    delay_s: FloatArray
    amplitude: FloatArray
    order: FloatArray
    distance_m: FloatArray


def specular_paths(
    tank: Tank,
    tx_m: ArrayLike,
    rx_m: ArrayLike,
    order: int,
    sound_speed_mps: float,
    *,
    tx: Transducer | None = None,
    rx: Transducer | None = None,
    absorption_db_per_km: float = 0.0,
) -> SpecularPaths:
    """Every image path of 1 … ``order`` reflections from ``tx_m`` to ``rx_m`` (m)."""
    n = check_order(order, "tank.own_echo_order")
    src, dst = as_point(tx_m, "tx_m"), as_point(rx_m, "rx_m")
    tank.check_inside(src, "transmitter position")
    tank.check_inside(dst, "receiver position")
    images = box_images(tank, n)
    keep = images.order >= 1
    pos = images.positions(src)[keep]
    d = dst - pos
    r = np.sqrt(np.sum(d * d, axis=1))
    if r.size and np.min(r) <= 0:
        raise ConfigError(
            "transmitter position", src.tolist(), "not on a boundary", "move it into the water"
        )
    amp = images.gain[keep] / r
    if absorption_db_per_km > 0:
        amp = amp * 10.0 ** (-absorption_db_per_km * r / 20000.0)
    if tx is not None:
        sign = images.sign[keep]
        amp = amp * tx.response(sign * d)
    if rx is not None:
        amp = amp * rx.response(pos - dst)
    idx = np.argsort(r, kind="stable")
    return SpecularPaths(
        r[idx] / sound_speed_mps, amp[idx], images.order[keep][idx].astype(float), r[idx]
    )


def _missing_fraction(tank: Tank, src: FloatArray, dst: FloatArray, order: int, t: FloatArray,
                      c: float) -> FloatArray:  # fmt: skip
    """Fraction of the images arriving at times ``t`` (s) that have more than ``order``
    reflections: 1 − (order-N images per bin) / (4π r² Δr / V), clipped to [0, 1]."""
    volume = tank.length_m * tank.width_m * tank.depth_m
    pos = box_images(tank, order).positions(src)
    r_have = np.sqrt(np.sum((dst - pos) ** 2, axis=1))
    edges = np.arange(0.0, float(t[-1]) + 2 * TAIL_BIN_S, TAIL_BIN_S) * c
    have, _ = np.histogram(r_have, bins=edges)
    expected = 4.0 * np.pi / 3.0 * (edges[1:] ** 3 - edges[:-1] ** 3) / volume
    frac = np.clip(1.0 - have / expected, 0.0, 1.0)
    k = np.minimum((t * c / (TAIL_BIN_S * c)).astype(np.int64), frac.size - 1)
    return frac[k]


def tank_impulse_response(
    tank: Tank,
    tx_m: ArrayLike,
    rx_m: ArrayLike,
    sound_speed_mps: float,
    fs_hz: float,
    settings: TankEchoSettings,
    *,
    tx: Transducer | None = None,
    rx: Transducer | None = None,
    absorption_db_per_km: float = 0.0,
) -> FloatArray:
    """``h[n]`` (per unit source amplitude at 1 m, shape ``(m,)``): the tank's own response
    from ``tx_m`` to ``rx_m`` at ``fs_hz`` (see the module docstring). Sample ``n`` is delay
    ``n / fs_hz``."""
    c, fs = float(sound_speed_mps), float(fs_hz)
    src, dst = as_point(tx_m, "tx_m"), as_point(rx_m, "rx_m")
    t60 = t60_s(tank, c, settings.t60_formula)
    paths = specular_paths(
        tank, src, dst, settings.order, c, tx=tx, rx=rx, absorption_db_per_km=absorption_db_per_km
    ) if settings.order >= 1 else None  # fmt: skip
    last_path = float(paths.delay_s[-1]) if paths is not None and paths.delay_s.size else 0.0
    length_s = settings.tail_s
    if length_s is None:
        length_s = min(t60, settings.max_tail_s) if settings.tail else last_path
    length_s = max(length_s, last_path)
    n_taps = int(math.ceil(length_s * fs)) + 2 * KERNEL_HALF + 1
    h = np.zeros(n_taps)
    if paths is not None and paths.delay_s.size:
        pos = paths.delay_s * fs
        base = np.floor(pos).astype(np.int64)
        taps = np.arange(-KERNEL_HALF + 1, KERNEL_HALF + 1)
        idx = base[:, None] + taps[None, :]
        w = kaiser_sinc(pos[:, None] - idx, KERNEL_HALF, KERNEL_BETA) * paths.amplitude[:, None]
        ok = (idx >= 0) & (idx < n_taps)
        np.add.at(h, idx[ok], w[ok])
    if settings.tail and math.isfinite(t60):
        # The first delay the order-N set is incomplete at: the nearest order-(N+1) image.
        nxt = box_images(tank, settings.order + 1)
        extra = nxt.order == settings.order + 1
        r_next = np.sqrt(np.sum((dst - nxt.positions(src)[extra]) ** 2, axis=1))
        t0 = float(np.min(r_next)) / c
        n0 = int(math.ceil(t0 * fs))
        if n0 < n_taps:
            t = np.arange(n0, n_taps) / fs
            var = 4.0 * np.pi * c / (tank.length_m * tank.width_m * tank.depth_m * fs)
            var *= (tx.mean_intensity() if tx is not None else 1.0) * (
                rx.mean_intensity() if rx is not None else 1.0
            )
            env = var * _missing_fraction(tank, src, dst, settings.order, t, c)
            env *= 10.0 ** (-6.0 * t / t60 - absorption_db_per_km * c * t / 10000.0)
            rng = np.random.default_rng(settings.seed)
            h[n0:] += rng.standard_normal(t.size) * np.sqrt(env)
    return h


class TankEchoes:
    """The tank's own echoes as a stream: ``h`` convolved with the transmit samples.

    ``source(n0, count)`` gives the transmit (unit amplitude) at samples ``n0 …`` (any
    ``n0``, also negative: the transmission before sample 0); ``amplitude`` scales ``h``
    (the source's pressure amplitude at 1 m, µPa·m). :meth:`generate` returns the next
    samples in µPa. Frames of ``frame`` samples (at least the response's length, a power of
    two) are rendered by overlap-add at fixed absolute indices, so any read sizes give the
    same stream.
    """

    def __init__(
        self, h: FloatArray, source: Callable[[int, int], FloatArray], amplitude: float = 1.0
    ) -> None:
        self.h = np.asarray(h, dtype=np.float64) * float(amplitude)
        self.source = source
        self._convolve = FixedResponseConvolver(self.h)
        self.frame = max(16384, 1 << int(math.ceil(math.log2(max(self.h.size, 2)))))
        self.position = 0
        self._frame_index = -1
        self._frame = np.zeros(0)
        # The tail of the previous frames' convolutions reaching into the next ones.
        self._carry = np.zeros(self.h.size)
        self._primed = False

    def _prime(self) -> None:
        # The transmission before sample 0 rings on into the first frame: convolve the
        # response's length of earlier transmit and keep what reaches past sample 0.
        m = self.h.size
        before = self.source(-m, m)
        full = self._convolve(before)
        self._carry = np.zeros(m)
        self._carry[: m - 1] = full[m : 2 * m - 1]
        self._primed = True

    def _render_next(self) -> None:
        if not self._primed:
            self._prime()
        k = self._frame_index + 1
        f = self.frame
        y = self._convolve(self.source(k * f, f))
        m = self.h.size
        y[:m] += self._carry
        self._frame = y[:f]
        carry = np.zeros(m)
        rest = y[f:]
        carry[: rest.size] = rest[:m]
        self._carry = carry
        self._frame_index = k

    def generate(self, n_samples: int) -> FloatArray:
        """The next ``n_samples`` of the stream (µPa), shape ``(n_samples,)``."""
        out = np.empty(int(n_samples))
        done = 0
        while done < n_samples:
            m = self.position + done
            k = m // self.frame
            while self._frame_index < k:
                self._render_next()
            off = m - k * self.frame
            take = min(int(n_samples) - done, self.frame - off)
            out[done : done + take] = self._frame[off : off + take]
            done += take
        self.position += int(n_samples)
        return out
