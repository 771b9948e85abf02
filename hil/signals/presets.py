"""Parameter presets (SPEC §6, all [R]: no carrier, rate, hop time or speed was published)
and the design checks every waveform must pass.

=============  ==========================================  ========  =======  =========
preset         use                                         f_c       B_w      fs
=============  ==========================================  ========  =======  =========
``att``        the seed's scale: near-range sonar, fast    30 kHz    4.4 kHz  100 kHz
               vehicle, 0–50 kn, ranges <= 100 m
``tank-audio`` tank with a 192 kHz audio interface          60 kHz    8 kHz    192 kHz
``tank-board`` tank with the DAC/ADC board                  150 kHz   20 kHz   1 MHz
=============  ==========================================  ========  =======  =========

Per-family values that SPEC §6 does not fix are chosen so that every check passes and are
stated in :data:`PRESETS` (for example the three-state hop of the tank presets, chosen so that
``Δf·T_h`` is an integer).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.errors import ConfigError
from hil.signals.schedule import HopSchedule
from hil.signals.waveforms import (
    FAMILIES,
    HFCCW_FAMILIES,
    TONE_HOP_FAMILIES,
    WaveformSpec,
    build_schedule,
    doppler_scale,
)

# Fresh water at 20 °C (Bilaniuk & Wong 1993 / Marczak 1997 agree to 0.1 m/s): 1482.3 m/s.
# A tank run computes c from the logged temperature instead; this is the preset default.
FRESH_WATER_20C_MPS = 1482.3

# Tolerance for "Δf·T_h is an integer" (relative to the product).
_INTEGER_TOLERANCE = 1e-6
#: The longest sounding hop, samples: the synthesiser and the receivers hold a hop's tone
#: table and correlators in memory (2**24 float64 samples = 128 MiB per table).
MAX_HOP_SAMPLES = 1 << 24
#: Sound speeds a design may assume, m/s (water of 0-95 °C and 0-42 ppt, with margin; the
#: experiment file's ``tank.sound_speed_mps`` allows the same).
WATER_SOUND_SPEED_MPS = (1300.0, 1700.0)


@dataclass(frozen=True)
class Preset:
    """A named parameter set: shared values plus per-family overrides."""

    name: str
    description: str
    base: WaveformSpec
    family_overrides: dict[str, dict[str, Any]] = field(default_factory=dict)

    def spec(self, family: str | None = None, **overrides: Any) -> WaveformSpec:
        """The :class:`WaveformSpec` of ``family`` under this preset, then ``overrides``."""
        fam = self.base.family if family is None else family
        if fam not in FAMILIES:
            raise ConfigError("family", fam, f"one of {', '.join(FAMILIES)}")
        spec = self.base.with_overrides(family=fam, **self.family_overrides.get(fam, {}))
        return spec.with_overrides(**overrides)


_ATT = WaveformSpec(
    family="random-cyclic",
    center_hz=30_000.0,
    bandwidth_hz=4_400.0,
    fs_hz=100_000.0,
    n_tones=4,
    hop_s=0.010,
    code_length=17,
    window=3,
    sound_speed_mps=1500.0,
    max_speed_mps=25.72,  # 50 kn
    min_speed_mps=5.0,  # ~10 kn: slower targets sit in the reverberation band at this T_h
    max_range_m=100.0,
    sweep_s=0.2,  # FMCW: c·T/2 = 150 m > 100 m
    pulse_s=0.010,
    pri_s=0.2,
)
_TANK_AUDIO = WaveformSpec(
    family="random-cyclic",
    center_hz=60_000.0,
    bandwidth_hz=8_000.0,
    fs_hz=192_000.0,
    n_tones=4,
    hop_s=0.010,
    code_length=17,
    window=3,
    sound_speed_mps=FRESH_WATER_20C_MPS,
    max_speed_mps=2.0,
    min_speed_mps=1.5,
    max_range_m=20.0,
    sweep_s=0.1,
    pulse_s=0.002,
    pri_s=0.05,
)
_TANK_BOARD = WaveformSpec(
    family="random-cyclic",
    center_hz=150_000.0,
    bandwidth_hz=20_000.0,
    fs_hz=1_000_000.0,
    n_tones=4,
    hop_s=0.005,
    code_length=17,
    window=3,
    sound_speed_mps=FRESH_WATER_20C_MPS,
    max_speed_mps=2.0,
    min_speed_mps=1.2,
    max_range_m=20.0,
    sweep_s=0.1,
    pulse_s=0.001,
    pri_s=0.05,
)

PRESETS: dict[str, Preset] = {
    "att": Preset(
        "att",
        "the seed's scale: near-range CAS on a fast underwater vehicle (0–50 kn, <= 100 m)",
        _ATT,
        {
            # SPEC §6: 15 ms for three states (Δf·T_h = 22); L_c = 5 because L_c = 3 gives an
            # unambiguous range of only 90 m.
            "three-state": {"n_tones": 3, "hop_s": 0.015, "order": 5},
            # Welch p = 11: 10 tones, Δf = 440 Hz; 25 ms makes Δf·T_h = 11.
            "costas": {"hop_s": 0.025},
            "costas-lfm": {"hop_s": 0.025},
        },
    ),
    "tank-audio": Preset(
        "tank-audio",
        "water tank with a 192 kHz audio interface (towed target <= 2 m/s, 0.5–20 m)",
        _TANK_AUDIO,
        {
            # Δf = 8/3 kHz: 15 ms gives Δf·T_h = 40 and a Doppler cell below 1.5 m/s.
            "three-state": {"n_tones": 3, "hop_s": 0.015, "order": 5},
            "costas": {"hop_s": 0.010},  # Δf = 800 Hz → 8
            "costas-lfm": {"hop_s": 0.010},
        },
    ),
    "tank-board": Preset(
        "tank-board",
        "water tank with the DAC/ADC board at 1 MS/s (towed target <= 2 m/s, 0.5–20 m)",
        _TANK_BOARD,
        {
            # Δf = 20/3 kHz: 4.5 ms gives Δf·T_h = 30 and a Doppler cell below 1.2 m/s.
            "three-state": {"n_tones": 3, "hop_s": 0.0045, "order": 5},
            "costas": {"hop_s": 0.005},  # Δf = 2 kHz → 10
            "costas-lfm": {"hop_s": 0.005},
        },
    ),
}


def get_preset(name: str) -> Preset:
    """The preset called ``name``; a clear error lists the known ones."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ConfigError("preset", name, f"one of {', '.join(PRESETS)}") from None


