"""Every transmit waveform of the project as a :class:`~hil.signals.schedule.HopSchedule`.

HFC-CW families (SPEC §2): ``three-state`` and ``random-cyclic``. Comparison waveforms
(SPEC §4): ``fmcw-saw`` and ``fmcw-tri`` (continuous FMCW), ``costas`` (Costas-coded
frequency-hopped CW, Welch construction), ``costas-lfm`` (Costas-staggered LFM sub-chirps),
``cw-pulse`` and ``lfm-pulse`` (pulsed, for reference). All share the schedule's evaluation
interface, so the simulator, receivers and diagnostics treat them alike.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any, Literal

import numpy as np

from hil.errors import ConfigError
from hil.signals.costas import is_costas, welch_costas
from hil.signals.random_cyclic import random_cyclic_code
from hil.signals.schedule import HopSchedule, tone_grid
from hil.signals.three_state import three_state_code

FAMILIES: tuple[str, ...] = (
    "random-cyclic",
    "three-state",
    "fmcw-saw",
    "fmcw-tri",
    "costas",
    "costas-lfm",
    "cw-pulse",
    "lfm-pulse",
)
HFCCW_FAMILIES: tuple[str, ...] = ("random-cyclic", "three-state")
TONE_HOP_FAMILIES: tuple[str, ...] = ("random-cyclic", "three-state", "costas", "costas-lfm")

#: The :class:`WaveformSpec` fields every family reads: the carrier and band, the sample rate
#: and the design checks' sound speed, speeds and range (:func:`~hil.signals.presets.check_design`).
COMMON_FIELDS: frozenset[str] = frozenset(
    {"center_hz", "bandwidth_hz", "fs_hz", "sound_speed_mps", "max_speed_mps", "min_speed_mps",
     "max_range_m"}
)  # fmt: skip
#: The fields each family reads besides :data:`COMMON_FIELDS` (:func:`build_schedule`).
FAMILY_FIELDS: dict[str, frozenset[str]] = {
    "random-cyclic": frozenset(
        {"n_tones", "hop_s", "code_length", "window", "seed", "candidates", "m_hops"}
    ),
    "three-state": frozenset({"n_tones", "hop_s", "order", "sequence"}),
    "fmcw-saw": frozenset({"sweep_s"}),
    "fmcw-tri": frozenset({"sweep_s"}),
    "costas": frozenset({"costas_prime", "hop_s"}),
    "costas-lfm": frozenset({"costas_prime", "hop_s", "subchirp_bandwidth_hz"}),
    "cw-pulse": frozenset({"pulse_s", "pri_s"}),
    "lfm-pulse": frozenset({"pulse_s", "pri_s"}),
}


def check_family_fields(family: str, given: dict[str, Any]) -> None:
    """Refuse a field of ``given`` (field -> value; ``None``: not given) that ``family``
    does not read (:data:`COMMON_FIELDS`, :data:`FAMILY_FIELDS`): a design option a
    family ignores would otherwise be dropped silently."""
    if family not in FAMILY_FIELDS:
        raise ConfigError("family", family, f"one of {', '.join(FAMILIES)}")
    reads = COMMON_FIELDS | FAMILY_FIELDS[family]
    for field, value in given.items():
        if value is not None and field not in reads:
            users = [f for f, fields in FAMILY_FIELDS.items() if field in fields]
            raise ConfigError(
                field,
                value,
                f"a setting the {family} family reads",
                f"only {', '.join(users)} read it: drop it, or choose that family",
            )


Family = Literal[
    "random-cyclic", "three-state", "fmcw-saw", "fmcw-tri", "costas", "costas-lfm",
    "cw-pulse", "lfm-pulse",
]  # fmt: skip


@dataclass(frozen=True)
class WaveformSpec:
    """All design parameters of a waveform. Units: Hz, seconds, m/s, metres.

    Which fields a family reads is listed in :func:`build_schedule`; the others are ignored.

    Attributes
    ----------
    family: one of :data:`FAMILIES`.
    center_hz: carrier f_c, Hz.
    bandwidth_hz: occupied bandwidth B_w (tone families: ``N_F·Δf``; sweeps: swept band), Hz.
    fs_hz: sample rate the waveform is meant for, Hz (checked against Nyquist).
    n_tones: N_F (random-cyclic; three-state needs exactly 3).
    hop_s: hop duration T_h, s (tone-hop families).
    code_length: L (random-cyclic), hops per period.
    window: W (random-cyclic): every W-hop cyclic window is distinct.
    order: L_c (three-state), bits per codeword.
    sequence: bit source of the three-state code, ``"debruijn"`` or ``"mseq"``.
    seed: seed of the random-cyclic code search.
    candidates: random-cyclic codes drawn; the one with the largest d_min at ``m_hops`` kept.
    m_hops: correlator length M used for d_min, hops.
    sweep_s: FMCW sweep duration (one leg), s.
    costas_prime: prime p of the Welch construction (``p − 1`` tones).
    subchirp_bandwidth_hz: sweep of each costas-lfm hop, Hz (default Δf).
    pulse_s: pulse duration (cw-pulse, lfm-pulse), s.
    pri_s: pulse repetition interval, s.
    sound_speed_mps: c, m/s.
    max_speed_mps: fastest closing/opening speed of interest (Nyquist with Doppler), m/s.
    min_speed_mps: slowest target of interest (Doppler resolution check), m/s.
    max_range_m: largest range of interest (unambiguous-range check), m.
    """

    family: str = "random-cyclic"
    center_hz: float = 30_000.0
    bandwidth_hz: float = 4_400.0
    fs_hz: float = 100_000.0
    n_tones: int = 4
    hop_s: float = 0.010
    code_length: int = 17
    window: int = 3
    order: int = 5
    sequence: str = "debruijn"
    seed: int = 1
    candidates: int = 8
    m_hops: int = 10
    sweep_s: float = 0.2
    costas_prime: int = 11
    subchirp_bandwidth_hz: float | None = None
    pulse_s: float = 0.010
    pri_s: float = 0.2
    sound_speed_mps: float = 1500.0
    max_speed_mps: float = 25.72
    min_speed_mps: float = 5.0
    max_range_m: float = 100.0

    def with_overrides(self, **overrides: Any) -> WaveformSpec:
        """A copy with the given fields replaced (``None`` values are ignored)."""
        known = set(asdict(self))
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ConfigError("override", unknown, f"fields of WaveformSpec: {sorted(known)}")
        return replace(self, **{k: v for k, v in overrides.items() if v is not None})

    def to_dict(self) -> dict[str, Any]:
        """The spec as JSON-ready data."""
        return asdict(self)


def _positive(name: str, value: float, unit: str) -> float:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ConfigError(name, value, f"> 0 {unit}")
    return float(value)


def _tone_spacing(spec: WaveformSpec, n: int) -> float:
    return spec.bandwidth_hz / n


def build_schedule(spec: WaveformSpec) -> HopSchedule:
    """The hop schedule of ``spec`` (one period; continuous phase unless pulsed).

    Fields read per family:

    - ``three-state``: center_hz, bandwidth_hz, n_tones (= 3), hop_s, order, sequence.
    - ``random-cyclic``: center_hz, bandwidth_hz, n_tones, hop_s, code_length, window, seed,
      candidates, m_hops.
    - ``fmcw-saw`` / ``fmcw-tri``: center_hz, bandwidth_hz, sweep_s (one up-sweep; the
      triangle adds a down-sweep of the same length).
    - ``costas`` / ``costas-lfm``: center_hz, bandwidth_hz, costas_prime, hop_s,
      subchirp_bandwidth_hz.
    - ``cw-pulse`` / ``lfm-pulse``: center_hz, bandwidth_hz (LFM), pulse_s, pri_s.

    >>> s = build_schedule(WaveformSpec(family="three-state", n_tones=3, order=3, hop_s=0.015))
    >>> s.code.tolist(), np.round(s.tones_hz, 3).tolist()
    ([0, 1, 2, 0, 2, 0, 2, 1], [28533.333, 30000.0, 31466.667])
    """
    fam = spec.family
    if fam not in FAMILIES:
        raise ConfigError("family", fam, f"one of {', '.join(FAMILIES)}")
    fc = _positive("center_hz", spec.center_hz, "Hz")
    bw = _positive("bandwidth_hz", spec.bandwidth_hz, "Hz")
    params = {"family": fam, **spec.to_dict()}

    if fam == "three-state":
        if spec.n_tones != 3:
            raise ConfigError(
                "n_tones",
                spec.n_tones,
                "exactly 3 for the three-state family",
                "use --family random-cyclic for other tone counts",
            )
        hop = _positive("hop_s", spec.hop_s, "s")
        if spec.sequence not in ("debruijn", "mseq"):
            raise ConfigError("sequence", spec.sequence, "'debruijn' or 'mseq'")
        code3 = three_state_code(spec.order, spec.sequence)  # type: ignore[arg-type]
        tones = tone_grid(fc, bw, 3)
        params["bits"] = code3.bits.tolist()
        return HopSchedule.from_segments(fam, tones, code3.states, hop, params=params)

    if fam == "random-cyclic":
        hop = _positive("hop_s", spec.hop_s, "s")
        rc = random_cyclic_code(
            spec.n_tones,
            spec.code_length,
            spec.window,
            spec.seed,
            candidates=spec.candidates,
            m_hops=spec.m_hops,
        )
        tones = tone_grid(fc, bw, spec.n_tones)
        params["d_min"] = rc.d_min
        return HopSchedule.from_segments(fam, tones, rc.code, hop, params=params)

    if fam in ("fmcw-saw", "fmcw-tri"):
        sweep = _positive("sweep_s", spec.sweep_s, "s")
        f_lo, f_hi = fc - bw / 2, fc + bw / 2
        if f_lo <= 0:
            raise ConfigError("bandwidth_hz", bw, f"< 2·center_hz = {2 * fc} Hz")
        rate = bw / sweep
        if fam == "fmcw-saw":
            return HopSchedule.from_segments(
                fam, [f_lo], [0], sweep, freq_hz=[f_lo], chirp_hz_per_s=[rate], params=params
            )
        return HopSchedule.from_segments(
            fam,
            [f_lo, f_hi],
            [0, 1],
            sweep,
            freq_hz=[f_lo, f_hi],
            chirp_hz_per_s=[rate, -rate],
            params=params,
        )

    if fam in ("costas", "costas-lfm"):
        hop = _positive("hop_s", spec.hop_s, "s")
        perm = welch_costas(spec.costas_prime)
        if not is_costas(perm):  # the construction guarantees it; keep the check honest
            raise ConfigError("costas_prime", spec.costas_prime, "a prime giving a Costas array")
        n = perm.shape[0]
        tones = tone_grid(fc, bw, n)
        params["costas"] = perm.tolist()
        if fam == "costas":
            return HopSchedule.from_segments(fam, tones, perm, hop, params=params)
        sub_bw = (
            _tone_spacing(spec, n)
            if spec.subchirp_bandwidth_hz is None
            else float(spec.subchirp_bandwidth_hz)
        )
        _positive("subchirp_bandwidth_hz", sub_bw, "Hz")
        starts = tones[perm] - sub_bw / 2
        return HopSchedule.from_segments(
            fam, tones, perm, hop, freq_hz=starts, chirp_hz_per_s=sub_bw / hop, params=params
        )

    # Pulsed references: a pulse then silence; every pulse starts at phase 0.
    pulse = _positive("pulse_s", spec.pulse_s, "s")
    pri = _positive("pri_s", spec.pri_s, "s")
    if pri <= pulse:
        raise ConfigError("pri_s", pri, f"> pulse_s = {pulse} s", "lengthen the PRI")
    if fam == "cw-pulse":
        return HopSchedule.from_segments(
            fam, [fc], [0, -1], [pulse, pri - pulse], continuous_phase=False, params=params
        )
    f_lo = fc - bw / 2
    return HopSchedule.from_segments(
        fam,
        [f_lo],
        [0, -1],
        [pulse, pri - pulse],
        freq_hz=[f_lo, 0.0],
        chirp_hz_per_s=[bw / pulse, 0.0],
        continuous_phase=False,
        params=params,
    )


def doppler_scale(speed_mps: float, sound_speed_mps: float) -> float:
    """Two-way Doppler time-scale factor ``α = (c + v)/(c − v)`` (v > 0 closing).

    >>> round(doppler_scale(10.0, 1500.0), 6)
    1.013423
    """
    if not sound_speed_mps > 0:
        raise ConfigError("sound_speed_mps", sound_speed_mps, "> 0 m/s")
    if not abs(speed_mps) < sound_speed_mps:
        raise ConfigError("speed_mps", speed_mps, f"|v| < c = {sound_speed_mps} m/s")
    return (sound_speed_mps + speed_mps) / (sound_speed_mps - speed_mps)


def design_summary(schedule: HopSchedule, sound_speed_mps: float) -> dict[str, Any]:
    """Key numbers of a schedule for printing and for the schedule file."""
    out: dict[str, Any] = {
        "family": schedule.family,
        "tones_hz": schedule.tones_hz.tolist(),
        "period_hops": schedule.period_hops,
        "period_s": schedule.period_s,
        "unambiguous_delay_s": schedule.unambiguous_delay_s(),
        "unambiguous_range_m": schedule.unambiguous_range_m(sound_speed_mps),
        "band_hz": [schedule.min_frequency_hz(), schedule.max_frequency_hz()],
    }
    if schedule.family in TONE_HOP_FAMILIES:
        out["hop_s"] = schedule.hop_s
        if schedule.n_tones > 1:
            df = float(np.diff(schedule.tones_hz)[0])
            out["tone_spacing_hz"] = df
            out["df_times_hop"] = df * schedule.hop_s
    return out
