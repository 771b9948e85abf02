"""The tables of a scenario file, one dataclass each (:mod:`hil.config_sections`).

Each table checks its own keys and what depends only on them (the trajectory's keys, a beam's
pattern keys, one of ``sea_state`` / ``wind_speed_mps``); what spans tables (speeds against
the sound speed, the waveform, targets inside the tank, a level relative to a target) is
checked in one place, :func:`sim_devices.acoustics.scenario.parse_scenario`.
:class:`ScenarioFile` is the whole file, from which ``hil schema`` writes the shipped JSON
Schema. The format is documented in ``docs/scenarios.md``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from hil.config_sections import Section, key, required
from hil.errors import ConfigError
from hil.signals.presets import PRESETS
from hil.signals.waveforms import FAMILIES, WaveformSpec
from sim_devices.acoustics.images import MAX_IMAGE_ORDER
from sim_devices.acoustics.tank_response import T60_FORMULAS

#: Where every key of the file is documented (named in the message on an unknown key).
DOCS = "hil docs scenarios"
OUTPUT_CHANNELS = (
    "received", "pressure", "echo", "reverberation", "noise", "direct", "tank",
)  # fmt: skip
#: Highest image order of the target's echoes (reflections per round trip): 1, 13, 85, 377,
#: 1289 echo paths for N = 0 … 4, each solved and rendered per sample.
MAX_TARGET_IMAGE_ORDER = 4
TRAJECTORIES = ("fixed", "constant-velocity", "radial", "piecewise")
#: The keys each trajectory needs.
TRAJECTORY_KEYS = {
    "fixed": ("position_m",),
    "constant-velocity": ("position_m",),
    "radial": ("range_m",),
    "piecewise": ("waypoints_m", "speeds_mps"),
}
SEED_MAX = 2**32 - 1


def _kind(key: str, value: str) -> dict[str, Any]:
    """A JSON Schema condition: ``key`` is given and equals ``value``."""
    return {"required": [key], "properties": {key: {"const": value}}}


@dataclass(frozen=True)
class EnvironmentSection(Section):
    """[environment]: the water (sound speed given, or from temperature and salinity)."""

    DOCS = DOCS
    sound_speed_mps: float | None = key(
        None, "number", "sound speed (default: from temperature_c, else the preset's)",
        lo=1300.0, hi=1800.0, unit="m/s",
    )  # fmt: skip
    temperature_c: float | None = key(None, "number", "water temperature", lo=0.0, hi=40.0,
                                      unit="°C")  # fmt: skip
    salinity_ppt: float | None = key(
        None, "number", "salinity", lo=0.0, hi=40.0, unit="ppt", shown_default=0.0
    )
    depth_m: float = key(1.0, "number", "depth for the UNESCO formula", lo=0.0, hi=10000.0,
                         unit="m")  # fmt: skip
    absorption_db_per_km: float = key(0.0, "number", "absorption", lo=0.0, hi=1000.0,
                                      unit="dB/km")  # fmt: skip

    def checks(self, path: str) -> Iterator[ConfigError]:
        if self.sound_speed_mps is not None:
            for name in ("temperature_c", "salinity_ppt"):
                if getattr(self, name) is not None:
                    yield ConfigError(
                        f"environment.{name}", getattr(self, name),
                        "absent when sound_speed_mps is given",
                        "give either the sound speed or the water temperature/salinity",
                    )  # fmt: skip

    def sound_speed(self) -> float | None:
        """The sound speed (m/s) the table gives or implies; None: the preset's."""
        from sim_devices.acoustics.sound_speed import tank_sound_speed, unesco_sound_speed

        if self.sound_speed_mps is not None:
            return self.sound_speed_mps
        if self.temperature_c is None:
            return None
        s = self.salinity_ppt or 0.0
        if s == 0.0:
            return float(tank_sound_speed(self.temperature_c))
        return float(unesco_sound_speed(s, 1.00024 * self.temperature_c, self.depth_m))


