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
hil.errors.ConfigError: colour = 'red' is not allowed: must be one of the keys ...
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hil.errors import ConfigError
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule import HopSchedule
from hil.signals.waveforms import WaveformSpec
from hil.toml_table import Table, read_toml
from sim_devices.acoustics.ambient_noise import AmbientNoiseModel
from sim_devices.acoustics.beam import (
    BeamPattern,
    OmniBeam,
    PistonBeam,
    TwoWayAmplitudeTable,
)
from sim_devices.acoustics.channel import Channel, DirectBlast, Receiver, Target
from sim_devices.acoustics.directivity import TableBeam, Transducer
from sim_devices.acoustics.images import MAX_IMAGE_ORDER
from sim_devices.acoustics.noise_generator import ShapedNoiseGenerator
from sim_devices.acoustics.reverberation import ReverberationSettings, VolumeReverberation
from sim_devices.acoustics.sound_speed import tank_sound_speed, unesco_sound_speed
from sim_devices.acoustics.tank import Tank
from sim_devices.acoustics.tank_response import T60_FORMULAS, TankEchoSettings
from sim_devices.acoustics.trajectory import (
    ConstantVelocity,
    Fixed,
    FloatArray,
    Piecewise,
    Trajectory,
)

OUTPUT_CHANNELS = (
    "received", "pressure", "echo", "reverberation", "noise", "direct", "tank",
)  # fmt: skip
#: Highest image order of the target's echoes (reflections per round trip): 1, 13, 85, 377,
#: 1289 echo paths for N = 0 … 4, each solved and rendered per sample.
MAX_TARGET_IMAGE_ORDER = 4
TRAJECTORIES = ("fixed", "constant-velocity", "radial", "piecewise")

_TOP = ("preset", "family", "fs_hz", "duration_s", "seed", "waveform", "environment", "sonar",
        "targets", "noise", "reverberation", "tank", "direct_blast", "output")  # fmt: skip


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


def _sound_speed(env: Table) -> float:
    if env.has("sound_speed_mps"):
        for other in ("temperature_c", "salinity_ppt"):
            if env.has(other):
                raise ConfigError(
                    env.name(other), env.data[other], "absent when sound_speed_mps is given",
                    "give either the sound speed or the water temperature/salinity",
                )  # fmt: skip
        return env.number("sound_speed_mps", lo=1300.0, hi=1800.0, unit="m/s")
    if env.has("temperature_c"):
        t = env.number("temperature_c", lo=0.0, hi=40.0, unit="°C")
        s = env.number("salinity_ppt", 0.0, lo=0.0, hi=40.0, unit="ppt")
        depth = env.number("depth_m", 1.0, lo=0.0, hi=10000.0, unit="m")
        if s == 0.0:
            return float(tank_sound_speed(t))
        return float(unesco_sound_speed(s, 1.00024 * t, depth * 1.0))
    return float("nan")  # the preset's


