"""The tables of an experiment file, one dataclass each (:mod:`hil.config_sections`).

Each table checks its own keys (types, ranges, choices) and what depends only on them (the
run name, the device URLs and channel, positions inside the tank, the sound speed against
the water temperature); what spans tables (the tow inside the tank, the waveform at the
tank's sound speed, the receiver against the tow) is checked in one place,
:func:`hil.experiments.experiment.parse_experiment`. :class:`ExperimentFile` is the whole
file, from which ``hil schema`` writes the shipped JSON Schema.

Coordinates: tank frame, metres, x along the tank, z up with the surface at 0; the stage is
GRBL's X axis, machine positions in ``[-travel, 0]`` (see :mod:`hil.experiments.experiment`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from hil.config_sections import Section, key, required
from hil.devices.table import check_device_url
from hil.errors import ConfigError
from hil.estimation.registry import RECEIVERS
from hil.signals.presets import PRESETS
from hil.signals.waveforms import FAMILIES, WaveformSpec

#: Where every key of the file is documented (named in the message on an unknown key).
DOCS = "hil docs tank-run"
#: Image order limit (reflections per round trip) of the simulated target's echoes (1, 13,
#: 85, 377, 1289 paths for 0 … 4, each rendered per sample) and of the tank's own echoes
#: (one convolution, any order).
MAX_TARGET_IMAGE_ORDER = 4
MAX_TANK_ECHO_ORDER = 40
#: Directivity of the simulated projector and hydrophone: omni, or a baffled circular
#: piston of the given radius at the waveform's centre frequency.
BEAM_KINDS = ("omni", "piston")
#: Largest side of a tank (m): a lab tank, not open water (the simulated tank renders its
#: volume reverberation out to the tank's diagonal).
MAX_TANK_SIDE_M = 1000.0
#: The ADC channel that carries the DAC monitor (input 2): the transmitted drive looped back
#: for the latency measurement (:mod:`hil.experiments.live.latency`), never the hydrophone.
MONITOR_CHANNEL = 1
#: How far ``tank.sound_speed_mps`` may be from the sound speed of water at
#: ``tank.water_temperature_c`` (and salinity), m/s: about 3 °C at 20 °C, well past a
#: thermometer's error and the spread of the standard formulas (< 1 m/s in fresh water).
SOUND_SPEED_TOLERANCE_MPS = 10.0


@dataclass(frozen=True)
class RunSection(Section):
    """[run]: what the run is called, where it is written, how long it may last."""

    DOCS = DOCS
    name: str = key("tank-run", "text", "run name: the folder is output_dir/name-timestamp")
    output_dir: str = key("runs", "text", "folder of the run folders (HIL_RUNS_DIR overrides)")
    max_duration_s: float = key(
        120.0, "number", "longest run from the start of transmission; must cover the tow",
        lo=0.0, lo_open=True, unit="s",
    )  # fmt: skip

    def checks(self, path: str) -> Iterator[ConfigError]:
        try:
            check_run_name(self.name)
        except ConfigError as exc:
            yield exc


@dataclass(frozen=True)
class DevicesSection(Section):
    """[devices]: the DAC/ADC board (or audio interface) and the GRBL stage."""

    DOCS = DOCS
    board: str = required("text", "DAC/ADC URL: a serial port, audio://DEVICE or sim://board")
    stage: str = required("text", "GRBL stage URL: a serial port or sim://stage")
    board_channel: int = key(
        0, "integer", "ADC channel of the hydrophone (1 is the DAC monitor)", lo=0, hi=15
    )

    @cached_property
    def urls(self) -> tuple[str, str]:
        """The board's and the stage's URLs in their canonical spelling (checked once: a
        deprecated spelling warns once); a ConfigError saying they look swapped when each
        would fit the other's role."""
        try:
            board = check_device_url(self.board, "daq", "devices.board")
            stage = check_device_url(self.stage, "stage", "devices.stage")
        except ConfigError as exc:
            if not self._swapped():
                raise
            hint = f"{exc.hint}; " if exc.hint else ""
            raise ConfigError(
                exc.field, exc.value, exc.allowed,
                hint + "devices.board and devices.stage look swapped: exchange them",
            ) from None  # fmt: skip
        return board, stage

    def _swapped(self) -> bool:
        try:
            check_device_url(self.board, "stage")
            check_device_url(self.stage, "daq")
        except ConfigError:
            return False
        return True

    def checks(self, path: str) -> Iterator[ConfigError]:
        try:
            self.urls  # noqa: B018 (checked here, cached for the experiment)
        except ConfigError as exc:
            yield exc
        if self.board_channel == MONITOR_CHANNEL:
            yield ConfigError(
                "devices.board_channel", self.board_channel,
                f"the hydrophone's channel, not {MONITOR_CHANNEL}",
                f"channel {MONITOR_CHANNEL} (ADC input 2) is the DAC monitor: it carries the"
                " transmitted drive for the latency measurement; the hydrophone is on 0",
            )  # fmt: skip


