"""The experiment file of a towed-target tank run (TOML), validated before any device is
touched.

Every problem is a :class:`~hil.errors.ConfigError` naming the field by its dotted path as
written in the file (``tow.speed_mps``), the value, the allowed range and what to do. The
format is documented in ``docs/tank-run.md``; :data:`DEFAULT_EXPERIMENT` is the built-in
simulated run that ``hil tank-run`` uses without arguments.

Coordinates: the tank frame has x along the tank length, y across, z up with the water
surface at z = 0 (so depths are negative), metres. The stage is GRBL's X axis, whose machine
positions are in ``[-travel, 0]`` (0 at the homing switch): the towed target sits at
``tank.stage_origin_m + x_stage · tank.stage_axis``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hil.devices.table import check_device_url, is_simulated
from hil.errors import ConfigError
from hil.estimation.first_arrival import RANGE_READOUTS
from hil.estimation.reverb_band import AUTO, doppler_resolution_mps, resolve_reverb_speed
from hil.paths import resolve_calibration_dir, resolve_runs_dir
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule import HopSchedule
from hil.signals.waveforms import WaveformSpec
from hil.toml_table import Table, did_you_mean, parse_toml, read_text_file

DEFAULT_EXPERIMENT = """\
# Built-in simulated tank run: `hil tank-run` with no arguments.
[run]
name = "sim-towed-pass"
output_dir = "runs"

[devices]
board = "sim://board"
stage = "sim://stage"

[waveform]
preset = "tank-audio"
family = "random-cyclic"
amplitude = 0.5

[tank]
size_m = [12.0, 4.0, 2.5]
water_temperature_c = 20.0
transducer_position_m = [0.5, 2.0, -1.2]
stage_origin_m = [11.0, 2.0, -1.2]
stage_axis = [1.0, 0.0, 0.0]

[tow]
start_m = -2.0
end_m = -5.0
speed_mps = 1.5
repeats = 1
run_up_m = 0.6
run_down_m = 0.6

[receiver]
# GCAS behind a one-code-period clutter canceller: the tank's own echoes and tail do not move,
# and outshine the target (docs/tank-run.md, "The receiver in the tank").
name = "gcas-mti"
m_hops = 10
max_speed_mps = 3.0
max_range_m = 12.0
# No options: the reverberation band is derived from the tow (see docs/tank-run.md).

[calibration]
store = "calibration"
max_age_days = 30.0
required = []

[simulation]
source_level_db = 185.0
target_strength_db = -12.0
sensitivity_db = -200.0
gain_db = 10.0
image_order = 1
tank_echoes = true
tank_echo_order = 3
late_tail = true
transducer_beam = "piston"
transducer_radius_m = 0.015
hydrophone_beam = "omni"
noise_level_db = 55.0
reverberation = true
scattering_strength_db = -70.0
time_scale = 0.4
seed = 1
"""

#: Image order limit (reflections per round trip) of the simulated target's echoes (1, 13,
#: 85, 377, 1289 paths for 0 … 4, each rendered per sample) and of the tank's own echoes
#: (one convolution, any order).
MAX_TARGET_IMAGE_ORDER = 4
MAX_TANK_ECHO_ORDER = 40
#: Directivity of the simulated projector and hydrophone: omni, or a baffled circular
#: piston of the given radius at the waveform's centre frequency.
BEAM_KINDS = ("omni", "piston")

_SECTIONS: dict[str, tuple[str, ...]] = {
    "run": ("name", "output_dir", "max_duration_s"),
    "devices": ("board", "stage", "board_channel"),
    "waveform": ("preset", "family", "amplitude", "overrides"),
    "tank": (
        "size_m",
        "water_temperature_c",
        "salinity_ppt",
        "sound_speed_mps",
        "transducer_position_m",
        "stage_origin_m",
        "stage_axis",
    ),
    "tow": ("start_m", "end_m", "speed_mps", "repeats", "run_up_m", "run_down_m"),
    "receiver": ("name", "m_hops", "max_speed_mps", "max_range_m", "options"),
    "calibration": ("store", "max_age_days", "required"),
    "simulation": (
        "source_level_db",
        "target_strength_db",
        "sensitivity_db",
        "gain_db",
        "image_order",
        "tank_echoes",
        "tank_echo_order",
        "late_tail",
        "wall_reflection",
        "bottom_reflection",
        "transducer_beam",
        "transducer_radius_m",
        "hydrophone_beam",
        "hydrophone_radius_m",
        "noise_level_db",
        "reverberation",
        "scattering_strength_db",
        "time_scale",
        "seed",
    ),
}
_REQUIRED = {"devices": ("board", "stage"), "tow": ("start_m", "end_m", "speed_mps")}


@dataclass(frozen=True)
class TowPlan:
    """A constant-speed pass of the stage, stage coordinates (m) and m/s."""

    start_m: float
    end_m: float
    speed_mps: float
    repeats: int = 1
    run_up_m: float = 0.5
    run_down_m: float = 0.5


@dataclass(frozen=True)
class SimulationSettings:
    """The simulated world behind ``sim://`` devices (ignored for real hardware)."""

    source_level_db: float = 185.0
    target_strength_db: float = -12.0
    sensitivity_db: float = -200.0
    gain_db: float = 30.0
    image_order: int = 1
    tank_echoes: bool = False
    tank_echo_order: int = 3
    late_tail: bool = True
    wall_reflection: float = 0.9
    bottom_reflection: float = 0.9
    transducer_beam: str = "piston"
    transducer_radius_m: float = 0.015
    hydrophone_beam: str = "omni"
    hydrophone_radius_m: float = 0.015
    noise_level_db: float = 40.0
    reverberation: bool = True
    scattering_strength_db: float = -70.0
    time_scale: float = 0.5
    seed: int = 1