def _target(tbl: Table, sonar_p: FloatArray, c: float) -> TargetSpec:
    kind = tbl.text("trajectory", None, TRAJECTORIES)
    ts = tbl.number("target_strength_db", 0.0, lo=-100.0, hi=60.0, unit="dB re 1 m²")

    def speed_check(key: str, v: float) -> None:
        if not abs(v) < c:
            raise ConfigError(
                tbl.name(key), v, f"|v| < sound speed c = {c:g} m/s", "check the units (m/s)"
            )

    traj: Trajectory
    if kind == "fixed":
        p = tbl.vector("position_m")
        traj, speed = Fixed(p), 0.0
    elif kind == "constant-velocity":
        p, v = tbl.vector("position_m"), tbl.vector("velocity_mps", (0.0, 0.0, 0.0))
        speed = float(np.linalg.norm(v))
        speed_check("velocity_mps", speed)
        traj = ConstantVelocity(p, v)
    elif kind == "radial":
        rng = tbl.number("range_m", lo=0.0, lo_open=True, unit="m")
        speed = tbl.number("speed_mps", 0.0, unit="m/s")
        speed_check("speed_mps", speed)
        az = math.radians(tbl.number("azimuth_deg", 0.0, lo=-360.0, hi=360.0, unit="deg"))
        el = math.radians(tbl.number("elevation_deg", 0.0, lo=-90.0, hi=90.0, unit="deg"))
        u = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        p = sonar_p + rng * u
        traj = ConstantVelocity(p, -speed * u)
        speed = abs(speed)
    else:
        pts = tbl.data.get("waypoints_m")
        if not isinstance(pts, list) or len(pts) < 2:
            raise ConfigError(tbl.name("waypoints_m"), pts, "a list of >= 2 points [x, y, z]")
        way = np.asarray(pts, dtype=np.float64)
        spd = tbl.data.get("speeds_mps")
        if not isinstance(spd, list) or len(spd) != len(pts) - 1:
            raise ConfigError(tbl.name("speeds_mps"), spd, f"a list of {len(pts) - 1} speeds")
        for i, v in enumerate(spd):
            if isinstance(v, bool) or not isinstance(v, int | float) or not 0 < v < c:
                raise ConfigError(f"{tbl.name('speeds_mps')}[{i}]", v, f"> 0 and < c = {c:g} m/s")
        dwell = tbl.data.get("dwell_s")
        traj = Piecewise(way, spd, dwell_s=dwell, t_start_s=tbl.number("t_start_s", 0.0))
        p, speed = way[0], float(max(spd))
    return TargetSpec(traj, ts, speed, np.asarray(p, dtype=np.float64))


