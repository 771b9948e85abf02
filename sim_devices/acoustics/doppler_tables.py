"""Doppler ratio and received-length tables (reconstruction of the seed's Tables 3.1 and 3.2).

The seed's tables are not available; their content follows from the two-way time scaling
``alpha = (c + v)/(c − v)`` (SPEC §1) and is rebuilt here [R]: for each target speed the
Doppler ratio, the received-length change rate ``1/alpha − 1``, the received length of a
transmission of given duration, and the Doppler shift ``(alpha − 1) f`` of given tones.

Examples
--------
>>> rows = doppler_table([10.0 / KNOT_MPS], duration_s=0.1, frequencies_hz=(50e3,))
>>> r = rows[0]
>>> round(r.alpha, 6), round(r.shift_hz[0]), round(r.length_change_ms, 3)
(1.013423, 671, -1.325)
>>> print(format_doppler_table(doppler_table([10, 50], frequencies_hz=(30e3,))))
speed   speed     alpha  1/alpha-1  received   change  shift @30 kHz
 (kn)   (m/s)                  (%)      (ms)     (ms)           (Hz)
-----  ------  --------  ---------  --------  -------  -------------
 10.0   5.144  1.006883    -0.6836   99.3164  -0.6836          206.5
 50.0  25.722  1.034895    -3.3718   96.6282  -3.3718         1046.8
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hil.errors import ConfigError
from sim_devices.acoustics.delay import check_sound_speed, doppler_ratio

#: One international knot in m/s (1852 m per hour).
KNOT_MPS = 1852.0 / 3600.0

#: Speeds (kn) of the default table: the seed's 0–50 kn closing range in 5 kn steps.
DEFAULT_SPEEDS_KN = tuple(float(v) for v in range(5, 55, 5))


@dataclass(frozen=True)
class DopplerRow:
    """One speed of the Doppler table.

    Attributes
    ----------
    speed_kn, speed_mps: closing speed (kn, m/s; > 0 approaching).
    alpha: time-scale factor (c + v)/(c − v).
    length_change_pct: received-length change rate 100 (1/alpha − 1) (%).
    received_length_ms: received length of the transmission, duration/alpha (ms).
    length_change_ms: received minus transmitted length (ms; < 0 when closing).
    frequencies_hz: the tones (Hz).
    shift_hz: Doppler shift (alpha − 1) f (Hz) of each tone.
    """

    speed_kn: float
    speed_mps: float
    alpha: float
    length_change_pct: float
    received_length_ms: float
    length_change_ms: float
    frequencies_hz: tuple[float, ...]
    shift_hz: tuple[float, ...]


def doppler_table(
    speeds_kn: Sequence[float] = DEFAULT_SPEEDS_KN,
    *,
    sound_speed_mps: float = 1500.0,
    duration_s: float = 0.1,
    frequencies_hz: Sequence[float] = (30e3,),
) -> list[DopplerRow]:
    """Rows of the Doppler table for closing speeds ``speeds_kn`` (kn, |v| < c).

    ``duration_s`` (s, > 0) is the transmitted length whose received length is listed;
    ``frequencies_hz`` (Hz, > 0) the tones whose shifts are listed.
    """
    c = check_sound_speed(sound_speed_mps)
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise ConfigError("duration_s", duration_s, "> 0 s and finite", "e.g. 0.1 s")
    freqs = tuple(float(f) for f in frequencies_hz)
    if not all(np.isfinite(f) and f > 0 for f in freqs):
        raise ConfigError("frequencies_hz", frequencies_hz, "finite values > 0 Hz")
    rows = []
    for kn in speeds_kn:
        if not np.isfinite(kn):
            raise ConfigError("speeds_kn", kn, "finite speeds in knots")
        v = float(kn) * KNOT_MPS
        if not abs(v) < c:
            raise ConfigError(
                "speeds_kn", kn, f"|v| < c = {c:g} m/s = {c / KNOT_MPS:.0f} kn", "check the units"
            )
        alpha = float(doppler_ratio(v, c))
        received = duration_s / alpha
        rows.append(
            DopplerRow(
                speed_kn=float(kn),
                speed_mps=v,
                alpha=alpha,
                length_change_pct=100.0 * (1.0 / alpha - 1.0),
                received_length_ms=1e3 * received,
                length_change_ms=1e3 * (received - duration_s),
                frequencies_hz=freqs,
                shift_hz=tuple((alpha - 1.0) * f for f in freqs),
            )
        )
    return rows


def format_doppler_table(rows: Sequence[DopplerRow]) -> str:
    """The rows as a plain-text table, one line per speed, shifts in Hz per tone."""
    freqs = rows[0].frequencies_hz if rows else ()
    headers = [
        ("speed", "(kn)"),
        ("speed", "(m/s)"),
        ("alpha", ""),
        ("1/alpha-1", "(%)"),
        ("received", "(ms)"),
        ("change", "(ms)"),
        *((f"shift @{f / 1e3:g} kHz", "(Hz)") for f in freqs),
    ]
    body = [
        [
            f"{r.speed_kn:.1f}",
            f"{r.speed_mps:.3f}",
            f"{r.alpha:.6f}",
            f"{r.length_change_pct:.4f}",
            f"{r.received_length_ms:.4f}",
            f"{r.length_change_ms:.4f}",
            *(f"{s:.1f}" for s in r.shift_hz),
        ]
        for r in rows
    ]
    widths = [
        max(len(h[0]), len(h[1]), *(len(line[i]) for line in body)) for i, h in enumerate(headers)
    ]
    lines = [
        "  ".join(h[0].rjust(w) for h, w in zip(headers, widths, strict=True)),
        "  ".join(h[1].rjust(w) for h, w in zip(headers, widths, strict=True)),
        "  ".join("-" * w for w in widths),
        *("  ".join(c.rjust(w) for c, w in zip(line, widths, strict=True)) for line in body),
    ]
    return "\n".join(line.rstrip() for line in lines)
