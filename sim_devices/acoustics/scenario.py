"""Scenario files (TOML): load, validate everything before anything runs, build the channel.

The format is documented with examples in ``docs/scenarios.md``. Every problem is a
:class:`~hil.errors.ConfigError` naming the field by its dotted path as written in the file
(``targets[0].speed_mps``), the value and the allowed range: unknown keys, a speed at or above
the sound speed, negative ranges, a sample rate too low for the (Doppler-scaled) band, a
target outside the tank, a missing required value.

Examples
--------
>>> sc = parse_scenario({"preset": "att", "duration_s": 0.01,
...                      "targets": [{"trajectory": "radial", "range_m": 50.0, "speed_mps": 5.0}]})
>>> sc.fs_hz, round(sc.sound_speed_mps, 1), len(sc.targets)
(100000.0, 1500.0, 1)
>>> parse_scenario({"preset": "att", "colour": "red"})
Traceback (most recent call last):
...
hil.errors.ConfigErrors: colour = 'red' is not allowed: must be one of the keys ...
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hil.config_sections import Problems
from hil.errors import ConfigError
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule import HopSchedule
from hil.signals.waveforms import WaveformSpec
from hil.toml_table import read_toml
from sim_devices.acoustics.ambient_noise import AmbientNoiseModel
from sim_devices.acoustics.beam import (
    BeamPattern,
    OmniBeam,
    PistonBeam,
    TwoWayAmplitudeTable,
)
from sim_devices.acoustics.channel import Channel, DirectBlast, Receiver, Target
from sim_devices.acoustics.directivity import TableBeam, Transducer
from sim_devices.acoustics.noise_generator import ShapedNoiseGenerator
from sim_devices.acoustics.reverberation import ReverberationSettings, VolumeReverberation
from sim_devices.acoustics.scenario_sections import (
    MAX_TARGET_IMAGE_ORDER,
    OUTPUT_CHANNELS,
    TRAJECTORIES,
    BeamSection,
    DirectBlastSection,
    EnvironmentSection,
    NoiseSection,
    OutputSection,
    ReverberationSection,
    ScenarioFile,
    SonarSection,
    TankSection,
    TargetSection,
)
from sim_devices.acoustics.tank import Tank
from sim_devices.acoustics.tank_response import TankEchoSettings
from sim_devices.acoustics.trajectory import (
    ConstantVelocity,
    Fixed,
    FloatArray,
    Piecewise,
    Trajectory,
)

__all__ = [
    "MAX_TARGET_IMAGE_ORDER",
    "OUTPUT_CHANNELS",
    "TRAJECTORIES",
    "Scenario",
    "TargetSpec",
    "build_channel",
    "load_scenario",
    "parse_scenario",
]


@dataclass(frozen=True)
class TargetSpec:
    """A validated target: trajectory, target strength (dB re 1 m²), fastest speed (m/s)."""

    trajectory: Trajectory
    target_strength_db: float
    max_speed_mps: float
    start_m: FloatArray


@dataclass
class Scenario:
    """A validated scenario; :func:`build_channel` turns it into a :class:`Channel`."""

    preset: str
    family: str
    fs_hz: float
    duration_s: float
    seed: int
    spec: WaveformSpec
    schedule: HopSchedule
    sound_speed_mps: float
    absorption_db_per_km: float
    sonar_position_m: FloatArray
    sonar_velocity_mps: FloatArray
    source_level_db: float
    receiver: Receiver
    beam: BeamPattern
    beam_axis: FloatArray
    hydrophone_beam: BeamPattern
    hydrophone_axis: FloatArray
    targets: list[TargetSpec]
    noise: dict[str, Any] | None
    reverberation: dict[str, Any] | None
    tank: Tank | None
    image_order: int
    tank_echoes: TankEchoSettings | None
    direct_blast: DirectBlast | None
    output_channels: tuple[str, ...]
    plots: bool
    block_s: float
    raw: dict[str, Any] = field(default_factory=dict)

    @property
    def sonar(self) -> ConstantVelocity:
        """The sonar's constant-velocity trajectory."""
        return ConstantVelocity(self.sonar_position_m, self.sonar_velocity_mps)

    @property
    def max_delay_s(self) -> float:
        """Longest two-way delay of interest (s): the preset's range or the farthest target."""
        r = self.spec.max_range_m
        for t in self.targets:
            r = max(r, float(np.linalg.norm(t.start_m - self.sonar_position_m)))
        return 2.0 * r / self.sound_speed_mps * 1.1