@dataclass(frozen=True)
class Experiment:
    """A validated experiment file; build it with :func:`parse_experiment`."""

    name: str
    output_dir: Path
    max_duration_s: float
    board_url: str
    stage_url: str
    board_channel: int
    waveform: WaveformSpec
    schedule: HopSchedule
    preset: str
    amplitude: float
    tank_size_m: tuple[float, float, float]
    water_temperature_c: float
    salinity_ppt: float
    sound_speed_mps: float
    transducer_m: tuple[float, float, float]
    stage_origin_m: tuple[float, float, float]
    stage_axis: tuple[float, float, float]
    tow: TowPlan
    receiver: str
    m_hops: int
    max_speed_mps: float
    max_range_m: float
    receiver_options: dict[str, Any]
    calibration_store: Path
    calibration_max_age_days: float
    calibration_required: tuple[str, ...]
    simulation: SimulationSettings
    text: str = field(default="", compare=False)

    @property
    def simulated(self) -> bool:
        """True when both devices are simulated (``sim://``)."""
        return is_simulated(self.board_url) and is_simulated(self.stage_url)

    def target_position(self, x_stage_m: np.ndarray) -> np.ndarray:
        """Tank position (m, shape ``(..., 3)``) of the target at stage positions (m)."""
        x = np.asarray(x_stage_m, dtype=np.float64)
        return np.asarray(self.stage_origin_m) + np.multiply.outer(x, np.asarray(self.stage_axis))

    def range_at(self, x_stage_m: np.ndarray) -> np.ndarray:
        """Distance (m) from the transducer to the target at stage positions (m)."""
        d = self.target_position(x_stage_m) - np.asarray(self.transducer_m)
        return np.asarray(np.sqrt(np.sum(d * d, axis=-1)))


def load_experiment(path: Path) -> Experiment:
    """Read and validate an experiment file."""
    try:
        text = read_text_file(path, "experiment")
    except FileNotFoundError:
        raise ConfigError("experiment", str(path), "an existing TOML file") from None
    return parse_experiment(text, str(path))