@dataclass(frozen=True)
class BeamSection(Section):
    """A beam pattern: omni, a piston (``ka``, or ``radius_m`` at ``frequency_hz``), or a
    table of levels (``angles_deg``, ``levels_db``)."""

    DOCS = DOCS
    type: str = key("omni", "text", "pattern", choices=("omni", "piston", "table"))
    ka: float | None = key(None, "number", "piston k·a", lo=0.0, lo_open=True)
    radius_m: float | None = key(None, "number", "piston radius", lo=0.0, lo_open=True, unit="m")
    frequency_hz: float | None = key(
        None, "number", "frequency of radius_m (default: the waveform's centre)", lo=0.0,
        lo_open=True, unit="Hz",
    )  # fmt: skip
    axis: tuple[float, float, float] = key((1.0, 0.0, 0.0), "vector", "beam axis")
    angles_deg: list[float] | None = key(None, "numbers", "table angles off axis", unit="deg")
    levels_db: list[float] | None = key(None, "numbers", "table levels", unit="dB")

    @classmethod
    def schema_rules(cls) -> dict[str, Any]:
        piston = {"anyOf": [{"required": ["ka"]}, {"required": ["radius_m"]}]}
        return {"allOf": [
            {"if": _kind("type", "piston"), "then": piston},
            {"if": _kind("type", "table"), "then": {"required": ["angles_deg", "levels_db"]}},
        ]}  # fmt: skip

    def checks(self, path: str) -> Iterator[ConfigError]:
        if not any(self.axis):
            yield ConfigError(f"{path}.axis", list(self.axis), "a non-zero vector")
        if self.type == "piston" and self.ka is None and self.radius_m is None:
            yield ConfigError(f"{path}.radius_m", None, "a value (or ka)", "a piston needs one")
        if self.type == "table":
            for name in ("angles_deg", "levels_db"):
                if getattr(self, name) is None:
                    yield ConfigError(f"{path}.{name}", None, "a list of numbers")


@dataclass(frozen=True)
class SonarSection(Section):
    """[sonar]: the monostatic sonar: where, how fast, its levels and beams."""

    DOCS = DOCS
    position_m: tuple[float, float, float] = key((0.0, 0.0, 0.0), "vector", "position",
                                                 unit="m")  # fmt: skip
    velocity_mps: tuple[float, float, float] = key((0.0, 0.0, 0.0), "vector", "velocity",
                                                   unit="m/s")  # fmt: skip
    source_level_db: float = key(200.0, "number", "source level", lo=0.0, hi=260.0,
                                 unit="dB re 1 µPa @ 1 m")  # fmt: skip
    sensitivity_db: float = key(-180.0, "number", "receive sensitivity", lo=-300.0, hi=0.0,
                                unit="dB re 1 V/µPa")  # fmt: skip
    gain_db: float = key(0.0, "number", "receive gain", lo=-60.0, hi=120.0, unit="dB")
    full_scale_v: float = key(1.0, "number", "ADC full scale", lo=0.0, lo_open=True, unit="V")
    beam: BeamSection = key(None, "section", "transmit beam", section=BeamSection)
    hydrophone_beam: BeamSection | None = key(
        None, "section", "receive beam (default: the transmit beam)", section=BeamSection,
        absent_none=True,
    )  # fmt: skip

    @property
    def receive_beam(self) -> BeamSection:
        """The receiving beam: the hydrophone's, else the transmitter's (one transducer)."""
        return self.hydrophone_beam or self.beam


@dataclass(frozen=True)
class TargetSection(Section):
    """[[targets]]: one target, its trajectory and strength."""

    DOCS = DOCS
    trajectory: str = required("text", "trajectory kind", choices=TRAJECTORIES)
    target_strength_db: float = key(0.0, "number", "target strength", lo=-100.0, hi=60.0,
                                    unit="dB re 1 m²")  # fmt: skip
    position_m: tuple[float, float, float] | None = key(
        None, "vector", "position (fixed, constant-velocity)", unit="m"
    )
    velocity_mps: tuple[float, float, float] = key(
        (0.0, 0.0, 0.0), "vector", "velocity (constant-velocity)", unit="m/s"
    )
    range_m: float | None = key(None, "number", "range from the sonar (radial)", lo=0.0,
                                lo_open=True, unit="m")  # fmt: skip
    speed_mps: float = key(0.0, "number", "closing speed (radial)", unit="m/s")
    azimuth_deg: float = key(0.0, "number", "azimuth (radial)", lo=-360.0, hi=360.0, unit="deg")
    elevation_deg: float = key(0.0, "number", "elevation (radial)", lo=-90.0, hi=90.0,
                               unit="deg")  # fmt: skip
    waypoints_m: list[tuple[float, float, float]] | None = key(
        None, "points", "waypoints (piecewise)", n=2
    )
    speeds_mps: list[float] | None = key(None, "numbers", "leg speeds (piecewise)", lo=0.0,
                                         lo_open=True, unit="m/s")  # fmt: skip
    dwell_s: list[float] | None = key(None, "numbers", "dwell at each waypoint (piecewise)",
                                      lo=0.0, unit="s")  # fmt: skip
    t_start_s: float = key(0.0, "number", "start time (piecewise)", unit="s")

    @classmethod
    def schema_rules(cls) -> dict[str, Any]:
        return {"allOf": [
            {"if": _kind("trajectory", kind), "then": {"required": list(keys)}}
            for kind, keys in TRAJECTORY_KEYS.items()
        ]}  # fmt: skip

    def checks(self, path: str) -> Iterator[ConfigError]:
        for name in TRAJECTORY_KEYS[self.trajectory]:
            if getattr(self, name) is None:
                yield ConfigError(f"{path}.{name}", None, "a value",
                                  f"a {self.trajectory} trajectory needs it")  # fmt: skip
        way, spd = self.waypoints_m, self.speeds_mps
        if way is not None and spd is not None and len(spd) != len(way) - 1:
            yield ConfigError(f"{path}.speeds_mps", spd, f"a list of {len(way) - 1} speeds")


