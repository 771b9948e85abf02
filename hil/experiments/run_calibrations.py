"""The calibrations a tank run applies: the kinds its experiment file lists in
``calibration.required``, checked present and recent before anything moves, then used.

- ``sound-speed``: the run's c (receiver, ranges, summary) is the calibrated one instead of
  the one from ``tank.water_temperature_c`` (or ``tank.sound_speed_mps``);
- ``stage``: the truth uses the carriage's true position and speed from the reported ones
  (:class:`~hil.experiments.calibration.apply.StagePositionCorrection`: scale about the
  reference, half the backlash against the direction of motion);
- ``latency``: the receiver's sample 0 when the DAC monitor input carries no loopback (the
  run measures the latency on the monitor itself when it can, and notes a disagreement);
- ``response`` and ``level``: checked and their ids recorded, not applied. GCAS decides on
  tone energies against its own CFAR noise estimate, so a flat gain changes nothing, and an
  equaliser in front of the live receiver would have to be reproduced by every replay.

Kinds not listed are not used, even when the store holds them: a run does what its file
says, and a simulated run is not corrected by calibrations of other devices.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hil.errors import ConfigError
from hil.experiments.calibration.apply import CalibrationSet, StagePositionCorrection
from hil.experiments.experiment import Experiment


@dataclass(frozen=True)
class RunCalibrations:
    """What a run takes from the calibration store.

    ``ids`` are the record ids of the required kinds (in the file's order), ``sound_speed_mps``
    (m/s), ``stage`` and ``latency_samples`` (samples at the run's rate) are ``None`` where
    the kind is not required.
    """

    ids: tuple[str, ...] = ()
    sound_speed_mps: float | None = None
    stage: StagePositionCorrection | None = None
    latency_samples: int | None = None
    kinds: tuple[str, ...] = ()

    def id_of(self, kind: str) -> str | None:
        """The record id of a required ``kind`` (``None`` if not required)."""
        return dict(zip(self.kinds, self.ids, strict=True)).get(kind)

    def apply(self, exp: Experiment) -> Experiment:
        """``exp`` with the calibrated sound speed (also in its waveform spec), if one is
        required; :class:`ConfigError` if ``receiver.max_range_m`` is then beyond the
        schedule's unambiguous range."""
        c = self.sound_speed_mps
        if c is None:
            return exp
        r_unamb = exp.schedule.unambiguous_range_m(c)
        if exp.max_range_m > r_unamb:
            raise ConfigError(
                "receiver.max_range_m",
                exp.max_range_m,
                f"<= the unambiguous range {r_unamb:.2f} m at the calibrated sound speed"
                f" {c:.1f} m/s (calibration {self.id_of('sound-speed')})",
                "lower receiver.max_range_m, or check that calibration",
            )
        waveform = dataclasses.replace(exp.waveform, sound_speed_mps=c)
        return dataclasses.replace(exp, sound_speed_mps=c, waveform=waveform)


def load_run_calibrations(exp: Experiment, fs_hz: float) -> RunCalibrations:
    """The required calibrations of ``exp`` (``fs_hz``: the run's sample rate, Hz).

    Raises :class:`ConfigError` if one is missing or older than
    ``calibration.max_age_days``, or if the latency calibration was measured at another
    sample rate than the run's (its samples would not be the run's).
    """
    kinds = exp.calibration_required
    if not kinds:
        return RunCalibrations()
    cal = CalibrationSet.require(
        exp.calibration_store, kinds, exp.calibration_max_age_days * 86400.0
    )
    if not exp.simulated:
        for kind in kinds:
            record = cal.records[kind]
            if record.settings.get("simulated"):
                raise ConfigError(
                    f"calibration {kind!r}", f"simulated (id {record.id})",
                    "measured on the real devices: a real run never applies a simulated one",
                    f"run: hil calibrate {kind} --device DEVICE --store {exp.calibration_store}",
                )  # fmt: skip
    latency = None
    if "latency" in kinds:
        assert cal.latency is not None  # required, so present
        if cal.latency.samplerate != fs_hz:
            raise ConfigError(
                "calibration 'latency'",
                f"measured at {cal.latency.samplerate:g} Hz",
                f"the run's rate, {fs_hz:g} Hz",
                f"run: hil calibrate latency --store {exp.calibration_store} at that rate",
            )
        latency = cal.latency.latency_samples
    return RunCalibrations(
        ids=tuple(cal.records[kind].id for kind in kinds),
        sound_speed_mps=cal.sound_speed_mps if "sound-speed" in kinds else None,
        stage=cal.stage_correction if "stage" in kinds else None,
        latency_samples=latency,
        kinds=tuple(kinds),
    )


def true_stage_motion(
    correction: StagePositionCorrection | None,
    position_m: npt.ArrayLike,
    velocity_mps: npt.ArrayLike,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Carriage position (m) and velocity (m/s) from the stage's reported ones (shape
    ``(n,)`` each, in time order), through ``correction`` (unchanged without one).

    The backlash side is the direction of motion: the sign of the reported velocity, or of
    the last nonzero one while the stage stands (+x before any motion).

    >>> corr = StagePositionCorrection(scale=1.01, backlash_m=0.002, reference_m=-1.0)
    >>> x, v = true_stage_motion(corr, [-2.0, -3.0, -3.0], [-1.0, -1.0, 0.0])
    >>> x.round(6).tolist(), v.round(6).tolist()
    ([-2.009, -3.019, -3.019], [-1.01, -1.01, 0.0])
    """
    x = np.asarray(position_m, dtype=np.float64)
    v = np.asarray(velocity_mps, dtype=np.float64)
    if correction is None:
        return x.copy(), v.copy()
    sign = np.sign(v)
    moving = sign != 0
    # The last nonzero direction, carried forward through the stops.
    last = np.maximum.accumulate(np.where(moving, np.arange(sign.size), -1))
    direction = np.where(last >= 0, sign[np.maximum(last, 0)], 1.0)
    scale, ref = correction.scale, correction.reference_m
    true_x = ref + scale * (x - ref) - direction * correction.backlash_m / 2.0
    return true_x, scale * v