def parse_scenario(data: dict[str, Any]) -> Scenario:
    """Validate a scenario given as a dict (a parsed TOML document)."""
    top = Table(data, "", _TOP)
    preset_name = top.data.get("preset")
    if preset_name is None:
        raise ConfigError("preset", None, "one of att, tank-audio, tank-board", "it is required")
    preset = get_preset(str(preset_name))
    family = str(top.data.get("family", preset.base.family))
    duration = top.number("duration_s", 1.0, lo=0.0, lo_open=True, hi=86400.0, unit="s")
    seed = top.integer("seed", 0, 0, 2**32 - 1)
    env = top.sub("environment", ("sound_speed_mps", "temperature_c", "salinity_ppt", "depth_m",
                                  "absorption_db_per_km"))  # fmt: skip
    c = _sound_speed(env)
    if math.isnan(c):
        c = preset.base.sound_speed_mps
    absorption = env.number("absorption_db_per_km", 0.0, lo=0.0, hi=1000.0, unit="dB/km")

    sonar = top.sub("sonar", ("position_m", "velocity_mps", "source_level_db", "sensitivity_db",
                              "gain_db", "full_scale_v", "beam", "hydrophone_beam"))  # fmt: skip
    sonar_p = sonar.vector("position_m", (0.0, 0.0, 0.0))
    sonar_v = sonar.vector("velocity_mps", (0.0, 0.0, 0.0))
    sonar_speed = float(np.linalg.norm(sonar_v))
    if not sonar_speed < c:
        raise ConfigError(sonar.name("velocity_mps"), sonar_speed, f"< c = {c:g} m/s")
    sl = sonar.number("source_level_db", 200.0, lo=0.0, hi=260.0, unit="dB re 1 µPa @ 1 m")
    receiver = Receiver(
        sonar.number("sensitivity_db", -180.0, lo=-300.0, hi=0.0, unit="dB re 1 V/µPa"),
        sonar.number("gain_db", 0.0, lo=-60.0, hi=120.0, unit="dB"),
        sonar.number("full_scale_v", 1.0, lo=0.0, lo_open=True, unit="V"),
    )
    beam_tables = [
        sonar.sub(key, ("type", "ka", "radius_m", "frequency_hz", "axis", "angles_deg",
                        "levels_db"))
        for key in ("beam", "hydrophone_beam")
    ]  # fmt: skip
    if not sonar.has("hydrophone_beam"):
        beam_tables[1] = beam_tables[0]  # one transducer sends and receives
    axes = []
    for bt in beam_tables:
        axis = bt.vector("axis", (1.0, 0.0, 0.0))
        if not np.any(axis):
            raise ConfigError(bt.name("axis"), axis.tolist(), "a non-zero vector")
        axes.append(axis / np.linalg.norm(axis))

    raw_targets = top.data.get("targets", [])
    if not isinstance(raw_targets, list):
        raise ConfigError("targets", raw_targets, "an array of tables [[targets]]")
    targets = [
        _target(
            Table(
                t,
                f"targets[{i}]",
                (
                    "trajectory",
                    "target_strength_db",
                    "position_m",
                    "velocity_mps",
                    "range_m",
                    "speed_mps",
                    "azimuth_deg",
                    "elevation_deg",
                    "waypoints_m",
                    "speeds_mps",
                    "dwell_s",
                    "t_start_s",
                ),
            ),
            sonar_p,
            c,
        )
        for i, t in enumerate(raw_targets)
    ]

    wt = top.data.get("waveform", {})
    wtab = Table(wt, "waveform", tuple(WaveformSpec.__dataclass_fields__))
    fastest = max([t.max_speed_mps for t in targets] + [0.0]) + sonar_speed
    overrides = dict(wtab.data)
    overrides["sound_speed_mps"] = c
    if top.has("fs_hz"):
        overrides["fs_hz"] = top.number("fs_hz", lo=0.0, lo_open=True, unit="Hz")
    base = preset.spec(family, **{k: v for k, v in overrides.items() if k != "max_speed_mps"})
    overrides["max_speed_mps"] = max(float(wt.get("max_speed_mps", base.max_speed_mps)), fastest)
    try:
        spec = preset.spec(family, **overrides)
        schedule = check_design(spec)
    except ConfigError as exc:
        where = exc.field
        if where == "fs_hz":
            where = "fs_hz" if top.has("fs_hz") or "fs_hz" not in wtab.data else "waveform.fs_hz"
        elif where in wtab.data or where in WaveformSpec.__dataclass_fields__:
            where = f"waveform.{where}"
        raise ConfigError(where, exc.value, exc.allowed, exc.hint) from None
    beam, hydrophone_beam = (_beam(bt, spec.center_hz, c) for bt in beam_tables)

    tank: Tank | None = None
    image_order = 0
    tank_echoes: TankEchoSettings | None = None
    if top.has("tank"):
        tt = top.sub("tank", ("size_m", "image_order", "surface_reflection", "wall_reflection",
                              "bottom_reflection", "own_echoes", "own_echo_order", "late_tail",
                              "t60_formula"))  # fmt: skip
        size = tt.vector("size_m")
        for i, v in enumerate(size):
            if not v > 0:
                raise ConfigError(f"{tt.name('size_m')}[{i}]", float(v), "> 0 m")
        tank = Tank(
            float(size[0]), float(size[1]), float(size[2]),
            wall_reflection=tt.number("wall_reflection", 0.9, lo=-1.0, hi=1.0),
            bottom_reflection=tt.number("bottom_reflection", 0.9, lo=-1.0, hi=1.0),
            surface_reflection=tt.number("surface_reflection", -1.0, lo=-1.0, hi=1.0),
        )  # fmt: skip
        image_order = tt.integer("image_order", 1, 0, MAX_TARGET_IMAGE_ORDER)
        if tt.flag("own_echoes", False):
            tank_echoes = TankEchoSettings(
                order=tt.integer("own_echo_order", 3, 0, MAX_IMAGE_ORDER),
                tail=tt.flag("late_tail", True),
                t60_formula=tt.text("t60_formula", "eyring", T60_FORMULAS),
                seed=seed + 7,
            )
            if float(np.linalg.norm(sonar_v)) != 0.0:
                raise ConfigError(
                    tt.name("own_echoes"), True, "a sonar at rest (sonar.velocity_mps = 0)",
                    "turn own_echoes off for a moving sonar",
                )  # fmt: skip
        tank.check_inside(sonar_p, "sonar.position_m")
        tank.check_inside(
            sonar_p + sonar_v * duration, "sonar.position_m + velocity_mps·duration_s"
        )
        for i, tgt in enumerate(targets):
            for when in (0.0, duration):
                p = tgt.trajectory.position(np.array([when]))[0]
                tank.check_inside(p, f"targets[{i}] position at t = {when:g} s")

    noise: dict[str, Any] | None = None
    nt = top.sub("noise", ("enabled", "sea_state", "wind_speed_mps", "shipping", "self_noise_db",
                           "snr_db", "band_hz", "seed"))  # fmt: skip
    if nt.flag("enabled", top.has("noise")):
        if nt.has("sea_state") and nt.has("wind_speed_mps"):
            raise ConfigError(nt.name("wind_speed_mps"), nt.data["wind_speed_mps"],
                              "absent when sea_state is given", "give one of them")  # fmt: skip
        f_lo, f_hi = schedule.min_frequency_hz(), schedule.max_frequency_hz()
        bw = f_hi - f_lo
        default_band = (max(1.0, f_lo - 0.25 * bw), min(0.499 * spec.fs_hz, f_hi + 0.25 * bw))
        band = tuple(nt.vector("band_hz", default_band, n=2).tolist())
        if not 0 <= band[0] < band[1] <= spec.fs_hz / 2:
            raise ConfigError(
                nt.name("band_hz"), list(band), f"0 <= low < high <= fs/2 = {spec.fs_hz / 2:g} Hz"
            )
        if nt.has("snr_db") and not targets:
            raise ConfigError(nt.name("snr_db"), nt.data["snr_db"], "used with at least one target",
                              "the SNR is the first target's echo power over the noise power")  # fmt: skip  # noqa: E501
        noise = {
            "sea_state": nt.integer("sea_state", 3, 0, 9) if nt.has("sea_state") else None,
            "wind_speed_mps": nt.number("wind_speed_mps", 5.0, lo=0.0, hi=80.0, unit="m/s"),
            "shipping": nt.number("shipping", 0.5, lo=0.0, hi=1.0),
            "self_noise_db": nt.number("self_noise_db") if nt.has("self_noise_db") else None,
            "snr_db": nt.number("snr_db", lo=-100.0, hi=200.0, unit="dB")
            if nt.has("snr_db")
            else None,
            "band_hz": band,
            "seed": nt.integer("seed", seed, 0, 2**32 - 1),
        }

    reverb: dict[str, Any] | None = None
    rt = top.sub("reverberation", ("enabled", "scattering_strength_db", "srr_db", "density_per_m3",
                                   "min_range_m", "max_range_m", "beam_floor_db", "taylor_order",
                                   "frame_samples", "seed"))  # fmt: skip
    if rt.flag("enabled", top.has("reverberation")):
        if rt.has("srr_db") and rt.has("scattering_strength_db"):
            raise ConfigError(rt.name("srr_db"), rt.data["srr_db"],
                              "absent when scattering_strength_db is given", "give one of them")  # fmt: skip  # noqa: E501
        if rt.has("srr_db") and not targets:
            raise ConfigError(rt.name("srr_db"), rt.data["srr_db"], "used with at least one target")
        r_min = rt.number("min_range_m", 1.0, lo=0.0, lo_open=True, unit="m")
        r_max = rt.number("max_range_m", spec.max_range_m, lo=r_min, lo_open=True, unit="m")
        reverb = {
            "settings": ReverberationSettings(
                density_per_m3=rt.number("density_per_m3", 0.01, lo=0.0, lo_open=True, unit="m⁻³"),
                scattering_strength_db=rt.number("scattering_strength_db", -70.0, lo=-200.0, hi=0.0, unit="dB"),  # noqa: E501
                max_range_m=r_max,
                min_range_m=r_min,
                beam_floor_db=rt.number("beam_floor_db", -40.0, lo=-200.0, hi=0.0, unit="dB"),
                taylor_order=rt.integer("taylor_order", 3, 0, 3),
                frame_samples=rt.integer("frame_samples", 24000, 64, 1 << 22),
                absorption_db_per_km=absorption,
                seed=rt.integer("seed", seed, 0, 2**32 - 1),
            ),
            "srr_db": rt.number("srr_db", lo=-100.0, hi=200.0, unit="dB") if rt.has("srr_db") else None,  # noqa: E501
        }  # fmt: skip

    direct: DirectBlast | None = None
    dt = top.sub("direct_blast", ("enabled", "coupling_db", "separation_m"))
    if dt.flag("enabled", top.has("direct_blast")):
        direct = DirectBlast(
            dt.number("coupling_db", 0.0, lo=-300.0, hi=60.0, unit="dB"),
            dt.number("separation_m", 0.1, lo=0.0, lo_open=True, unit="m"),
        )

    ot = top.sub("output", ("channels", "plots", "block_s"))
    channels = ot.data.get("channels", ["received"])
    if (
        not isinstance(channels, list)
        or not channels
        or any(ch not in OUTPUT_CHANNELS for ch in channels)
    ):
        raise ConfigError(
            ot.name("channels"), channels, f"a non-empty list of {', '.join(OUTPUT_CHANNELS)}"
        )
    return Scenario(
        preset=preset.name, family=family, fs_hz=spec.fs_hz, duration_s=duration, seed=seed,
        spec=spec, schedule=schedule, sound_speed_mps=c, absorption_db_per_km=absorption,
        sonar_position_m=sonar_p, sonar_velocity_mps=sonar_v, source_level_db=sl,
        receiver=receiver, beam=beam, beam_axis=axes[0], hydrophone_beam=hydrophone_beam,
        hydrophone_axis=axes[1], targets=targets,
        noise=noise, reverberation=reverb, tank=tank, image_order=image_order,
        tank_echoes=tank_echoes,
        direct_blast=direct, output_channels=tuple(channels),
        plots=ot.flag("plots", True), block_s=ot.number("block_s", 0.5, lo=0.0, lo_open=True, unit="s"),  # noqa: E501
        raw=data,
    )  # fmt: skip


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