@dataclass(frozen=True)
class TankSection(Section):
    """[tank]: a rectangular tank around sonar and targets (water in 0..L, 0..W, -D..0)."""

    DOCS = DOCS
    size_m: tuple[float, float, float] = required(
        "vector", "length, width, depth", lo=0.0, lo_open=True, unit="m"
    )
    image_order: int = key(1, "integer", "target echo reflections per round trip", lo=0,
                           hi=MAX_TARGET_IMAGE_ORDER)  # fmt: skip
    surface_reflection: float = key(-1.0, "number", "surface reflection", lo=-1.0, hi=1.0)
    wall_reflection: float = key(0.9, "number", "wall reflection", lo=-1.0, hi=1.0)
    bottom_reflection: float = key(0.9, "number", "bottom reflection", lo=-1.0, hi=1.0)
    own_echoes: bool = key(False, "flag", "the tank's own echoes of the transmission")
    own_echo_order: int = key(3, "integer", "image order of the own echoes", lo=0,
                              hi=MAX_IMAGE_ORDER)  # fmt: skip
    late_tail: bool = key(True, "flag", "the diffuse late tail")
    t60_formula: str = key("eyring", "text", "reverberation time formula", choices=T60_FORMULAS)


@dataclass(frozen=True)
class NoiseSection(Section):
    """[noise]: ambient noise (sea state or wind, shipping), or a flat level at an SNR."""

    DOCS = DOCS
    enabled: bool = key(True, "flag", "noise on")
    sea_state: int | None = key(None, "integer", "sea state (instead of wind_speed_mps)", lo=0,
                                hi=9)  # fmt: skip
    wind_speed_mps: float | None = key(None, "number", "wind speed", lo=0.0, hi=80.0, unit="m/s",
                                       shown_default=5.0)  # fmt: skip
    shipping: float = key(0.5, "number", "shipping activity", lo=0.0, hi=1.0)
    self_noise_db: float | None = key(None, "number", "platform self-noise",
                                      unit="dB re 1 µPa²/Hz")  # fmt: skip
    snr_db: float | None = key(None, "number", "first target's echo over the noise", lo=-100.0,
                               hi=200.0, unit="dB")  # fmt: skip
    band_hz: tuple[float, float] | None = key(
        None, "vector", "noise band (default: the waveform's band ± 25 %)", n=2, unit="Hz"
    )
    seed: int | None = key(None, "integer", "noise seed (default: the scenario's)", lo=0,
                           hi=SEED_MAX)  # fmt: skip

    def checks(self, path: str) -> Iterator[ConfigError]:
        if self.sea_state is not None and self.wind_speed_mps is not None:
            yield ConfigError("noise.wind_speed_mps", self.wind_speed_mps,
                              "absent when sea_state is given", "give one of them")  # fmt: skip