def parse_experiment(text: str, source: str = "<text>") -> Experiment:
    """Validate experiment TOML text (see the module docstring); nothing is touched."""
    data = parse_toml(text, "experiment", source)
    unknown = sorted(set(data) - set(_SECTIONS))
    if unknown:
        raise ConfigError(
            unknown[0],
            data[unknown[0]],
            f"one of the tables {', '.join(_SECTIONS)}",
            "remove it or fix its spelling" + did_you_mean(unknown[0], tuple(_SECTIONS)),
        )
    # The tables first (a list of tables, a misspelt key), then what is missing: a key
    # misspelt is named as such, not as a required key that is absent.
    t = {
        name: Table(data.get(name, {}), name, keys, "hil docs tank-run")
        for name, keys in _SECTIONS.items()
    }
    for section, keys in _REQUIRED.items():
        for key in keys:
            if key not in data.get(section, {}):
                raise ConfigError(f"{section}.{key}", None, "a value", "it is required")

    run, dev, wav, tank, tow, rec, cal, sim = (t[k] for k in _SECTIONS)
    name = check_run_name(run.text("name", "tank-run"))
    output_dir = resolve_runs_dir(run.text("output_dir", "runs"))
    max_duration = run.number("max_duration_s", 120.0, lo=0.0, lo_open=True, unit="s")
    board_url, stage_url = dev.text("board"), dev.text("stage")
    board_url = check_device_url(board_url, "daq", "devices.board")
    stage_url = check_device_url(stage_url, "stage", "devices.stage")
    board_channel = dev.integer("board_channel", 0, lo=0, hi=15)

    preset_name = wav.text("preset", "tank-board")
    family = wav.text("family", "random-cyclic")
    amplitude = wav.number("amplitude", 0.5, lo=0.0, hi=1.0, lo_open=True, unit="(full scale)")
    overrides = wav.data.get("overrides", {})
    if not isinstance(overrides, dict):
        raise ConfigError("waveform.overrides", overrides, "a table of waveform fields")

    size = tank.point("size_m", (12.0, 4.0, 2.5))
    if min(size) <= 0:
        raise ConfigError("tank.size_m", list(size), "three lengths > 0 m")
    temp = tank.number("water_temperature_c", 20.0, lo=0.0, hi=95.0, unit="°C")
    salinity = tank.number("salinity_ppt", 0.0, lo=0.0, hi=42.0, unit="ppt")
    if "sound_speed_mps" in tank.data:
        c = tank.number("sound_speed_mps", lo=1300.0, hi=1700.0, unit="m/s")
    else:
        c = _sound_speed_from_water(temp, salinity)
    xdcr = tank.point("transducer_position_m", (0.5, size[1] / 2, -size[2] / 2))
    origin = tank.point("stage_origin_m", (size[0] - 1.0, size[1] / 2, -size[2] / 2))
    axis_raw = np.asarray(tank.point("stage_axis", (1.0, 0.0, 0.0)))
    norm = float(np.sqrt(axis_raw @ axis_raw))
    if norm == 0:
        raise ConfigError("tank.stage_axis", axis_raw.tolist(), "a non-zero direction")
    axis = axis_raw / norm
    for key, p in (("transducer_position_m", xdcr), ("stage_origin_m", origin)):
        _inside_tank(f"tank.{key}", p, size)

    plan = TowPlan(
        start_m=tow.number("start_m", unit="m"),
        end_m=tow.number("end_m", unit="m"),
        speed_mps=tow.number("speed_mps", lo=0.0, lo_open=True, hi=5.0, unit="m/s"),
        repeats=tow.integer("repeats", 1, lo=1, hi=1000),
        run_up_m=tow.number("run_up_m", 0.5, lo=0.0, unit="m"),
        run_down_m=tow.number("run_down_m", 0.5, lo=0.0, unit="m"),
    )
    if plan.start_m == plan.end_m:
        raise ConfigError("tow.end_m", plan.end_m, f"!= tow.start_m = {plan.start_m} m")
    d = 1.0 if plan.end_m > plan.start_m else -1.0
    for key, x in (
        ("tow.start_m - tow.run_up_m", plan.start_m - d * plan.run_up_m),
        ("tow.end_m + tow.run_down_m", plan.end_m + d * plan.run_down_m),
    ):
        if x > 0:
            raise ConfigError(key, x, "<= 0 m (GRBL machine positions are in [-travel, 0])")
        towed = np.asarray(origin) + x * axis
        _inside_tank(f"target at stage x = {x:g} m ({key})", tuple(towed.tolist()), size)

    receiver = rec.text("name", "gcas")
    m_hops = rec.integer("m_hops", 10, lo=1, hi=64)
    v_max = rec.number("max_speed_mps", 3.0, lo=0.0, lo_open=True, unit="m/s")
    if v_max < plan.speed_mps:
        raise ConfigError(
            "receiver.max_speed_mps",
            v_max,
            f">= tow.speed_mps = {plan.speed_mps} m/s",
            "the Doppler search must cover the tow speed",
        )
    diag = float(np.sqrt(sum(s * s for s in size)))
    r_max = rec.number("max_range_m", diag, lo=0.0, lo_open=True, unit="m")
    options = rec.data.get("options", {})
    if not isinstance(options, dict):
        raise ConfigError("receiver.options", options, "a table of receiver options")
    from hil.estimation.option_types import check_option_types
    from hil.estimation.registry import receiver_class

    check_option_types(receiver_class(receiver), options, receiver, "receiver.options.")
    _check_tracker_options(options)

    # The waveform: preset, family, overrides, with the tank's sound speed and tow limits.
    preset = get_preset(preset_name)
    try:
        spec = preset.spec(family, sound_speed_mps=c, **overrides)
    except ConfigError as exc:
        raise ConfigError(f"waveform.{exc.field}", exc.value, exc.allowed, exc.hint) from None
    spec = spec.with_overrides(max_range_m=min(spec.max_range_m, r_max))
    try:
        schedule = check_design(spec)
    except ConfigError as exc:
        raise ConfigError(f"waveform.{exc.field}", exc.value, exc.allowed, exc.hint) from None
    r_unamb = schedule.unambiguous_range_m(c)
    if r_max > r_unamb:
        raise ConfigError(
            "receiver.max_range_m", r_max, f"<= the waveform's unambiguous range {r_unamb:.2f} m"
        )

    store = resolve_calibration_dir(cal.text("store", "calibration"))
    max_age = cal.number("max_age_days", 30.0, lo=0.0, lo_open=True, unit="days")
    required = cal.data.get("required", [])
    if not isinstance(required, list) or not all(isinstance(r, str) for r in required):
        raise ConfigError("calibration.required", required, "a list of calibration kinds")

    simulation = SimulationSettings(
        source_level_db=sim.number(
            "source_level_db", 185.0, lo=100.0, hi=250.0, unit="dB re 1 µPa @ 1 m"
        ),
        target_strength_db=sim.number(
            "target_strength_db", -12.0, lo=-80.0, hi=40.0, unit="dB re 1 m²"
        ),
        sensitivity_db=sim.number(
            "sensitivity_db", -200.0, lo=-260.0, hi=-100.0, unit="dB re 1 V/µPa"
        ),
        gain_db=sim.number("gain_db", 30.0, lo=-20.0, hi=80.0, unit="dB"),
        image_order=sim.integer("image_order", 1, lo=0, hi=MAX_TARGET_IMAGE_ORDER),
        tank_echoes=sim.flag("tank_echoes", False),
        tank_echo_order=sim.integer("tank_echo_order", 3, lo=0, hi=MAX_TANK_ECHO_ORDER),
        late_tail=sim.flag("late_tail", True),
        wall_reflection=sim.number("wall_reflection", 0.9, lo=-1.0, hi=1.0),
        bottom_reflection=sim.number("bottom_reflection", 0.9, lo=-1.0, hi=1.0),
        transducer_beam=sim.text("transducer_beam", "piston", BEAM_KINDS),
        transducer_radius_m=sim.number(
            "transducer_radius_m", 0.015, lo=0.0, lo_open=True, hi=1.0, unit="m"
        ),
        hydrophone_beam=sim.text("hydrophone_beam", "omni", BEAM_KINDS),
        hydrophone_radius_m=sim.number(
            "hydrophone_radius_m", 0.015, lo=0.0, lo_open=True, hi=1.0, unit="m"
        ),
        noise_level_db=sim.number(
            "noise_level_db", 40.0, lo=-20.0, hi=120.0, unit="dB re 1 µPa²/Hz"
        ),
        reverberation=sim.flag("reverberation", True),
        scattering_strength_db=sim.number(
            "scattering_strength_db", -70.0, lo=-120.0, hi=-10.0, unit="dB"
        ),
        time_scale=sim.number("time_scale", 0.5, lo=0.01, hi=1.0, unit="(simulated s per wall s)"),
        seed=sim.integer("seed", 1, lo=0),
    )
    return Experiment(
        name=name,
        output_dir=output_dir,
        max_duration_s=max_duration,
        board_url=board_url,
        stage_url=stage_url,
        board_channel=board_channel,
        waveform=spec,
        schedule=schedule,
        preset=preset_name,
        amplitude=amplitude,
        tank_size_m=size,
        water_temperature_c=temp,
        salinity_ppt=salinity,
        sound_speed_mps=c,
        transducer_m=xdcr,
        stage_origin_m=origin,
        stage_axis=(float(axis[0]), float(axis[1]), float(axis[2])),
        tow=plan,
        receiver=receiver,
        m_hops=m_hops,
        max_speed_mps=v_max,
        max_range_m=r_max,
        receiver_options=tank_receiver_options(
            receiver, dict(options), schedule, spec.fs_hz, c, plan
        ),
        calibration_store=store,
        calibration_max_age_days=max_age,
        calibration_required=tuple(required),
        simulation=simulation,
        text=text,
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


def _inside_tank(name: str, p: tuple[float, ...], size: tuple[float, float, float]) -> None:
    lx, ly, lz = size
    inside = 0 < p[0] < lx and 0 < p[1] < ly and -lz < p[2] < 0
    if not inside:
        raise ConfigError(
            name,
            [round(c, 4) for c in p],
            f"inside the tank: 0 < x < {lx}, 0 < y < {ly}, -{lz} < z < 0 m",
            "move it, or change tank.size_m / the tow plan",
        )


def _sound_speed_from_water(temperature_c: float, salinity_ppt: float) -> float:
    """c from the logged water: fresh water (Marczak 1997) or UNESCO for salt water."""
    # Lazy import: the formulas live with the acoustics (DESIGN: hil imports sim_devices lazily).
    from sim_devices.acoustics.sound_speed import tank_sound_speed, unesco_sound_speed

    if salinity_ppt == 0.0:
        return float(tank_sound_speed(temperature_c))
    return float(unesco_sound_speed(salinity_ppt, temperature_c, 0.0))


def tank_receiver_options(
    receiver: str,
    options: dict[str, Any],
    schedule: HopSchedule,
    fs_hz: float,
    c: float,
    plan: TowPlan,
) -> dict[str, Any]:
    """The receiver options of a tank run: ``options`` as given, with two GCAS settings
    derived from the tank when the file does not set them.

    ``range_readout``: ``"first-arrival"`` (:mod:`hil.estimation.first_arrival`): in a tank
    the surface, bottom and wall images follow the direct echo by a few tenths of a
    millisecond and pull the peak of the accumulated sums to their centroid (+0.45 m in the
    built-in tank); the peak readout only where the code period is not a whole number of
    samples (the first-arrival readout's clutter canceller needs one). With the peak readout
    ``refine`` is False unless the file sets it: the refinement fits one echo
    (:mod:`hil.estimation.refine`), and through the tank's images its fit is not one echo, so
    it would refuse the target's detections; the peak then reads the images' centroid.

    ``reverb_speed_mps``, the reverberation band (m/s):

    A tow starts and ends at rest, so the target passes through every speed below the tow
    speed. The band hides targets slower than the waveform's Doppler resolution
    ``v_res = c/(2 f_lo T_h)`` (:mod:`hil.estimation.reverb_band`): it stays on
    (``"auto"``) only when the tow speed clears the band's edge by a resolution cell
    (``>= 2 v_res``), and is off (0) otherwise, where it would remove the tow itself
    (tank-audio: ``v_res`` = 1.30 m/s, so tows below 2.6 m/s run without it).
    """
    if receiver not in ("gcas", "gcas-mti"):
        return options
    out = dict(options)
    if "reverb_speed_mps" in out:
        try:
            # Checked here, so a bad value is refused before the run starts anything.
            resolve_reverb_speed(
                out["reverb_speed_mps"], schedule.tones_hz, schedule.hop_s, c, math.inf
            )
        except ConfigError as exc:
            raise ConfigError(
                "receiver.options.reverb_speed_mps", exc.value, exc.allowed, exc.hint
            ) from None
    if out.get("range_readout", "peak") not in RANGE_READOUTS:
        raise ConfigError(
            "receiver.options.range_readout",
            out["range_readout"],
            f"one of {', '.join(RANGE_READOUTS)}",
            "first-arrival times the direct path in a tank; peak is the accumulated sums' peak",
        )
    if "reverb_speed_mps" not in out:
        v_res = doppler_resolution_mps(schedule.tones_hz, schedule.hop_s, c)
        out["reverb_speed_mps"] = AUTO if plan.speed_mps >= 2.0 * v_res else 0.0
    if "range_readout" not in out:
        whole = schedule.period_samples(fs_hz) is not None
        out["range_readout"] = "first-arrival" if whole else "peak"
    if out["range_readout"] == "peak" and "refine" not in out:
        out["refine"] = False
    return out


def _check_tracker_options(options: dict[str, Any]) -> None:
    """Refuse a bad ``track_*`` receiver option (docs/tracks.md) when the file is read,
    named as the file names it."""
    from hil.estimation.tracking import TrackerSettings

    try:
        TrackerSettings.from_options(options)
    except ConfigError as exc:
        raise ConfigError(
            f"receiver.options.{exc.field}", exc.value, exc.allowed, exc.hint
        ) from None
