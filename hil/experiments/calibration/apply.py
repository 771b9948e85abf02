"""Applying stored calibrations: each result turned into what the processing chain uses.

- latency -> :func:`sample_offset` / :func:`align_recording` (time alignment);
- response -> :func:`equalise` (the equaliser FIR, modelling delay removed);
- level -> :func:`pressure_upa` (ADC full scale to µPa with the hydrophone sensitivity);
- sound speed -> :attr:`CalibrationSet.sound_speed_mps`;
- stage -> :class:`StagePositionCorrection` (scale and backlash).

:meth:`CalibrationSet.current` collects whatever the store holds;
:meth:`CalibrationSet.require` is the preflight check ("present and recent").
"""

from __future__ import annotations

import datetime as dt
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import signal as sp_signal

from hil.errors import ConfigError
from hil.experiments.calibration.device import FloatArray
from hil.experiments.calibration.latency import LatencyResult
from hil.experiments.calibration.level import LevelResult
from hil.experiments.calibration.response import ResponseResult
from hil.experiments.calibration.sound_speed import SoundSpeedResult
from hil.experiments.calibration.stage import StageResult
from hil.experiments.calibration.store import CalibrationStore, StoredCalibration


def sample_offset(latency: LatencyResult) -> int:
    """Input samples to skip so that input row n lines up with output row n.

    >>> sample_offset(LatencyResult((549,), 48000.0, 549, 549.0, 0.0, 0, 40.0, 1.0))
    549
    """
    return latency.latency_samples


def align_recording(recording: npt.ArrayLike, latency: LatencyResult) -> FloatArray:
    """``recording[latency:]`` (rows = samples): row n then holds the echo of output row n."""
    x = np.asarray(recording)
    return np.asarray(x[sample_offset(latency) :])


def equalise(signal: npt.ArrayLike, response: ResponseResult) -> FloatArray:
    """``signal`` (shape (n,) or (n, channels)) filtered by the equaliser, modelling delay
    removed, same shape: what to play (pre-equalised) or how to flatten what was recorded."""
    x = np.asarray(signal, dtype=np.float64)
    g = response.equaliser if x.ndim == 1 else response.equaliser[:, None]
    y = sp_signal.fftconvolve(x, g, axes=0)
    d = response.equaliser_delay_samples
    return np.asarray(y[d : d + x.shape[0]])


def pressure_upa(counts: npt.ArrayLike, level: LevelResult) -> FloatArray:
    """Acoustic pressure (µPa) from ADC samples (full scale) of the calibrated hydrophone."""
    if level.sensitivity_db is None:
        raise ConfigError(
            "level.sensitivity_db", None, "a calibrated hydrophone sensitivity",
            "run hil calibrate level with --reference-sensitivity or --source-level",
        )  # fmt: skip
    volts_per_fs = level.adc_full_scale_v / 10.0 ** (level.input_gain_db / 20.0)
    return (
        np.asarray(counts, dtype=np.float64) * volts_per_fs / 10.0 ** (level.sensitivity_db / 20.0)
    )


@dataclass(frozen=True)
class StagePositionCorrection:
    """True carriage position from the commanded one, and back (see :mod:`.stage`).

    Examples
    --------
    >>> corr = StagePositionCorrection(scale=1.001, backlash_m=2e-4, reference_m=-0.2)
    >>> round(corr.true_position(-0.1, direction=+1), 6), round(corr.true_position(-0.1, -1), 6)
    (-0.1, -0.0998)
    >>> round(corr.command_for(-0.0998, direction=-1), 9)
    -0.1
    """

    scale: float
    backlash_m: float
    reference_m: float

    @classmethod
    def from_result(cls, result: StageResult) -> StagePositionCorrection:
        """The correction of a stage calibration."""
        return cls(result.scale, result.backlash_m, result.reference_m)

    def true_position(self, commanded_m: float, direction: int) -> float:
        """Carriage position (m) after a move to ``commanded_m`` made in ``direction``
        (+1 moving +x, -1 moving -x)."""
        _check_direction(direction)
        return (
            self.reference_m
            + self.scale * (commanded_m - self.reference_m)
            - direction * self.backlash_m / 2.0
        )

    def command_for(self, target_m: float, direction: int) -> float:
        """The command (m) that puts the carriage at ``target_m`` when approached moving in
        ``direction``."""
        _check_direction(direction)
        shifted = target_m + direction * self.backlash_m / 2.0 - self.reference_m
        return self.reference_m + shifted / self.scale


def _check_direction(direction: int) -> None:
    if direction not in (1, -1):
        raise ConfigError("direction", direction, "+1 (moving +x) or -1 (moving -x)")


@dataclass(frozen=True)
class CalibrationSet:
    """The current calibrations of a store (``None`` where a kind has none).

    ``records`` maps each present kind to its stored record (id, age, settings).
    """

    latency: LatencyResult | None = None
    response: ResponseResult | None = None
    level: LevelResult | None = None
    sound_speed: SoundSpeedResult | None = None
    stage: StageResult | None = None
    records: dict[str, StoredCalibration] = field(default_factory=dict)

    @classmethod
    def current(cls, store_dir: str | os.PathLike[str]) -> CalibrationSet:
        """Everything current in the store at ``store_dir``."""
        store = CalibrationStore(store_dir)
        records = {}
        for kind in ("latency", "response", "level", "sound-speed", "stage"):
            record = store.current(kind)
            if record is not None:
                records[kind] = record

        def get(kind: str) -> Any:
            return records[kind].result if kind in records else None

        return cls(
            latency=get("latency"),
            response=get("response"),
            level=get("level"),
            sound_speed=get("sound-speed"),
            stage=get("stage"),
            records=records,
        )

    @staticmethod
    def require(
        store_dir: str | os.PathLike[str],
        kinds: Sequence[str],
        max_age_s: float,
        now: dt.datetime | None = None,
    ) -> CalibrationSet:
        """The current set after checking every kind in ``kinds`` is present and at most
        ``max_age_s`` old (the tank-run preflight); :class:`ConfigError` otherwise."""
        store = CalibrationStore(store_dir)
        for kind in kinds:
            store.require(kind, max_age_s, now)
        return CalibrationSet.current(store_dir)

    @property
    def sound_speed_mps(self) -> float | None:
        """Calibrated c (m/s), or ``None``."""
        return None if self.sound_speed is None else self.sound_speed.sound_speed_mps

    @property
    def sample_offset(self) -> int | None:
        """Latency to align recordings (samples), or ``None``."""
        return None if self.latency is None else sample_offset(self.latency)

    @property
    def stage_correction(self) -> StagePositionCorrection | None:
        """The stage's position correction, or ``None``."""
        return None if self.stage is None else StagePositionCorrection.from_result(self.stage)
