"""The sonar equations as a calculator: all terms in dB.

Units: SL source level, dB re 1 µPa at 1 m; TL one-way transmission loss, dB re 1 m;
TS target strength, dB re 1 m²; NL noise level in the processing band, dB re 1 µPa
(spectrum level dB re 1 µPa²/Hz plus ``10 log10(bandwidth / 1 Hz)``); DI receiver
directivity index, dB; RL reverberation level, dB re 1 µPa; DT detection threshold, dB.

- active, noise-limited:          SNR = SL - 2 TL + TS - (NL - DI)
- active, reverberation-limited:  SNR = SL - 2 TL + TS - RL
- passive:                        SNR = SL - TL - (NL - DI)
- signal excess:                  SE = SNR - DT   (SE = 0 at about 50 % detection probability)

The inverse forms (source level needed, transmission loss allowed) follow MATLAB's
``sonareqsl`` / ``sonareqtl``. Inputs broadcast; a scalar input gives a float.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from sim_devices.acoustics._physics_inputs import (
    FloatArray,
    FloatOrArray,
    as_float_array,
    check_positive,
    scalar_or_array,
)


def _db(name: str, value: ArrayLike) -> FloatArray:
    return as_float_array(name, value, "levels are in dB")


def _masking(noise_level_db: ArrayLike, directivity_index_db: ArrayLike) -> FloatArray:
    """``NL - DI``: the noise the array lets through, dB re 1 µPa."""
    return _db("noise_level_db", noise_level_db) - _db("directivity_index_db", directivity_index_db)


def band_noise_level(spectrum_level_db: ArrayLike, bandwidth_hz: ArrayLike) -> FloatOrArray:
    """Noise level in a band, dB re 1 µPa: ``spectrum level + 10 log10(B / 1 Hz)``.

    Assumes a flat spectrum across the band (use the band-centre spectrum level).

    Examples
    --------
    >>> round(band_noise_level(46.1, 10e3), 1)
    86.1
    """
    nsl = _db("spectrum_level_db", spectrum_level_db)
    bw = as_float_array("bandwidth_hz", bandwidth_hz)
    check_positive("bandwidth_hz", bw, "Hz", "the receiver's processing bandwidth")
    return scalar_or_array(np.asarray(nsl + 10.0 * np.log10(bw), dtype=np.float64))


def active_snr_noise_limited(
    source_level_db: ArrayLike,
    transmission_loss_db: ArrayLike,
    target_strength_db: ArrayLike,
    noise_level_db: ArrayLike,
    directivity_index_db: ArrayLike = 0.0,
) -> FloatOrArray:
    """Echo SNR of an active sonar against noise, dB: ``SL - 2TL + TS - (NL - DI)``.

    ``transmission_loss_db`` is one-way (it is doubled here).

    Examples
    --------
    >>> active_snr_noise_limited(130.0, 60.0, 25.0, 45.0, 25.0)   # MATLAB sonareqsnr
    15.0
    """
    snr = (
        _db("source_level_db", source_level_db)
        - 2.0 * _db("transmission_loss_db", transmission_loss_db)
        + _db("target_strength_db", target_strength_db)
        - _masking(noise_level_db, directivity_index_db)
    )
    return scalar_or_array(np.asarray(snr, dtype=np.float64))


def active_snr_reverberation_limited(
    source_level_db: ArrayLike,
    transmission_loss_db: ArrayLike,
    target_strength_db: ArrayLike,
    reverberation_level_db: ArrayLike,
) -> FloatOrArray:
    """Echo-to-reverberation ratio, dB: ``SL - 2TL + TS - RL`` (RL given, dB re 1 µPa).

    Examples
    --------
    >>> active_snr_reverberation_limited(200.0, 60.0, 10.0, 70.0)
    20.0
    """
    snr = (
        _db("source_level_db", source_level_db)
        - 2.0 * _db("transmission_loss_db", transmission_loss_db)
        + _db("target_strength_db", target_strength_db)
        - _db("reverberation_level_db", reverberation_level_db)
    )
    return scalar_or_array(np.asarray(snr, dtype=np.float64))


def passive_snr(
    source_level_db: ArrayLike,
    transmission_loss_db: ArrayLike,
    noise_level_db: ArrayLike,
    directivity_index_db: ArrayLike = 0.0,
) -> FloatOrArray:
    """SNR of a passive sonar, dB: ``SL - TL - (NL - DI)``.

    Examples
    --------
    >>> passive_snr(200.0, 140.0, 75.0, 25.0)   # MATLAB sonareqsnr
    10.0
    """
    snr = (
        _db("source_level_db", source_level_db)
        - _db("transmission_loss_db", transmission_loss_db)
        - _masking(noise_level_db, directivity_index_db)
    )
    return scalar_or_array(np.asarray(snr, dtype=np.float64))


def signal_excess(snr_db: ArrayLike, detection_threshold_db: ArrayLike) -> FloatOrArray:
    """Signal excess, dB: ``SNR - DT``; 0 dB means about 50 % probability of detection.

    Examples
    --------
    >>> signal_excess(15.0, 12.0)
    3.0
    """
    se = _db("snr_db", snr_db) - _db("detection_threshold_db", detection_threshold_db)
    return scalar_or_array(np.asarray(se, dtype=np.float64))


def active_source_level_required(
    snr_db: ArrayLike,
    transmission_loss_db: ArrayLike,
    target_strength_db: ArrayLike,
    noise_level_db: ArrayLike,
    directivity_index_db: ArrayLike = 0.0,
) -> FloatOrArray:
    """Source level giving ``snr_db`` on an active, noise-limited echo, dB re 1 µPa at 1 m.

    Examples
    --------
    >>> active_source_level_required(15.0, 60.0, 25.0, 45.0, 25.0)   # MATLAB sonareqsl
    130.0
    """
    sl = (
        _db("snr_db", snr_db)
        + 2.0 * _db("transmission_loss_db", transmission_loss_db)
        - _db("target_strength_db", target_strength_db)
        + _db("noise_level_db", noise_level_db)
        - _db("directivity_index_db", directivity_index_db)
    )
    return scalar_or_array(np.asarray(sl, dtype=np.float64))


def active_transmission_loss_allowed(
    source_level_db: ArrayLike,
    snr_db: ArrayLike,
    target_strength_db: ArrayLike,
    noise_level_db: ArrayLike,
    directivity_index_db: ArrayLike = 0.0,
) -> FloatOrArray:
    """One-way TL at which an active, noise-limited echo has ``snr_db``, dB.

    Examples
    --------
    >>> active_transmission_loss_allowed(130.0, 15.0, 25.0, 45.0, 25.0)   # MATLAB sonareqtl
    60.0
    """
    two_tl = (
        _db("source_level_db", source_level_db)
        + _db("target_strength_db", target_strength_db)
        - _masking(noise_level_db, directivity_index_db)
        - _db("snr_db", snr_db)
    )
    return scalar_or_array(np.asarray(two_tl / 2.0, dtype=np.float64))


def sphere_target_strength(radius_m: ArrayLike) -> FloatOrArray:
    """Geometric-optics target strength of a rigid sphere, dB re 1 m²: ``10 log10(a² / 4)``.

    Valid when ``k a >> 1`` (circumference many wavelengths). A 2 m radius sphere is 0 dB.

    Examples
    --------
    >>> sphere_target_strength(2.0)
    0.0
    """
    a = as_float_array("radius_m", radius_m)
    check_positive("radius_m", a, "m", "the sphere radius in metres")
    return scalar_or_array(np.asarray(10.0 * np.log10(a**2 / 4.0), dtype=np.float64))