def _beam(bt: Table, center_hz: float, c: float) -> BeamPattern:
    """The pattern of a ``beam`` table: omni, piston (``ka``, or ``radius_m`` at
    ``frequency_hz``, default the waveform's centre) or a table (``angles_deg``, ``levels_db``)."""
    kind = bt.text("type", "omni", ("omni", "piston", "table"))
    if kind == "piston":
        if bt.has("ka"):
            return PistonBeam(bt.number("ka", lo=0.0, lo_open=True))
        radius = bt.number("radius_m", lo=0.0, lo_open=True, unit="m")
        f = bt.number("frequency_hz", center_hz, lo=0.0, lo_open=True, unit="Hz")
        return PistonBeam.from_radius(radius, f, c)
    if kind == "table":
        for key in ("angles_deg", "levels_db"):
            if not isinstance(bt.data.get(key), list):
                raise ConfigError(bt.name(key), bt.data.get(key), "a list of numbers")
        return TableBeam(bt.data["angles_deg"], bt.data["levels_db"])
    return OmniBeam()


class _FlatSpectrum:
    """A flat spectrum level (dB re 1 µPa²/Hz) at every frequency."""

    def __init__(self, level_db: float) -> None:
        self.level_db = float(level_db)

    def __call__(self, frequency_hz: FloatArray) -> FloatArray:
        return np.full(np.shape(frequency_hz), self.level_db)