def load_scenario(path: Path) -> Scenario:
    """Read and validate a scenario TOML file."""
    return parse_scenario(read_toml(path, "scenario"))


def parse_scenario(data: dict[str, Any]) -> Scenario:
    """Validate a scenario given as a dict (a parsed TOML document).

    Every table is read by its dataclass (:mod:`sim_devices.acoustics.scenario_sections`),
    then the checks across tables run (:func:`_across_tables`); every problem found is
    reported at once, as a :class:`~hil.errors.ConfigErrors` (one line each).
    """
    problems = Problems()
    tables = ScenarioFile.read_values(data, "", problems)
    sc = None if tables is None else _across_tables(tables, data, problems)
    problems.raise_any()
    assert sc is not None
    return sc


def _across_tables(t: dict[str, Any], data: dict[str, Any], problems: Problems) -> Scenario | None:
    """The checks that span tables, in one place, and the scenario when nothing failed.

    A check that needs a table with a problem of its own is skipped (that problem is already
    reported): speeds against the sound speed, the waveform (its Doppler span from the
    fastest target), beams at the waveform's frequency, sonar and targets inside the tank,
    the noise band and the levels relative to a target.
    """
    env: EnvironmentSection | None = t.get("environment")
    sonar: SonarSection | None = t.get("sonar")
    targets_in: list[TargetSection | None] = t.get("targets", [])
    preset_name: str | None = t.get("preset")
    if preset_name is None or env is None or sonar is None:
        return None
    preset = get_preset(preset_name)
    c = env.sound_speed() or preset.base.sound_speed_mps
    sonar_p, sonar_v = np.asarray(sonar.position_m), np.asarray(sonar.velocity_mps)
    sonar_speed = float(np.linalg.norm(sonar_v))
    if not sonar_speed < c:
        problems.add(ConfigError("sonar.velocity_mps", sonar_speed, f"< c = {c:g} m/s"))
    targets: list[TargetSpec] = []
    for i, tgt in enumerate(targets_in):
        if tgt is not None:
            with problems.collect():
                targets.append(_target(tgt, f"targets[{i}]", sonar_p, c))
    if problems or None in targets_in:
        return None
    family = t.get("family") or preset.base.family
    duration, seed = t.get("duration_s", 1.0), t.get("seed", 0)
    spec, schedule = _waveform(t, family, c, targets, sonar_speed)
    beam = _beam(sonar.beam, spec.center_hz, c)
    hydrophone_beam = _beam(sonar.receive_beam, spec.center_hz, c)
    tank, image_order, tank_echoes = _tank(t.get("tank"), sonar, targets, duration, seed)
    noise = _noise(t.get("noise"), schedule, spec.fs_hz, targets, seed)
    reverb = _reverberation(t.get("reverberation"), spec, env, targets, seed)
    direct = None
    dt: DirectBlastSection | None = t.get("direct_blast")
    if dt is not None and dt.enabled:
        direct = DirectBlast(dt.coupling_db, dt.separation_m)
    out: OutputSection | None = t.get("output")
    if out is None:
        return None
    return Scenario(
        preset=preset.name, family=family, fs_hz=spec.fs_hz, duration_s=duration, seed=seed,
        spec=spec, schedule=schedule, sound_speed_mps=c,
        absorption_db_per_km=env.absorption_db_per_km,
        sonar_position_m=sonar_p, sonar_velocity_mps=sonar_v,
        source_level_db=sonar.source_level_db,
        receiver=Receiver(sonar.sensitivity_db, sonar.gain_db, sonar.full_scale_v),
        beam=beam, beam_axis=_unit(sonar.beam.axis), hydrophone_beam=hydrophone_beam,
        hydrophone_axis=_unit(sonar.receive_beam.axis), targets=targets,
        noise=noise, reverberation=reverb, tank=tank, image_order=image_order,
        tank_echoes=tank_echoes, direct_blast=direct, output_channels=tuple(out.channels),
        plots=out.plots, block_s=out.block_s, raw=data,
    )  # fmt: skip