@dataclass(frozen=True)
class WaveformSection(Section):
    """[waveform]: the transmitted code, a preset's family at the tank's sound speed."""

    DOCS = DOCS
    preset: str = key("tank-board", "text", "waveform preset", choices=tuple(PRESETS))
    family: str = key("random-cyclic", "text", "waveform family", choices=FAMILIES)
    amplitude: float = key(
        0.5, "number", "DAC drive", lo=0.0, lo_open=True, hi=1.0, unit="full scale"
    )
    overrides: dict[str, Any] = key(
        {}, "table", "waveform fields replacing the preset's",
        choices=tuple(WaveformSpec.__dataclass_fields__),
    )  # fmt: skip


@dataclass(frozen=True)
class TankSection(Section):
    """[tank]: the tank, its water and where the transducer and the stage are."""

    DOCS = DOCS
    size_m: tuple[float, float, float] = key(
        (12.0, 4.0, 2.5), "vector", "length, width, depth", lo=0.0, lo_open=True,
        hi=MAX_TANK_SIDE_M, unit="m",
    )  # fmt: skip
    water_temperature_c: float | None = key(
        None, "number", "water temperature", lo=0.0, hi=95.0, unit="°C", shown_default=20.0
    )
    salinity_ppt: float = key(0.0, "number", "salinity", lo=0.0, hi=42.0, unit="ppt")
    sound_speed_mps: float | None = key(
        None, "number", "measured sound speed (default: from the temperature and salinity)",
        lo=1300.0, hi=1700.0, unit="m/s",
    )  # fmt: skip
    transducer_position_m: tuple[float, float, float] | None = key(
        None, "vector", "transducer [x, y, z] (default: 0.5 m from the near wall, centred)",
        unit="m",
    )  # fmt: skip
    stage_origin_m: tuple[float, float, float] | None = key(
        None, "vector", "towed target at stage x = 0 (default: 1 m from the far wall, centred)",
        unit="m",
    )  # fmt: skip
    stage_axis: tuple[float, float, float] = key(
        (1.0, 0.0, 0.0), "vector", "direction of the stage's X axis in the tank"
    )

    @property
    def temperature_c(self) -> float:
        """The water temperature, °C (20 when the file leaves it out)."""
        return 20.0 if self.water_temperature_c is None else self.water_temperature_c

    @property
    def transducer_m(self) -> tuple[float, float, float]:
        """Transducer position (m), the default derived from the tank's size."""
        _, ly, lz = self.size_m
        return self.transducer_position_m or (0.5, ly / 2, -lz / 2)

    @property
    def origin_m(self) -> tuple[float, float, float]:
        """Towed target's position at stage x = 0 (m), the default from the tank's size."""
        lx, ly, lz = self.size_m
        return self.stage_origin_m or (lx - 1.0, ly / 2, -lz / 2)

    @property
    def axis(self) -> tuple[float, float, float]:
        """The stage axis as a unit vector."""
        a = np.asarray(self.stage_axis)
        a = a / float(np.sqrt(a @ a))
        return (float(a[0]), float(a[1]), float(a[2]))

    def water_sound_speed_mps(self) -> float:
        """Sound speed of the tank's water (m/s) from its temperature and salinity:
        Marczak (1997) for fresh water, UNESCO (Chen and Millero) for salt water."""
        # Lazy import: the formulas live with the acoustics (DESIGN: hil imports sim_devices
        # lazily).
        from sim_devices.acoustics.sound_speed import tank_sound_speed, unesco_sound_speed

        if self.salinity_ppt == 0.0:
            return float(tank_sound_speed(self.temperature_c))
        return float(unesco_sound_speed(self.salinity_ppt, self.temperature_c, 0.0))

    @property
    def sound_speed(self) -> float:
        """The sound speed of the run (m/s): as given, else the water's."""
        return self.sound_speed_mps or self.water_sound_speed_mps()

    def checks(self, path: str) -> Iterator[ConfigError]:
        if not any(self.stage_axis):
            yield ConfigError("tank.stage_axis", list(self.stage_axis), "a non-zero direction")
        for name, p in (("transducer_position_m", self.transducer_m),
                        ("stage_origin_m", self.origin_m)):  # fmt: skip
            bad = outside_tank(f"tank.{name}", p, self.size_m)
            if bad is not None:
                yield bad
        given = self.sound_speed_mps
        if given is not None and self.water_temperature_c is not None:
            water = self.water_sound_speed_mps()
            if abs(given - water) > SOUND_SPEED_TOLERANCE_MPS:
                yield ConfigError(
                    "tank.sound_speed_mps", given,
                    f"within {SOUND_SPEED_TOLERANCE_MPS:g} m/s of {water:.1f} m/s, the sound"
                    f" speed of water at tank.water_temperature_c = {self.temperature_c:g} °C"
                    f" and salinity {self.salinity_ppt:g} ppt",
                    "check the thermometer and the measurement, or give only one of them",
                )  # fmt: skip


