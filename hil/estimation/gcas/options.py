"""GCAS receiver options: the allowed values, the defaults and their validation.

Every check raises :class:`~hil.errors.ConfigError` naming the option, the value, the allowed
range and what to do; the receiver runs them before it builds anything.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation.detection import lambda_for_pfa
from hil.estimation.doppler_grid import speed_to_alpha
from hil.estimation.first_arrival import RANGE_READOUTS
from hil.signals.random_cyclic import minimum_distance
from hil.signals.schedule import HopSchedule

HFCCW_FAMILIES = ("random-cyclic", "three-state")
#: Largest correlator length accepted (the seed uses up to 29).
M_MAX = 64
#: Baseband rate over twice the highest baseband frequency (room for the filter transition).
TRANSITION_FACTOR = 1.3
CFAR_MODES = ("bank", "statistic")
#: Correlator searches: every hypothesis at every sample, or coarse-then-fine (two-stage).
SEARCH_MODES = ("full", "two-stage")
#: Default coarse step B of the two-stage search, baseband samples.
COARSE_STEP = 8
#: λ of the ``"statistic"`` CFAR when none is given (``pfa`` sets it for ``"bank"`` only).
STATISTIC_LAMBDA = 5.0
#: The keyword options of :meth:`~hil.estimation.gcas.GcasReceiver.from_options`.
OPTION_NAMES = frozenset(
    {
        "n_doppler", "coherent", "pfa", "cfar_lambda", "runner_up_ratio",
        "cfar_window_hops", "cfar_mode", "reverb_speed_mps", "reverb_weight",
        "decimation", "attenuation_db", "on_map", "search", "coarse_step",
        "range_readout", "max_spread_s", "refine", "cancel",
    }
)  # fmt: skip


def minimum_m_hops(code: NDArray[np.int64], upper: int = M_MAX) -> int:
    """Smallest M at which all M-hop codewords of the cyclic ``code`` differ (d_min >= 1).

    >>> minimum_m_hops(np.array([0, 1, 2, 0, 2, 0, 2, 1]))
    4
    """
    for m in range(1, upper + 1):
        if minimum_distance(code, m) >= 1:
            return m
    raise ConfigError("code", code.tolist(), f"a code whose codewords differ at some M <= {upper}")


def check_option_names(options: dict[str, Any]) -> None:
    """Refuse keyword options that the receiver does not have, naming the first."""
    unknown = sorted(set(options) - OPTION_NAMES)
    if unknown:
        raise ConfigError(
            f"receiver.options.{unknown[0]}",
            options[unknown[0]],
            f"an option of the gcas receiver: {', '.join(sorted(OPTION_NAMES))}",
            "check its spelling, or choose the receiver it belongs to",
        )


def check_schedule(schedule: HopSchedule, fs_hz: float, c: float, v_max: float) -> None:
    """The schedule is an HFC-CW code of equal, non-silent hops designed for ``fs_hz``, whose
    Doppler-scaled top tone (at ``v_max`` m/s) stays below Nyquist."""
    if schedule.family not in HFCCW_FAMILIES:
        raise ConfigError(
            "schedule.family",
            schedule.family,
            f"an HFC-CW family ({' or '.join(HFCCW_FAMILIES)})",
            "GCAS decodes tone-hop codes; use the fmcw, stft or mfbank receiver for this waveform",
        )
    if np.any(schedule.code < 0):
        raise ConfigError("schedule.code", schedule.code.tolist(), "no silent hops")
    schedule.hop_s  # noqa: B018 - raises for unequal hops
    design_fs = schedule.params.get("fs_hz")
    if design_fs is not None and not math.isclose(float(design_fs), fs_hz, rel_tol=1e-9):
        raise ConfigError(
            "fs_hz",
            fs_hz,
            f"the rate the schedule was designed for, {float(design_fs):g} Hz",
            "resample the input or rebuild the schedule for this rate",
        )
    nyquist = 2.0 * float(speed_to_alpha(v_max, c)) * schedule.max_frequency_hz()
    if fs_hz <= nyquist:
        raise ConfigError(
            "fs_hz", fs_hz, f"> {nyquist:.1f} Hz (Nyquist of the Doppler-scaled top tone)"
        )


def check_geometry(
    schedule: HopSchedule,
    fs_hz: float,
    sound_speed_mps: float,
    max_speed_mps: float,
    max_range_m: float,
    m_hops: int,
) -> None:
    """The rate, sound speed, speed span, correlator length and range limit are usable with
    ``schedule``: ``m_hops`` tells its codewords apart and ``max_range_m`` is unambiguous."""
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise ConfigError("fs_hz", fs_hz, "> 0 Hz")
    c = float(sound_speed_mps)
    if not (math.isfinite(c) and c > 0):
        raise ConfigError("sound_speed_mps", sound_speed_mps, "> 0 m/s")
    if not (math.isfinite(max_speed_mps) and 0 < max_speed_mps < c):
        raise ConfigError("max_speed_mps", max_speed_mps, f"0 < v < c = {c} m/s")
    check_schedule(schedule, float(fs_hz), c, float(max_speed_mps))
    m_min = minimum_m_hops(schedule.code.astype(np.int64))
    if int(m_hops) != m_hops or not m_min <= m_hops <= M_MAX:
        raise ConfigError(
            "m_hops",
            m_hops,
            f"an integer in {m_min}..{M_MAX} for this code (codewords are distinct, "
            f"d_min >= 1, from M = {m_min}; {M_MAX} is the largest correlator supported)",
            "M larger than the code allows or too short to tell codewords apart",
        )
    if not (math.isfinite(max_range_m) and max_range_m > 0):
        raise ConfigError("max_range_m", max_range_m, "> 0 m")
    r_unamb = schedule.unambiguous_range_m(c)
    if max_range_m > r_unamb:
        raise ConfigError(
            "max_range_m",
            max_range_m,
            f"<= the unambiguous range c·period/2 = {r_unamb:.2f} m",
            "lengthen the code or the hop, or lower the maximum range",
        )


def check_modes(
    cfar_mode: str,
    runner_up_ratio: float,
    cfar_window_hops: float,
    search: str,
    range_readout: str,
) -> None:
    """The detection and search settings are among the allowed ones."""
    if cfar_mode not in CFAR_MODES:
        raise ConfigError("cfar_mode", cfar_mode, f"one of {', '.join(CFAR_MODES)}")
    if not (math.isfinite(runner_up_ratio) and runner_up_ratio >= 1):
        raise ConfigError("runner_up_ratio", runner_up_ratio, ">= 1")
    if not (math.isfinite(cfar_window_hops) and cfar_window_hops >= 1):
        raise ConfigError("cfar_window_hops", cfar_window_hops, ">= 1 hop")
    if search not in SEARCH_MODES:
        raise ConfigError("search", search, f"one of {', '.join(SEARCH_MODES)}")
    if range_readout not in RANGE_READOUTS:
        raise ConfigError("range_readout", range_readout, f"one of {', '.join(RANGE_READOUTS)}")


def resolve_cfar_lambda(
    cfar_lambda: float | None, pfa: float, m_hops: int, n_codewords: int, cfar_mode: str
) -> float:
    """λ of the threshold ``μ̂ + λσ̂``: ``cfar_lambda`` when given, else from ``pfa`` (bank
    CFAR, whose noise moments are known) or :data:`STATISTIC_LAMBDA`."""
    if cfar_lambda is None:
        if cfar_mode == "bank":
            return lambda_for_pfa(pfa, m_hops, n_codewords, False)
        return STATISTIC_LAMBDA
    if not math.isfinite(cfar_lambda):
        raise ConfigError("cfar_lambda", cfar_lambda, "a finite number")
    return float(cfar_lambda)


def check_coarse_step(coarse_step: int, n_min: int) -> int:
    """The coarse step B of the two-stage search: 1 to a quarter of the shortest hop window
    ``n_min`` (baseband samples)."""
    top = max(1, n_min // 4)
    if int(coarse_step) != coarse_step or not 1 <= coarse_step <= top:
        raise ConfigError(
            "coarse_step",
            coarse_step,
            f"an integer in 1..{top} (a quarter of the shortest hop, baseband samples)",
            "the coarse response of a hop boundary is a tent about two hops wide",
        )
    return int(coarse_step)