def _unit(v: tuple[float, float, float]) -> FloatArray:
    a = np.asarray(v, dtype=np.float64)
    return a / np.linalg.norm(a)


def _target(tgt: TargetSection, name: str, sonar_p: FloatArray, c: float) -> TargetSpec:
    """The trajectory of a ``[[targets]]`` table; its speeds below the sound speed ``c``."""

    def speed_check(key: str, v: float) -> None:
        if not abs(v) < c:
            raise ConfigError(
                f"{name}.{key}", v, f"|v| < sound speed c = {c:g} m/s", "check the units (m/s)"
            )

    traj: Trajectory
    kind = tgt.trajectory
    if kind == "fixed":
        assert tgt.position_m is not None
        p = np.asarray(tgt.position_m)
        traj, speed = Fixed(p), 0.0
    elif kind == "constant-velocity":
        assert tgt.position_m is not None
        p, v = np.asarray(tgt.position_m), np.asarray(tgt.velocity_mps)
        speed = float(np.linalg.norm(v))
        speed_check("velocity_mps", speed)
        traj = ConstantVelocity(p, v)
    elif kind == "radial":
        assert tgt.range_m is not None
        speed_check("speed_mps", tgt.speed_mps)
        az, el = math.radians(tgt.azimuth_deg), math.radians(tgt.elevation_deg)
        u = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        p = sonar_p + tgt.range_m * u
        traj, speed = ConstantVelocity(p, -tgt.speed_mps * u), abs(tgt.speed_mps)
    else:
        assert tgt.waypoints_m is not None and tgt.speeds_mps is not None
        for i, leg in enumerate(tgt.speeds_mps):
            if not leg < c:
                raise ConfigError(f"{name}.speeds_mps[{i}]", leg, f"> 0 and < c = {c:g} m/s")
        way = np.asarray(tgt.waypoints_m, dtype=np.float64)
        traj = Piecewise(way, tgt.speeds_mps, dwell_s=tgt.dwell_s, t_start_s=tgt.t_start_s)
        p, speed = way[0], float(max(tgt.speeds_mps))
    return TargetSpec(traj, tgt.target_strength_db, speed, np.asarray(p, dtype=np.float64))


def _waveform(
    t: dict[str, Any], family: str, c: float, targets: list[TargetSpec], sonar_speed: float
) -> tuple[WaveformSpec, HopSchedule]:
    """The preset's waveform with the file's overrides, at the sound speed ``c``, its
    Doppler span covering the fastest target; errors named as the file's keys."""
    preset = get_preset(t["preset"])
    wt: dict[str, Any] = t.get("waveform", {})
    fastest = max([tg.max_speed_mps for tg in targets] + [0.0]) + sonar_speed
    overrides = dict(wt)
    overrides["sound_speed_mps"] = c
    if t.get("fs_hz") is not None:
        overrides["fs_hz"] = t["fs_hz"]
    try:
        base = preset.spec(family, **{k: v for k, v in overrides.items() if k != "max_speed_mps"})
        overrides["max_speed_mps"] = max(
            float(wt.get("max_speed_mps", base.max_speed_mps)), fastest
        )
        spec = preset.spec(family, **overrides)
        return spec, check_design(spec)
    except ConfigError as exc:
        where = exc.field
        if where == "fs_hz":
            where = "fs_hz" if t.get("fs_hz") is not None or "fs_hz" not in wt else "waveform.fs_hz"
        elif where in wt or where in WaveformSpec.__dataclass_fields__:
            where = f"waveform.{where}"
        raise ConfigError(where, exc.value, exc.allowed, exc.hint) from None