def outside_tank(
    name: str, p: tuple[float, ...], size: tuple[float, float, float]
) -> ConfigError | None:
    """The error for point ``p`` (m) outside the tank of ``size`` (m), else None."""
    lx, ly, lz = size
    if 0 < p[0] < lx and 0 < p[1] < ly and -lz < p[2] < 0:
        return None
    return ConfigError(
        name, [round(c, 4) for c in p],
        f"inside the tank: 0 < x < {lx}, 0 < y < {ly}, -{lz} < z < 0 m",
        "move it, or change tank.size_m / the tow plan",
    )  # fmt: skip


@dataclass(frozen=True)
class TowPlan(Section):
    """[tow]: a constant-speed pass of the stage, stage coordinates (m) and m/s."""

    DOCS = DOCS
    start_m: float = required("number", "where the constant-speed pass starts", unit="m")
    end_m: float = required("number", "where it ends", unit="m")
    speed_mps: float = required("number", "tow speed", lo=0.0, lo_open=True, hi=5.0, unit="m/s")
    repeats: int = key(1, "integer", "passes, alternating direction", lo=1, hi=1000)
    run_up_m: float = key(0.5, "number", "acceleration before start_m", lo=0.0, unit="m")
    run_down_m: float = key(0.5, "number", "deceleration after end_m", lo=0.0, unit="m")

    @property
    def direction(self) -> float:
        """+1 when the pass runs towards larger x, else -1."""
        return 1.0 if self.end_m > self.start_m else -1.0

    @property
    def shortest_duration_s(self) -> float:
        """The least time the tow takes (s): every pass with its run-up and run-down at the
        tow speed (the acceleration and the capture's tail only add to it)."""
        leg = abs(self.end_m - self.start_m) + self.run_up_m + self.run_down_m
        return self.repeats * leg / self.speed_mps

    def checks(self, path: str) -> Iterator[ConfigError]:
        if self.start_m == self.end_m:
            yield ConfigError("tow.end_m", self.end_m, f"!= tow.start_m = {self.start_m} m")
            return
        d = self.direction
        for name, x in (
            ("tow.start_m - tow.run_up_m", self.start_m - d * self.run_up_m),
            ("tow.end_m + tow.run_down_m", self.end_m + d * self.run_down_m),
        ):
            if x > 0:
                yield ConfigError(name, x, "<= 0 m (GRBL machine positions are in [-travel, 0])")


@dataclass(frozen=True)
class ReceiverSection(Section):
    """[receiver]: the estimator run on the hydrophone's samples."""

    DOCS = DOCS
    name: str = key("gcas", "text", "receiver", choices=tuple(RECEIVERS))
    m_hops: int = key(10, "integer", "hops accumulated per estimate", lo=1, hi=64)
    max_speed_mps: float = key(
        3.0, "number", "Doppler search limit (>= the tow speed)", lo=0.0, lo_open=True,
        unit="m/s",
    )  # fmt: skip
    max_range_m: float | None = key(
        None, "number", "range searched (default: the tank's diagonal; >= the tow's farthest)",
        lo=0.0, lo_open=True, unit="m",
    )  # fmt: skip
    options: dict[str, Any] = key({}, "table", "receiver options")

    def checks(self, path: str) -> Iterator[ConfigError]:
        from hil.estimation.registry import check_receiver_options
        from hil.estimation.tracking import TrackerSettings

        try:
            check_receiver_options(self.name, self.options)
        except ConfigError as exc:
            yield exc
        try:  # the tracker's track_* options (docs/tracks.md)
            TrackerSettings.from_options(self.options)
        except ConfigError as exc:
            yield ConfigError(f"receiver.options.{exc.field}", exc.value, exc.allowed, exc.hint)


@dataclass(frozen=True)
class CalibrationSection(Section):
    """[calibration]: the store of calibrations and the ones this run requires."""

    DOCS = DOCS
    store: str = key("calibration", "text", "calibration store folder (HIL_CALIBRATION_DIR)")
    max_age_days: float = key(
        30.0, "number", "oldest calibration used", lo=0.0, lo_open=True, unit="days"
    )
    required: list[str] = key([], "texts", "calibration kinds the run requires")