@dataclass(frozen=True)
class ReverberationSection(Section):
    """[reverberation]: volume reverberation from a field of point scatterers."""

    DOCS = DOCS
    enabled: bool = key(True, "flag", "reverberation on")
    scattering_strength_db: float | None = key(
        None, "number", "volume scattering strength", lo=-200.0, hi=0.0, unit="dB",
        shown_default=-70.0,
    )  # fmt: skip
    srr_db: float | None = key(None, "number", "first target's echo over the reverberation",
                               lo=-100.0, hi=200.0, unit="dB")  # fmt: skip
    density_per_m3: float = key(0.01, "number", "scatterer density", lo=0.0, lo_open=True,
                                unit="m⁻³")  # fmt: skip
    min_range_m: float = key(1.0, "number", "nearest scatterer", lo=0.0, lo_open=True, unit="m")
    max_range_m: float | None = key(None, "number", "farthest scatterer (default: the preset's "
                                    "range)", lo=0.0, lo_open=True, unit="m")  # fmt: skip
    beam_floor_db: float = key(-40.0, "number", "two-way beam level below which scatterers are"
                               " left out", lo=-200.0, hi=0.0, unit="dB")  # fmt: skip
    taylor_order: int = key(3, "integer", "Taylor order of the delay", lo=0, hi=3)
    frame_samples: int = key(24000, "integer", "frame length", lo=64, hi=1 << 22)
    seed: int | None = key(None, "integer", "scatterer seed (default: the scenario's)", lo=0,
                           hi=SEED_MAX)  # fmt: skip

    def checks(self, path: str) -> Iterator[ConfigError]:
        if self.srr_db is not None and self.scattering_strength_db is not None:
            yield ConfigError("reverberation.srr_db", self.srr_db,
                              "absent when scattering_strength_db is given", "give one of them")  # fmt: skip  # noqa: E501
        if self.max_range_m is not None and self.max_range_m <= self.min_range_m:
            yield ConfigError("reverberation.max_range_m", self.max_range_m,
                              f"> reverberation.min_range_m = {self.min_range_m:g} m")  # fmt: skip


@dataclass(frozen=True)
class DirectBlastSection(Section):
    """[direct_blast]: the transmitter's leakage straight into the receiver."""

    DOCS = DOCS
    enabled: bool = key(True, "flag", "direct blast on")
    coupling_db: float = key(0.0, "number", "coupling", lo=-300.0, hi=60.0, unit="dB")
    separation_m: float = key(0.1, "number", "transmitter-receiver separation", lo=0.0,
                              lo_open=True, unit="m")  # fmt: skip


@dataclass(frozen=True)
class OutputSection(Section):
    """[output]: what ``hil simulate`` writes."""

    DOCS = DOCS
    channels: list[str] = key(["received"], "texts", "WAV channels", choices=OUTPUT_CHANNELS)
    plots: bool = key(True, "flag", "diagnostic plots")
    block_s: float = key(0.5, "number", "rendering block", lo=0.0, lo_open=True, unit="s")

    def checks(self, path: str) -> Iterator[ConfigError]:
        if not self.channels:
            yield ConfigError(
                "output.channels", [], f"a non-empty list of {', '.join(OUTPUT_CHANNELS)}"
            )


@dataclass(frozen=True)
class ScenarioFile(Section):
    """A simulated scenario (hil simulate SCENARIO.toml): hil docs scenarios."""

    preset: str = required("text", "waveform preset", choices=tuple(PRESETS))
    family: str | None = key(None, "text", "waveform family (default: the preset's)",
                             choices=FAMILIES)  # fmt: skip
    fs_hz: float | None = key(None, "number", "sample rate (default: the preset's)", lo=0.0,
                              lo_open=True, unit="Hz")  # fmt: skip
    duration_s: float = key(1.0, "number", "duration", lo=0.0, lo_open=True, hi=86400.0,
                            unit="s")  # fmt: skip
    seed: int = key(0, "integer", "random seed", lo=0, hi=SEED_MAX)
    waveform: dict[str, Any] = key({}, "table", "waveform fields replacing the preset's",
                                   choices=tuple(WaveformSpec.__dataclass_fields__))  # fmt: skip
    environment: EnvironmentSection = key(None, "section", "the water",
                                          section=EnvironmentSection)  # fmt: skip
    sonar: SonarSection = key(None, "section", "the sonar", section=SonarSection)
    targets: list[TargetSection] = key([], "sections", "the targets", section=TargetSection)
    noise: NoiseSection | None = key(None, "section", "ambient noise", section=NoiseSection,
                                     absent_none=True)  # fmt: skip
    reverberation: ReverberationSection | None = key(
        None, "section", "volume reverberation", section=ReverberationSection, absent_none=True
    )
    tank: TankSection | None = key(None, "section", "a tank", section=TankSection,
                                   absent_none=True)  # fmt: skip
    direct_blast: DirectBlastSection | None = key(
        None, "section", "direct blast", section=DirectBlastSection, absent_none=True
    )
    output: OutputSection = key(None, "section", "outputs", section=OutputSection)