def check_design(spec: WaveformSpec, schedule: HopSchedule | None = None) -> HopSchedule:
    """Build the schedule of ``spec`` and run the design checks; return the schedule.

    Checks (each raises :class:`~hil.errors.ConfigError` naming the field and what to do):

    1. Sample rate above the Nyquist rate of the highest Doppler-scaled frequency:
       ``fs > 2·α_max·f_max`` with ``α_max = (c + v_max)/(c − v_max)``.
    2. Tone-hop families: ``Δf·T_h`` an integer, so the tones are orthogonal over a hop (this
       survives Doppler, since α scales both).
    3. Unambiguous range ``c·period/2`` at least the maximum range of interest.
    4. HFC-CW families: the Doppler shift of the slowest target of interest at the lowest tone,
       ``(α_min − 1)·f_min``, is at least one unit-correlator resolution cell ``1/T_h``.

    >>> sch = check_design(get_preset("att").spec("random-cyclic"))
    >>> sch.period_hops, round(sch.unambiguous_range_m(1500.0), 1)
    (17, 127.5)
    """
    c = spec.sound_speed_mps
    if not (math.isfinite(c) and c > 0):
        raise ConfigError("sound_speed_mps", c, "> 0 m/s")
    for name in ("max_speed_mps", "min_speed_mps"):
        v = getattr(spec, name)
        if not (math.isfinite(v) and 0 <= v < c):
            raise ConfigError(name, v, f"0 <= v < c = {c} m/s")
    if not (math.isfinite(spec.max_range_m) and spec.max_range_m > 0):
        raise ConfigError("max_range_m", spec.max_range_m, "> 0 m")
    if not (math.isfinite(spec.fs_hz) and spec.fs_hz > 0):
        raise ConfigError("fs_hz", spec.fs_hz, "> 0 Hz")
    sch = build_schedule(spec) if schedule is None else schedule
    _check_hop_length(sch, spec.fs_hz)

    alpha_max = doppler_scale(spec.max_speed_mps, c)
    f_max = sch.max_frequency_hz()
    nyquist = 2.0 * alpha_max * f_max
    if spec.fs_hz <= nyquist:
        raise ConfigError(
            "fs_hz",
            spec.fs_hz,
            f"> {nyquist:.1f} Hz (Nyquist: 2 × highest tone {f_max:.1f} Hz × Doppler "
            f"{alpha_max:.5f} at {spec.max_speed_mps} m/s)",
            "raise --fs or lower the carrier/bandwidth",
        )

    if spec.family in TONE_HOP_FAMILIES and sch.n_tones > 1:
        df = float(sch.tones_hz[1] - sch.tones_hz[0])
        product = df * sch.hop_s
        if abs(product - round(product)) > _INTEGER_TOLERANCE * max(1.0, product):
            lo = math.floor(product) / df
            hi = math.ceil(product) / df
            raise ConfigError(
                "hop_s",
                sch.hop_s,
                f"a multiple of 1/Δf = {1 / df:.6g} s so that Δf·T_h is an integer "
                f"(Δf = {df:.6g} Hz gives Δf·T_h = {product:.6g})",
                f"try {' or '.join(f'--hop {h:.6g}' for h in (lo, hi) if h > 0)}, "
                "or change the bandwidth",
            )

    r_unamb = sch.unambiguous_range_m(c)
    if r_unamb < spec.max_range_m:
        raise ConfigError(
            "max_range_m",
            spec.max_range_m,
            f"<= the unambiguous range c·period/2 = {r_unamb:.2f} m "
            f"(period {sch.period_s:.6g} s at c = {c} m/s)",
            "lengthen the code or the hop/sweep/PRI, or lower --max-range",
        )

    if spec.family in HFCCW_FAMILIES:
        hop = sch.hop_s
        alpha_min = doppler_scale(spec.min_speed_mps, c)
        shift = (alpha_min - 1.0) * float(sch.tones_hz.min())
        cell = 1.0 / hop
        if shift < cell:
            need = c * cell / (2.0 * float(sch.tones_hz.min()) + cell)
            raise ConfigError(
                "min_speed_mps",
                spec.min_speed_mps,
                f">= {need:.3f} m/s, so that the Doppler shift at the lowest tone "
                f"({shift:.1f} Hz) is at least one resolution cell 1/T_h = {cell:.1f} Hz",
                "raise --min-speed, lengthen --hop, or raise the carrier",
            )
    return sch


