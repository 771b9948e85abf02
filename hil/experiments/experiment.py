"""The experiment file of a towed-target tank run (TOML), validated before any device is
touched.

Each table is read by its dataclass (:mod:`hil.experiments.experiment_sections`), then what
spans tables is checked here; every problem of the file is reported at once (a
:class:`~hil.errors.ConfigErrors`), each naming the field by its dotted path as written in
the file (``tow.speed_mps``), the value, the allowed range and what to do. The format is
documented in ``docs/tank-run.md``; :data:`DEFAULT_EXPERIMENT` is the built-in simulated run
that ``hil tank-run`` uses without arguments.

Coordinates: the tank frame has x along the tank length, y across, z up with the water
surface at z = 0 (so depths are negative), metres. The stage is GRBL's X axis, whose machine
positions are in ``[-travel, 0]`` (0 at the homing switch): the towed target sits at
``tank.stage_origin_m + x_stage · tank.stage_axis``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hil.config_sections import Problems
from hil.devices.table import is_simulated
from hil.errors import ConfigError
from hil.estimation.first_arrival import RANGE_READOUTS
from hil.estimation.reverb_band import AUTO, doppler_resolution_mps, resolve_reverb_speed
from hil.experiments.experiment_sections import (
    BEAM_KINDS,
    MAX_TANK_ECHO_ORDER,
    MAX_TARGET_IMAGE_ORDER,
    CalibrationSection,
    DevicesSection,
    ExperimentFile,
    ReceiverSection,
    RunSection,
    SimulationSettings,
    TankSection,
    TowPlan,
    WaveformSection,
    check_run_name,
    outside_tank,
)
from hil.paths import resolve_calibration_dir, resolve_runs_dir
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule import HopSchedule
from hil.signals.waveforms import HFCCW_FAMILIES, WaveformSpec, check_family_fields
from hil.toml_table import parse_toml, read_text_file

__all__ = [
    "BEAM_KINDS",
    "DEFAULT_EXPERIMENT",
    "MAX_TANK_ECHO_ORDER",
    "MAX_TARGET_IMAGE_ORDER",
    "Experiment",
    "SimulationSettings",
    "TowPlan",
    "check_run_name",
    "load_experiment",
    "parse_experiment",
    "tank_receiver_options",
]

#: Receivers that need every hop of the code the same length (the GCAS family: its
#: accumulated sums and Doppler resolution are per hop).
EQUAL_HOP_RECEIVERS = ("gcas", "gcas-mti", "gcas-bg")

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
# GCAS on the input less the empty tank: the tank's own echoes and tail do not move, and
# outshine the target. "simulated" captures the built-in tank with the target taken out
# before the run (docs/tank-run.md, "Empty-tank background"). The reverberation band is
# derived from the tow (see docs/tank-run.md).
name = "gcas-bg"
m_hops = 10
max_speed_mps = 3.0
max_range_m = 12.0
options = { background = "simulated" }

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
    """Validate experiment TOML text (see the module docstring); nothing is touched.

    Every table is read by its dataclass (:mod:`hil.experiments.experiment_sections`), then
    the checks across tables run (:func:`_across_tables`); every problem found is reported at
    once, as a :class:`~hil.errors.ConfigErrors` (one line each).
    """
    data = parse_toml(text, "experiment", source)
    problems = Problems()
    tables = ExperimentFile.read_values(data, "", problems)
    exp = None if tables is None else _across_tables(tables, text, problems)
    problems.raise_any()
    assert exp is not None
    return exp


def _across_tables(t: dict[str, Any], text: str, problems: Problems) -> Experiment | None:
    """The checks that span tables, in one place, and the experiment when nothing failed.

    A check that needs a table with a problem of its own is skipped (that problem is already
    reported): the tow inside the tank, the receiver's speed and range against the tow, the
    run's duration against the tow, the waveform at the tank's sound speed and within the
    receiver's range, the receiver's options for that waveform.
    """
    run: RunSection | None = t.get("run")
    dev: DevicesSection | None = t.get("devices")
    wav: WaveformSection | None = t.get("waveform")
    tank: TankSection | None = t.get("tank")
    tow: TowPlan | None = t.get("tow")
    rec: ReceiverSection | None = t.get("receiver")
    cal: CalibrationSection | None = t.get("calibration")
    sim: SimulationSettings | None = t.get("simulation")
    for exc in _tow_fits(run, tank, tow, rec):
        problems.add(exc)
    r_max = None
    if rec is not None and tank is not None:
        # Left out, the range searched is the tank's diagonal.
        r_max = rec.max_range_m or float(np.sqrt(sum(s * s for s in tank.size_m)))
    spec = schedule = None
    if wav is not None and tank is not None and r_max is not None:
        with problems.collect():
            spec, schedule = _waveform(wav, tank.sound_speed, r_max, rec)
    options = None
    derived = spec is not None and schedule is not None
    if rec is not None and tow is not None and tank is not None and derived:
        assert spec is not None and schedule is not None
        with problems.collect():
            options = tank_receiver_options(
                rec.name, dict(rec.options), schedule, spec.fs_hz, tank.sound_speed, tow
            )
    output_dir = store = None
    if run is not None:
        with problems.collect():
            output_dir = resolve_runs_dir(run.output_dir)
    if cal is not None:
        with problems.collect():
            store = resolve_calibration_dir(cal.store)
    if problems or None in (run, dev, wav, tank, tow, rec, cal, sim, output_dir, store):
        return None
    # Narrowed for the type checker: every table read and every value derived.
    assert run is not None and dev is not None and wav is not None and tank is not None
    assert tow is not None and rec is not None and cal is not None and sim is not None
    assert spec is not None and schedule is not None and r_max is not None
    assert output_dir is not None and store is not None and options is not None
    board_url, stage_url = dev.urls
    return Experiment(
        name=run.name,
        output_dir=output_dir,
        max_duration_s=run.max_duration_s,
        board_url=board_url,
        stage_url=stage_url,
        board_channel=dev.board_channel,
        waveform=spec,
        schedule=schedule,
        preset=wav.preset,
        amplitude=wav.amplitude,
        tank_size_m=tank.size_m,
        water_temperature_c=tank.temperature_c,
        salinity_ppt=tank.salinity_ppt,
        sound_speed_mps=tank.sound_speed,
        transducer_m=tank.transducer_m,
        stage_origin_m=tank.origin_m,
        stage_axis=tank.axis,
        tow=tow,
        receiver=rec.name,
        m_hops=rec.m_hops,
        max_speed_mps=rec.max_speed_mps,
        max_range_m=r_max,
        receiver_options=options,
        calibration_store=store,
        calibration_max_age_days=cal.max_age_days,
        calibration_required=tuple(cal.required),
        simulation=sim,
        text=text,
    )


def _tow_fits(
    run: RunSection | None,
    tank: TankSection | None,
    tow: TowPlan | None,
    rec: ReceiverSection | None,
) -> Iterator[ConfigError]:
    """The tow against the other tables: the target inside the tank at both ends (with the
    run-up and run-down), the run's duration, the receiver's speed and range."""
    if tow is None:
        return
    if tank is not None:
        for key, x in _tow_ends(tow):
            towed = np.asarray(tank.origin_m) + x * np.asarray(tank.axis)
            bad = outside_tank(f"target at stage x = {x:g} m ({key})", tuple(towed), tank.size_m)
            if bad is not None:
                yield bad
    # The tolerance: a duration written as the tow's, to its printed digits, is enough.
    if run is not None and run.max_duration_s < tow.shortest_duration_s * (1.0 - 1e-9):
        yield ConfigError(
            "run.max_duration_s", run.max_duration_s,
            f">= {tow.shortest_duration_s:.3g} s, the tow's shortest duration (tow.repeats"
            " x (|end_m - start_m| + run_up_m + run_down_m) / speed_mps)",
            "raise it: the run is stopped as a failure when it runs out",
        )  # fmt: skip
    if rec is None:
        return
    if rec.max_speed_mps < tow.speed_mps:
        yield ConfigError(
            "receiver.max_speed_mps", rec.max_speed_mps,
            f">= tow.speed_mps = {tow.speed_mps} m/s",
            "the Doppler search must cover the tow speed",
        )  # fmt: skip
    if tank is not None:
        r_max = rec.max_range_m or float(np.sqrt(sum(s * s for s in tank.size_m)))
        yield from _range_covers_tow(r_max, rec.max_range_m is not None, tank, tow)


def _tow_ends(tow: TowPlan) -> tuple[tuple[str, float], tuple[str, float]]:
    """Where the carriage is farthest each way (stage m): the run-up's start and the
    run-down's end, named as the file's keys."""
    d = tow.direction
    return (
        ("tow.start_m - tow.run_up_m", tow.start_m - d * tow.run_up_m),
        ("tow.end_m + tow.run_down_m", tow.end_m + d * tow.run_down_m),
    )


def _range_covers_tow(
    r_max: float, given: bool, tank: TankSection, tow: TowPlan
) -> list[ConfigError]:
    """``receiver.max_range_m`` against the target's farthest range during the passes (at
    ``tow.start_m`` or ``tow.end_m``: the range along a straight pass is largest at an end):
    a shorter search range finds no target there, so the run is refused before it moves."""
    xdcr, origin, axis = (np.asarray(v) for v in (tank.transducer_m, tank.origin_m, tank.axis))
    far_r, far_key, x = max(
        (float(np.linalg.norm(origin + x * axis - xdcr)), key, x)
        for key, x in (("tow.start_m", tow.start_m), ("tow.end_m", tow.end_m))
    )
    if r_max >= far_r:
        return []
    name = "receiver.max_range_m" if given else "receiver.max_range_m (the tank's diagonal)"
    return [
        ConfigError(
            name,
            round(r_max, 4),
            f">= {far_r:.3f} m, the target's range at {far_key} = {x:g} m (the tow's farthest)",
            "raise it (or leave it out: the tank's diagonal), or shorten the tow: beyond it"
            " the receiver finds no target",
        )
    ]


def _waveform(
    wav: WaveformSection, c: float, r_max: float, rec: ReceiverSection | None
) -> tuple[WaveformSpec, HopSchedule]:
    """The waveform of ``[waveform]`` at the tank's sound speed ``c`` (m/s), searched to
    ``r_max`` (m), checked for the receiver; errors named under ``waveform.``."""
    preset = get_preset(wav.preset)
    try:
        check_family_fields(wav.family, wav.overrides)
        spec = preset.spec(wav.family, sound_speed_mps=c, **wav.overrides)
        spec = spec.with_overrides(max_range_m=min(spec.max_range_m, r_max))
        schedule = check_design(spec)
    except ConfigError as exc:
        raise ConfigError(f"waveform.{exc.field}", exc.value, exc.allowed, exc.hint) from None
    hops = np.unique(np.round(schedule.duration_s, 12))
    if rec is not None and rec.name in EQUAL_HOP_RECEIVERS and hops.size > 1:
        raise ConfigError(
            "waveform.family", wav.family,
            f"a family of equal hops for receiver.name = {rec.name!r}",
            f"{wav.family} has hops of {', '.join(f'{h * 1e3:g}' for h in hops)} ms (a pulse"
            f" then silence); use a continuous family ({', '.join(HFCCW_FAMILIES)}), or a"
            " receiver for pulses (stft)",
        )  # fmt: skip
    r_unamb = schedule.unambiguous_range_m(c)
    if r_max > r_unamb:
        name = "receiver.max_range_m"
        if rec is None or rec.max_range_m is None:
            name += " (the tank's diagonal)"
        raise ConfigError(name, r_max, f"<= the waveform's unambiguous range {r_unamb:.2f} m")
    return spec, schedule


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
    if receiver not in EQUAL_HOP_RECEIVERS:
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