def _tank(
    tt: TankSection | None,
    sonar: SonarSection,
    targets: list[TargetSpec],
    duration: float,
    seed: int,
) -> tuple[Tank | None, int, TankEchoSettings | None]:
    """The tank, the target's image order and the own echoes; sonar and targets inside it."""
    if tt is None:
        return None, 0, None
    tank = Tank(*tt.size_m, wall_reflection=tt.wall_reflection,
                bottom_reflection=tt.bottom_reflection, surface_reflection=tt.surface_reflection)  # fmt: skip  # noqa: E501
    echoes = None
    sonar_p, sonar_v = np.asarray(sonar.position_m), np.asarray(sonar.velocity_mps)
    if tt.own_echoes:
        if float(np.linalg.norm(sonar_v)) != 0.0:
            raise ConfigError(
                "tank.own_echoes", True, "a sonar at rest (sonar.velocity_mps = 0)",
                "turn own_echoes off for a moving sonar",
            )  # fmt: skip
        echoes = TankEchoSettings(order=tt.own_echo_order, tail=tt.late_tail,
                                  t60_formula=tt.t60_formula, seed=seed + 7)  # fmt: skip
    tank.check_inside(sonar_p, "sonar.position_m")
    tank.check_inside(sonar_p + sonar_v * duration, "sonar.position_m + velocity_mps·duration_s")
    for i, tgt in enumerate(targets):
        for when in (0.0, duration):
            p = tgt.trajectory.position(np.array([when]))[0]
            tank.check_inside(p, f"targets[{i}] position at t = {when:g} s")
    return tank, tt.image_order, echoes


def _noise(
    nt: NoiseSection | None,
    schedule: HopSchedule,
    fs: float,
    targets: list[TargetSpec],
    seed: int,
) -> dict[str, Any] | None:
    """The noise settings :func:`build_channel` scales: band within Nyquist, an SNR only
    with a target to set it against."""
    if nt is None or not nt.enabled:
        return None
    f_lo, f_hi = schedule.min_frequency_hz(), schedule.max_frequency_hz()
    bw = f_hi - f_lo
    band = nt.band_hz or (max(1.0, f_lo - 0.25 * bw), min(0.499 * fs, f_hi + 0.25 * bw))
    if not 0 <= band[0] < band[1] <= fs / 2:
        raise ConfigError("noise.band_hz", list(band), f"0 <= low < high <= fs/2 = {fs / 2:g} Hz")
    if nt.snr_db is not None and not targets:
        raise ConfigError("noise.snr_db", nt.snr_db, "used with at least one target",
                          "the SNR is the first target's echo power over the noise power")  # fmt: skip  # noqa: E501
    return {
        "sea_state": nt.sea_state,
        "wind_speed_mps": 5.0 if nt.wind_speed_mps is None else nt.wind_speed_mps,
        "shipping": nt.shipping,
        "self_noise_db": nt.self_noise_db,
        "snr_db": nt.snr_db,
        "band_hz": tuple(band),
        "seed": seed if nt.seed is None else nt.seed,
    }


def _reverberation(
    rt: ReverberationSection | None,
    spec: WaveformSpec,
    env: EnvironmentSection,
    targets: list[TargetSpec],
    seed: int,
) -> dict[str, Any] | None:
    """The reverberation settings: out to the preset's range unless given; an SRR only with
    a target to set it against."""
    if rt is None or not rt.enabled:
        return None
    if rt.srr_db is not None and not targets:
        raise ConfigError("reverberation.srr_db", rt.srr_db, "used with at least one target")
    r_max = spec.max_range_m if rt.max_range_m is None else rt.max_range_m
    if r_max <= rt.min_range_m:
        raise ConfigError("reverberation.min_range_m", rt.min_range_m,
                          f"< the preset's range {r_max:g} m", "or give max_range_m")  # fmt: skip
    ss = -70.0 if rt.scattering_strength_db is None else rt.scattering_strength_db
    return {
        "settings": ReverberationSettings(
            density_per_m3=rt.density_per_m3, scattering_strength_db=ss, max_range_m=r_max,
            min_range_m=rt.min_range_m, beam_floor_db=rt.beam_floor_db,
            taylor_order=rt.taylor_order, frame_samples=rt.frame_samples,
            absorption_db_per_km=env.absorption_db_per_km,
            seed=seed if rt.seed is None else rt.seed,
        ),
        "srr_db": rt.srr_db,
    }  # fmt: skip