def check_water_sound_speed(field: str, value: float, hint: str) -> float:
    """``value`` (m/s) when it is a sound speed of water (:data:`WATER_SOUND_SPEED_MPS`), else
    a ConfigError naming ``field`` with ``hint``.

    >>> check_water_sound_speed("--sound-speed", 1e12, "e.g. 1500")
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: --sound-speed = 1000000000000.0 is not allowed: must be a sound \
speed of water, 1300 .. 1700 m/s; e.g. 1500
    """
    lo, hi = WATER_SOUND_SPEED_MPS
    if not (math.isfinite(value) and lo <= value <= hi):
        raise ConfigError(field, value, f"a sound speed of water, {lo:g} .. {hi:g} m/s", hint)
    return float(value)


def _check_hop_length(sch: HopSchedule, fs_hz: float) -> None:
    """Refuse a sounding hop (of one period) longer than :data:`MAX_HOP_SAMPLES` at
    ``fs_hz`` (Hz): its tables would not fit in memory."""
    hops = sch.hops(0, sch.period_hops)
    sounding = hops.duration_s[hops.amplitude > 0]
    longest = float(np.max(sounding)) if sounding.size else 0.0
    limit = MAX_HOP_SAMPLES / fs_hz
    if not longest * fs_hz <= MAX_HOP_SAMPLES:
        fields = {"fmcw-saw": "sweep_s", "fmcw-tri": "sweep_s", "cw-pulse": "pulse_s",
                  "lfm-pulse": "pulse_s"}  # fmt: skip
        field = fields.get(sch.family, "hop_s")
        raise ConfigError(
            field,
            longest,
            f"<= {limit:.6g} s ({MAX_HOP_SAMPLES} samples at {fs_hz:g} Hz, the longest hop "
            "held in memory)",
            "shorten it (more hops in a period give the same unambiguous range)",
        )
