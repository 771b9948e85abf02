"""``waveform_af_sidelobe``: the peak sidelobe of a random-cyclic HFC-CW code's periodic AF.

Each trial draws a random cyclic code (seeded from the trial's SeedSequence), builds its
HFC-CW schedule and computes the periodic ambiguity function over one period
(:func:`hil.signals.ambiguity.periodic_af`) on the Doppler grid ``k / period``,
``k = −doppler_bins … doppler_bins``. The peak sidelobe level (PSL) is the largest ``|χ|``
outside the mainlobe, taken as cyclic ``|τ| < T_h`` and ``|ν| < 1/T_h``. Real CPU work
(``2·doppler_bins + 1`` FFTs of one period) and deterministic per seed: the workload of the
evaluation tests and benchmark.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hil.errors import ConfigError
from hil.evaluation.registry import Params
from hil.signals.ambiguity import periodic_af
from hil.signals.random_cyclic import validate_code_request
from hil.signals.waveforms import WaveformSpec, build_schedule

#: Parameters and their defaults (Hz, s).
DEFAULTS: dict[str, Any] = {
    "n_tones": 4,
    "code_length": 17,
    "window": 3,
    "candidates": 8,
    "m_hops": 10,
    "center_hz": 30_000.0,
    "bandwidth_hz": 4_400.0,
    "hop_s": 0.010,
    "fs_hz": 100_000.0,
    "doppler_bins": 4,
}
_INTS = ("n_tones", "code_length", "window", "candidates", "m_hops", "doppler_bins")


def validate_params(params: Params) -> None:
    """Refuse unknown parameters, wrong types and designs no code or AF can satisfy.

    >>> try:
    ...     validate_params({"n_tones": 4, "code_length": 17, "window": 2})
    ... except ConfigError as exc:
    ...     print(exc.field, exc.value)
    window 2
    """
    for key, value in params.items():
        if key not in DEFAULTS:
            raise ConfigError(
                key, value, f"a parameter of waveform_af_sidelobe: {', '.join(DEFAULTS)}"
            )
        if key in _INTS:
            if (
                isinstance(value, bool)
                or not isinstance(value, int)
                or value < (key != "doppler_bins")
            ):
                low = 0 if key == "doppler_bins" else 1
                raise ConfigError(key, value, f"an integer >= {low}")
        elif (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or not (math.isfinite(value) and value > 0)
        ):
            raise ConfigError(key, value, "a finite number > 0")
    p = {**DEFAULTS, **params}
    validate_code_request(p["n_tones"], p["code_length"], p["window"])
    samples = p["code_length"] * p["hop_s"] * p["fs_hz"]
    if abs(samples - round(samples)) > 1e-6:
        raise ConfigError(
            "fs_hz",
            p["fs_hz"],
            "a rate giving a whole number of samples per period (code_length·hop_s·fs_hz)",
            f"{p['code_length']}·{p['hop_s']}·{p['fs_hz']} = {samples:.6g}",
        )


def waveform_af_sidelobe(params: Params, seed: np.random.SeedSequence) -> dict[str, Any]:
    """Draw a code, compute its periodic AF, return ``psl`` (linear), ``psl_db`` (dB re the
    matched peak), ``d_min`` (at ``m_hops``), ``code_seed`` and ``code`` (tone per hop).

    >>> out = waveform_af_sidelobe({}, np.random.SeedSequence(1, spawn_key=(0, 0)))
    >>> out["code_seed"], out["d_min"], round(out["psl_db"], 3)
    (3023998541, 6, -10.212)
    """
    p = {**DEFAULTS, **params}
    code_seed = int(seed.generate_state(1, dtype=np.uint32)[0])
    spec = WaveformSpec(
        family="random-cyclic",
        center_hz=float(p["center_hz"]),
        bandwidth_hz=float(p["bandwidth_hz"]),
        fs_hz=float(p["fs_hz"]),
        n_tones=p["n_tones"],
        hop_s=float(p["hop_s"]),
        code_length=p["code_length"],
        window=p["window"],
        seed=code_seed,
        candidates=p["candidates"],
        m_hops=p["m_hops"],
    )
    schedule = build_schedule(spec)
    k = np.arange(-p["doppler_bins"], p["doppler_bins"] + 1)
    af = periodic_af(schedule, spec.fs_hz, k / schedule.period_s)
    period = schedule.period_s
    delay = np.minimum(af.delay_s, period - af.delay_s)  # cyclic distance from zero delay
    mainlobe = (np.abs(af.doppler)[:, None] < 1.0 / spec.hop_s) & (delay[None, :] < spec.hop_s)
    psl = float(np.max(np.where(mainlobe, 0.0, af.magnitude)))
    return {
        "psl": psl,
        "psl_db": 20.0 * math.log10(psl),
        "d_min": int(schedule.params["d_min"]),
        "code_seed": code_seed,
        "code": schedule.code.tolist(),
    }


waveform_af_sidelobe.validate_params = validate_params  # type: ignore[attr-defined]