def build_channel(sc: Scenario) -> Channel:
    """The :class:`Channel` of a validated scenario (noise and reverberation scaled)."""
    table = TwoWayAmplitudeTable(sc.beam, sc.hydrophone_beam)
    channel = Channel(
        waveform=sc.schedule, fs_hz=sc.fs_hz, sonar=sc.sonar, source_level_db=sc.source_level_db,
        sound_speed_mps=sc.sound_speed_mps,
        targets=[Target(t.trajectory, t.target_strength_db) for t in sc.targets],
        receiver=sc.receiver, tx_beam=Transducer(sc.beam, sc.beam_axis),
        rx_beam=Transducer(sc.hydrophone_beam, sc.hydrophone_axis),
        absorption_db_per_km=sc.absorption_db_per_km, tank=sc.tank, image_order=sc.image_order,
        tank_echoes=sc.tank_echoes, direct_blast=sc.direct_blast,
    )  # fmt: skip
    if sc.reverberation is not None:
        f_ref = 0.5 * (sc.schedule.min_frequency_hz() + sc.schedule.max_frequency_hz())
        rev = VolumeReverberation(
            sc.schedule, sc.fs_hz, source_amplitude_upa=channel.amplitude, reference_hz=f_ref,
            sonar_position_m=sc.sonar_position_m, sonar_velocity_mps=sc.sonar_velocity_mps,
            beam=table, beam_axis=sc.beam_axis, sound_speed_mps=sc.sound_speed_mps,
            settings=sc.reverberation["settings"],
        )  # fmt: skip
        srr = sc.reverberation["srr_db"]
        if srr is not None:
            p_rev = rev.expected_power(0.0)
            if p_rev <= 0:
                raise ConfigError("reverberation.srr_db", srr, "a field with scatterers in the beam",  # noqa: E501
                                  "raise density_per_m3 or max_range_m")  # fmt: skip
            rev.scale = math.sqrt(channel.echo_power(0) / (10.0 ** (srr / 10.0) * p_rev))
        channel.reverberation = rev
    if sc.noise is not None:
        nz = sc.noise
        band = nz["band_hz"]
        if nz["snr_db"] is not None:
            level = (
                10.0 * math.log10(channel.echo_power(0))
                - nz["snr_db"]
                - 10.0 * math.log10(band[1] - band[0])
            )
            model: Any = _FlatSpectrum(level)
        elif nz["sea_state"] is not None:
            model = AmbientNoiseModel.from_sea_state(
                nz["sea_state"], nz["shipping"], nz["self_noise_db"]
            )
        else:
            model = AmbientNoiseModel(nz["wind_speed_mps"], nz["shipping"], nz["self_noise_db"])
        channel.noise = ShapedNoiseGenerator(model, sc.fs_hz, band, seed=nz["seed"], n_taps=2049)
    return channel


def _beam(bt: BeamSection, center_hz: float, c: float) -> BeamPattern:
    """The pattern of a ``beam`` table: omni, piston (``ka``, or ``radius_m`` at
    ``frequency_hz``, default the waveform's centre) or a table (``angles_deg``, ``levels_db``)."""
    if bt.type == "piston":
        if bt.ka is not None:
            return PistonBeam(bt.ka)
        assert bt.radius_m is not None
        f = center_hz if bt.frequency_hz is None else bt.frequency_hz
        return PistonBeam.from_radius(bt.radius_m, f, c)
    if bt.type == "table":
        assert bt.angles_deg is not None and bt.levels_db is not None
        return TableBeam(bt.angles_deg, bt.levels_db)
    return OmniBeam()


class _FlatSpectrum:
    """A flat spectrum level (dB re 1 µPa²/Hz) at every frequency."""

    def __init__(self, level_db: float) -> None:
        self.level_db = float(level_db)

    def __call__(self, frequency_hz: FloatArray) -> FloatArray:
        return np.full(np.shape(frequency_hz), self.level_db)