@dataclass(frozen=True)
class SimulationSettings(Section):
    """[simulation]: the simulated world behind ``sim://`` devices (ignored for real
    hardware)."""

    DOCS = DOCS
    source_level_db: float = key(
        185.0, "number", "source level at full scale", lo=100.0, hi=250.0,
        unit="dB re 1 µPa @ 1 m",
    )  # fmt: skip
    target_strength_db: float = key(
        -12.0, "number", "target strength", lo=-80.0, hi=40.0, unit="dB re 1 m²"
    )
    sensitivity_db: float = key(
        -200.0, "number", "hydrophone sensitivity", lo=-260.0, hi=-100.0, unit="dB re 1 V/µPa"
    )
    gain_db: float = key(30.0, "number", "preamplifier gain", lo=-20.0, hi=80.0, unit="dB")
    image_order: int = key(
        1, "integer", "target echo reflections per round trip", lo=0, hi=MAX_TARGET_IMAGE_ORDER
    )
    tank_echoes: bool = key(False, "flag", "the tank's own echoes of the transmission")
    tank_echo_order: int = key(
        3, "integer", "image order of the tank's own echoes", lo=0, hi=MAX_TANK_ECHO_ORDER
    )
    late_tail: bool = key(True, "flag", "the tank's diffuse late tail")
    wall_reflection: float = key(0.9, "number", "wall reflection coefficient", lo=-1.0, hi=1.0)
    bottom_reflection: float = key(0.9, "number", "bottom reflection coefficient", lo=-1.0, hi=1.0)
    transducer_beam: str = key("piston", "text", "projector directivity", choices=BEAM_KINDS)
    transducer_radius_m: float = key(
        0.015, "number", "projector piston radius", lo=0.0, lo_open=True, hi=1.0, unit="m"
    )
    hydrophone_beam: str = key("omni", "text", "hydrophone directivity", choices=BEAM_KINDS)
    hydrophone_radius_m: float = key(
        0.015, "number", "hydrophone piston radius", lo=0.0, lo_open=True, hi=1.0, unit="m"
    )
    noise_level_db: float = key(
        40.0, "number", "ambient noise spectrum level", lo=-20.0, hi=120.0,
        unit="dB re 1 µPa²/Hz",
    )  # fmt: skip
    reverberation: bool = key(True, "flag", "volume reverberation")
    scattering_strength_db: float = key(
        -70.0, "number", "volume scattering strength", lo=-120.0, hi=-10.0, unit="dB"
    )
    time_scale: float = key(
        0.5, "number", "simulated seconds per wall-clock second", lo=0.01, hi=1.0
    )
    seed: int = key(1, "integer", "random seed of the simulated world", lo=0)


@dataclass(frozen=True)
class ExperimentFile(Section):
    """A towed-target tank run (hil tank-run EXPERIMENT.toml): hil docs tank-run."""

    KEY_WORD = "tables"
    run: RunSection = key(None, "section", "the run", section=RunSection)
    devices: DevicesSection = key(None, "section", "the devices", section=DevicesSection)
    waveform: WaveformSection = key(None, "section", "the waveform", section=WaveformSection)
    tank: TankSection = key(None, "section", "the tank", section=TankSection)
    tow: TowPlan = key(None, "section", "the tow", section=TowPlan)
    receiver: ReceiverSection = key(None, "section", "the receiver", section=ReceiverSection)
    calibration: CalibrationSection = key(
        None, "section", "the calibrations", section=CalibrationSection
    )
    simulation: SimulationSettings = key(
        None, "section", "the simulated tank", section=SimulationSettings
    )


def check_run_name(name: str) -> str:
    """``name`` if it is a plain folder name (``run.name``): the run folder is
    ``output_dir/name-timestamp``, so a name with a path separator, ``..``, a leading ``.``,
    or an absolute path would put it elsewhere.

    >>> check_run_name("towed-pass")
    'towed-pass'
    >>> check_run_name("../../x")
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: run.name = '../../x' is not allowed: must be a plain folder name \
(letters, digits, '-', '_', '.', not starting with '.'); the run folder is \
run.output_dir/name-timestamp and must stay inside run.output_dir
    """
    plain = (
        bool(name)
        and not name.startswith(".")
        and all(ch.isalnum() or ch in "-_." for ch in name)
        and len(name) <= 100
    )
    if not plain:
        raise ConfigError(
            "run.name",
            name,
            "a plain folder name (letters, digits, '-', '_', '.', not starting with '.')",
            "the run folder is run.output_dir/name-timestamp and must stay inside run.output_dir",
        )
    return name
