"""The Doppler hypothesis grid of the unit correlators (SPEC §3, step 2).

Hypotheses are uniform in radial speed over ``±max_speed`` (m/s, positive closing); each has
the time-scale factor ``α_d = (c + v_d)/(c − v_d)``, the received hop length
``L_d = T_h·fs/α_d`` (samples, fractional) and the unit-correlator window
``N_d = round(L_d)`` (samples). A weight per hypothesis implements the reverberation band
[R]: hypotheses with ``|v_d|`` below ``reverb_speed_mps`` get ``reverb_weight`` (0 excludes
them from the Doppler decision, a value in (0, 1) down-weights them).

>>> g = doppler_grid(30.0, 5, 1500.0, 0.01, 10_000.0, reverb_speed_mps=10.0)
>>> g.speeds_mps.tolist(), g.lengths.tolist(), g.weights.tolist()
([-30.0, -15.0, 0.0, 15.0, 30.0], [104, 102, 100, 98, 96], [1.0, 1.0, 0.0, 1.0, 1.0])
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError

FloatArray = NDArray[np.float64]

#: The most Doppler hypotheses a receiver's grid holds: each is a row of its correlators
#: (GCAS: per codeword and hop; the matched-filter bank: per replica), so memory and work grow
#: with it (10^8 asked 3 GiB of GCAS, 12.7 GiB of the bank); hypotheses closer than a small
#: fraction of the Doppler resolution (c / (2 f M T_h), a few m/s on att) add nothing.
MAX_HYPOTHESES = 4096


def check_n_doppler(n_doppler: Any) -> int:
    """``n_doppler``, the count of a receiver's Doppler hypotheses, as an int in 1 ..
    :data:`MAX_HYPOTHESES`; else a ConfigError naming ``n_doppler``. The one check of every
    receiver with a Doppler grid (GCAS through :func:`doppler_grid`, the baselines).

    >>> check_n_doppler(64), check_n_doppler(np.int64(15))
    (64, 15)
    """
    whole = isinstance(n_doppler, numbers.Integral) or (
        isinstance(n_doppler, float) and n_doppler.is_integer()
    )
    if isinstance(n_doppler, bool) or not whole or not 1 <= n_doppler <= MAX_HYPOTHESES:
        raise ConfigError(
            "n_doppler",
            n_doppler,
            f"an integer in 1 .. {MAX_HYPOTHESES}",
            "hypotheses closer than the Doppler resolution add nothing: leave it out for"
            " the receiver's default",
        )
    return int(n_doppler)


@dataclass(frozen=True)
class DopplerGrid:
    """``D`` Doppler hypotheses; every array has shape ``(D,)``.

    Attributes: ``speeds_mps`` (m/s, closing positive), ``alphas`` (dimensionless),
    ``exact_lengths`` (``L_d``, samples), ``lengths`` (``N_d``, samples, int64), ``weights``
    (reverberation-band weights), ``sound_speed_mps`` (m/s), ``hop_s`` (s), ``fs_hz`` (Hz).
    """

    speeds_mps: FloatArray
    alphas: FloatArray
    exact_lengths: FloatArray
    lengths: NDArray[np.int64]
    weights: FloatArray
    sound_speed_mps: float
    hop_s: float
    fs_hz: float

    @property
    def size(self) -> int:
        """Number of hypotheses D."""
        return int(self.speeds_mps.shape[0])

    @property
    def speed_step_mps(self) -> float:
        """Spacing of the speed grid, m/s (0 for a single hypothesis)."""
        return float(self.speeds_mps[1] - self.speeds_mps[0]) if self.size > 1 else 0.0

    def frequencies(self, tones_hz: NDArray[np.float64], center_hz: float) -> FloatArray:
        """Unit-correlator baseband frequencies ``ν[d, k] = α_d f_k − f_c``, Hz, ``(D, K)``."""
        return self.alphas[:, None] * np.asarray(tones_hz, dtype=np.float64)[None, :] - center_hz


def speed_to_alpha(speed_mps: float | FloatArray, c: float) -> FloatArray:
    """``α = (c + v)/(c − v)``."""
    v = np.asarray(speed_mps, dtype=np.float64)
    return (c + v) / (c - v)


def alpha_to_speed(alpha: float | FloatArray, c: float) -> FloatArray:
    """``v = c (α − 1)/(α + 1)``, m/s.

    >>> round(float(alpha_to_speed(1.013423, 1500.0)), 3)
    10.0
    """
    a = np.asarray(alpha, dtype=np.float64)
    return c * (a - 1.0) / (a + 1.0)


def doppler_grid(
    max_speed_mps: float,
    n_hypotheses: int,
    sound_speed_mps: float,
    hop_s: float,
    fs_hz: float,
    *,
    reverb_speed_mps: float = 0.0,
    reverb_weight: float = 0.0,
) -> DopplerGrid:
    """Build the grid (see the module docstring); ``fs_hz`` is the correlator sample rate."""
    c = float(sound_speed_mps)
    if not (math.isfinite(c) and c > 0):
        raise ConfigError("sound_speed_mps", sound_speed_mps, "> 0 m/s")
    if not (math.isfinite(max_speed_mps) and 0 <= max_speed_mps < c):
        raise ConfigError("max_speed_mps", max_speed_mps, f"0 <= v < c = {c} m/s")
    n_hypotheses = check_n_doppler(n_hypotheses)
    if n_hypotheses > 1 and max_speed_mps == 0:
        raise ConfigError("max_speed_mps", max_speed_mps, "> 0 m/s for more than one hypothesis")
    if not (math.isfinite(reverb_speed_mps) and reverb_speed_mps >= 0):
        raise ConfigError("reverb_speed_mps", reverb_speed_mps, ">= 0 m/s")
    if not (math.isfinite(reverb_weight) and 0 <= reverb_weight <= 1):
        raise ConfigError("reverb_weight", reverb_weight, "in [0, 1]")
    speeds = (
        np.linspace(-max_speed_mps, max_speed_mps, int(n_hypotheses))
        if n_hypotheses > 1
        else np.zeros(1)
    )
    alphas = speed_to_alpha(speeds, c)
    exact = hop_s * fs_hz / alphas
    lengths = np.round(exact).astype(np.int64)
    weights = np.where(np.abs(speeds) < reverb_speed_mps, float(reverb_weight), 1.0)
    if not np.any(weights > 0):
        raise ConfigError(
            "reverb_speed_mps",
            reverb_speed_mps,
            f"< max_speed_mps = {max_speed_mps} m/s (or reverb_weight > 0)",
            "the reverberation band excludes every Doppler hypothesis",
        )
    return DopplerGrid(speeds, alphas, exact, lengths, weights, c, float(hop_s), float(fs_hz))
