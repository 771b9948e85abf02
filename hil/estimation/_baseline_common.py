"""Helpers shared by the comparison receivers (mfbank, stft, fmcw, jifs).

Option checks with the project's :class:`~hil.errors.ConfigError` messages, input-block checks,
and the range readout ``R = c (t_rx − t_tx)/2`` with the code-period ambiguity resolved
against the maximum range. Private to :mod:`hil.estimation`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation.option_types import OptionNames
from hil.signals.schedule import HopSchedule

FloatArray = NDArray[np.float64]


def positive(field: str, value: Any, unit: str = "") -> float:
    """``value`` as a finite float > 0, else a ConfigError naming ``field``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(field, value, f"a number > 0 {unit}".rstrip()) from None
    if not (math.isfinite(v) and v > 0):
        raise ConfigError(field, value, f"a finite number > 0 {unit}".rstrip())
    return v


def positive_int(field: str, value: Any, minimum: int = 1) -> int:
    """``value`` as an int >= ``minimum``, else a ConfigError naming ``field``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ConfigError(field, value, f"an integer >= {minimum}")
    return int(value)


def reject_unknown(extra: dict[str, Any], known: Iterable[str], receiver: str) -> None:
    """Raise for option keys the receiver does not understand."""
    known_set = set(known)
    unknown = sorted(set(extra) - known_set)
    if unknown:
        raise ConfigError(
            f"receiver.options.{unknown[0]}",
            extra[unknown[0]],
            f"an option of the {receiver} receiver: {', '.join(sorted(known_set)) or 'none'}",
            "check its spelling, or choose the receiver it belongs to",
        )


def require_family(schedule: HopSchedule, allowed: Iterable[str], receiver: str) -> None:
    """Raise unless ``schedule.family`` is one this receiver can decode."""
    allowed_t = tuple(allowed)
    if schedule.family not in allowed_t:
        raise ConfigError(
            "schedule.family",
            schedule.family,
            f"one of {', '.join(allowed_t)} for the {receiver} receiver",
            "pick the receiver that matches the transmitted waveform",
        )


def check_block(block: Any, gap_before: int) -> FloatArray:
    """The input block as a 1-D float64 array, refusing NaN/inf, 2-D input and bad gaps."""
    x = np.asarray(block)
    if x.ndim != 1:
        raise ConfigError("block", f"shape {x.shape}", "a 1-D array of samples (n,)")
    if not np.issubdtype(x.dtype, np.floating) and not np.issubdtype(x.dtype, np.integer):
        raise ConfigError("block", f"dtype {x.dtype}", "real samples (float or int)")
    xf = x.astype(np.float64, copy=False)
    if not np.all(np.isfinite(xf)):
        bad = int(np.flatnonzero(~np.isfinite(xf))[0])
        raise ConfigError(
            "block",
            f"NaN/inf at sample {bad}",
            "finite samples",
            "drop or repair the bad samples and pass the hole as gap_before",
        )
    if isinstance(gap_before, bool) or not isinstance(gap_before, (int, np.integer)):
        raise ConfigError("gap_before", gap_before, "an integer >= 0 (samples)")
    if gap_before < 0:
        raise ConfigError("gap_before", gap_before, "an integer >= 0 (samples)")
    return xf


def common_options(
    fs_hz: Any, sound_speed_mps: Any, max_speed_mps: Any, max_range_m: Any, m_hops: Any
) -> tuple[float, float, float, float, int]:
    """Checked ``(fs, c, v_max, R_max, M)`` of the common constructor options."""
    fs = positive("fs_hz", fs_hz, "Hz")
    c = positive("sound_speed_mps", sound_speed_mps, "m/s")
    try:
        vmax = float(max_speed_mps)
    except (TypeError, ValueError):
        vmax = math.nan
    if not (math.isfinite(vmax) and 0 <= vmax < c):
        raise ConfigError("max_speed_mps", max_speed_mps, f"0 <= v < c = {c} m/s")
    rmax = positive("max_range_m", max_range_m, "m")
    m = positive_int("m_hops", m_hops)
    return fs, c, vmax, rmax, m


def alpha_of_speed(speed_mps: Any, c: float) -> Any:
    """Doppler time scale ``α = (c + v)/(c − v)`` (v > 0 closing); array or float."""
    return (c + speed_mps) / (c - speed_mps)


def speed_of_alpha(alpha: Any, c: float) -> Any:
    """Radial speed ``v = c (α − 1)/(α + 1)``, m/s, positive closing."""
    return c * (alpha - 1.0) / (alpha + 1.0)


def resolve_transmit_time(
    t_rx_s: float, t_tx_period0_s: float, period_s: float, max_delay_s: float
) -> tuple[float, int] | None:
    """Transmit time of a boundary and its period number, or None when out of range.

    ``t_tx_period0_s`` is the boundary's transmit time in period 0 (s). The period number
    ``q`` is chosen so the delay ``t_rx − t_tx`` lies in ``[0, period)``; a delay above
    ``max_delay_s`` (= 2 R_max / c) is out of range and gives None.

    >>> t_tx, q = resolve_transmit_time(1.05, 0.02, 0.17, 0.2)
    >>> round(t_tx, 12), q
    (1.04, 6)
    >>> resolve_transmit_time(1.05, 0.10, 0.17, 0.05) is None
    True
    """
    q = math.floor((t_rx_s - t_tx_period0_s) / period_s)
    t_tx = t_tx_period0_s + q * period_s
    if t_rx_s - t_tx > max_delay_s:
        return None
    return t_tx, q


def parabolic_peak(y_minus: float, y0: float, y_plus: float) -> tuple[float, float]:
    """Vertex offset (in steps, within [−0.5, 0.5]) and height of the parabola through 3 points.

    >>> parabolic_peak(1.0, 3.0, 2.0)
    (0.16666666666666666, 3.0416666666666665)
    """
    den = y_minus - 2.0 * y0 + y_plus
    if den >= 0.0:  # not a maximum: keep the centre sample
        return 0.0, y0
    off = 0.5 * (y_minus - y_plus) / den
    off = min(0.5, max(-0.5, off)) + 0.0  # + 0.0 turns −0.0 into 0.0
    return off, y0 - 0.25 * (y_minus - y_plus) * off


def unique_window(code: NDArray[np.int64]) -> int:
    """Smallest W such that every cyclic W-hop window of ``code`` is distinct (<= len(code)).

    >>> unique_window(np.array([0, 1, 2, 0, 2, 0, 2, 1]))
    4
    """
    p = int(code.shape[0])
    for w in range(1, p + 1):
        idx = (np.arange(p)[:, None] + np.arange(w)[None, :]) % p
        if len({tuple(r) for r in code[idx].tolist()}) == p:
            return w
    return p


class EmitsOnAnyBlock:
    """Mixin: the sample count of a receiver that may emit an estimate on any block; the
    receiver keeps ``_seen``, the samples it consumed, gaps included."""

    _seen: int

    @property
    def samples_seen(self) -> int:
        """Samples consumed so far, gaps included."""
        return self._seen

    @property
    def next_decision_index(self) -> int:
        """It may emit on any block: :attr:`samples_seen`."""
        return self.samples_seen


class RegistryConstructor:
    """Mixin: the registry's common ``from_options`` for receivers whose constructor takes
    the common options as keywords plus the receiver-specific ``OPTIONS``."""

    OPTIONS: tuple[str, ...] = ()
    name: str

    @classmethod
    def option_names(cls) -> OptionNames:
        """The receiver's own options, ``OPTIONS`` (it is not built on GCAS)."""
        return OptionNames(frozenset(cls.OPTIONS))

    @classmethod
    def from_options(
        cls,
        schedule: HopSchedule,
        fs_hz: float,
        *,
        sound_speed_mps: float,
        max_speed_mps: float,
        max_range_m: float,
        m_hops: int,
        **extra: Any,
    ) -> Any:
        """The registry constructor (:mod:`hil.estimation.registry`); ``extra`` holds the
        receiver's own options, listed in ``OPTIONS``."""
        reject_unknown(extra, cls.OPTIONS, cls.name)
        return cls(  # type: ignore[call-arg]
            schedule,
            fs_hz,
            sound_speed_mps=sound_speed_mps,
            max_speed_mps=max_speed_mps,
            max_range_m=max_range_m,
            m_hops=m_hops,
            **extra,
        )
