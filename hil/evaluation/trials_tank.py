"""The tank trial: one simulated tank run on virtual time, scored as ``hil tank-run`` scores it.

:func:`tank_run_trial` (``"tank_run"``) builds an experiment (the built-in one, or a lab's own
file named by ``experiment``) with the trial's parameters put in, runs it with
:func:`hil.experiments.api.run` on virtual time (``virtual_time=True``: the simulated stage,
board and acoustic tank in the worker's own thread, deterministic for a seed) in a scratch
folder, and returns the run's scores (:func:`hil.experiments.run_scoring.summarize`) and the
range and speed error of every scored estimate. The run's folder (recording, summary) is
deleted afterwards: the sweep keeps what the record holds. After the sweep,
:func:`~hil.evaluation.report_tank.write_tank_report` writes its report (rates and error
distributions per grid point, figures).

Parameters (each left out keeps the experiment file's value):

- ``experiment``: ``"built-in"`` (``hil tank-run --print-default``) or the path of an
  experiment file (absolute, or relative to the folder the sweep runs in; workers on other
  machines need the same path). Its devices are replaced by the simulated ones
  (``sim://board``, ``sim://stage``) and ``calibration.required`` is emptied: the trial
  predicts what that tank shows, with the file's waveform, receiver and geometry;
- ``tank_size_m``: ``[L, W, D]``, m. The transducer and the tow line keep their distance from
  the near and the far end wall and their depth, and move to mid-width;
- ``tow_speed_mps``: ``tow.speed_mps``, m/s;
- ``direction``: ``"closing"`` (the first pass towards the transducer) or ``"opening"``: the
  tow's start and end are swapped when the file's tow goes the other way;
- ``tow_repeats``: ``tow.repeats`` (passes, alternating direction);
- ``noise_level_db``: ``simulation.noise_level_db``, dB re 1 µPa²/Hz;
- ``image_order``: ``simulation.image_order`` (reflections per round trip of the target's
  echoes, 0–4);
- ``receiver``, ``m_hops``: ``receiver.name`` and ``receiver.m_hops``.

``simulation.seed`` is drawn from the trial's seed sequence, so every repetition of a grid
point is a different realisation of the noise and reverberation, and the same sweep seed gives
the same runs. ``run.max_duration_s`` is raised to twice the tow's least duration plus 30 s
when the file's is shorter (a sweep over repeats and slow tows would otherwise be refused).

Every parameter is checked with the experiment's own validation
(:func:`hil.experiments.experiment.parse_experiment`) before any trial runs; an error names the
trial parameter it comes from.
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from hil.errors import ConfigError, ConfigErrors
from hil.evaluation.registry import Params
from hil.evaluation.report_tank import write_tank_report
from hil.experiments.experiment import DEFAULT_EXPERIMENT, Experiment, parse_experiment
from hil.toml_table import parse_toml, read_text_file

#: Parameters of :func:`tank_run_trial`; None keeps the experiment file's value.
TANK_DEFAULTS: dict[str, Any] = {
    "experiment": "built-in",
    "tank_size_m": None,
    "tow_speed_mps": None,
    "direction": None,
    "tow_repeats": None,
    "noise_level_db": None,
    "image_order": None,
    "receiver": None,
    "m_hops": None,
}
DIRECTIONS = ("closing", "opening")

#: Experiment fields set from a trial parameter: an error on one names the parameter.
_FIELD_PARAM = {
    "tank.size_m": "tank_size_m",
    "tow.speed_mps": "tow_speed_mps",
    "tow.repeats": "tow_repeats",
    "simulation.noise_level_db": "noise_level_db",
    "simulation.image_order": "image_order",
    "receiver.name": "receiver",
    "receiver.m_hops": "m_hops",
}
#: Parameters that move the target or the tow: an experiment error about where the target
#: goes (a position outside the tank, a tow beyond the stage) is put down to the first given.
_GEOMETRY_PARAMS = ("tank_size_m", "direction", "tow_repeats")
_GEOMETRY_FIELDS = ("target", "tank.", "tow.", "run.max_duration_s")

#: Decimals kept of each scored estimate's error: 1 µm, 10 µm/s (far below any RMSE here).
_RANGE_DECIMALS = 6
_SPEED_DECIMALS = 5


def _known(params: Params) -> dict[str, Any]:
    for key, value in params.items():
        if key not in TANK_DEFAULTS:
            raise ConfigError(key, value, f"a parameter of tank_run: {', '.join(TANK_DEFAULTS)}")
    return {**TANK_DEFAULTS, **params}


def _base_document(experiment: Any) -> tuple[dict[str, Any], str]:
    """The experiment file's tables and where they came from."""
    if experiment == "built-in":
        return parse_toml(DEFAULT_EXPERIMENT, "experiment", "built-in"), "built-in"
    if not isinstance(experiment, str) or not experiment.strip():
        raise ConfigError("experiment", experiment, '"built-in" or the path of an experiment file')
    path = Path(experiment).expanduser()
    try:
        text = read_text_file(path, "experiment")
    except FileNotFoundError:
        raise ConfigError(
            "experiment", experiment, "an existing experiment file, or \"built-in\"",
            f"{path.resolve()} not found (a relative path is taken from the folder the sweep "
            "runs in)",
        ) from None  # fmt: skip
    return parse_toml(text, "experiment", str(path)), str(path)


def experiment_text(params: Params, sim_seed: int) -> tuple[str, str]:
    """The experiment TOML of one trial (module docstring) and the file it started from.

    >>> text, source = experiment_text({"tow_speed_mps": 1.0, "direction": "opening"}, 7)
    >>> doc = parse_toml(text, "experiment")
    >>> tow = doc["tow"]
    >>> tow["speed_mps"], tow["start_m"], tow["end_m"], doc["simulation"]["seed"]
    (1.0, -5.0, -2.0, 7)
    """
    p = _known(params)
    doc, source = _base_document(p["experiment"])
    tables = {name: dict(doc.get(name, {})) for name in doc}
    devices = tables.setdefault("devices", {})
    devices["board"], devices["stage"] = "sim://board", "sim://stage"
    tables.setdefault("calibration", {})["required"] = []
    sim = tables.setdefault("simulation", {})
    sim["seed"] = int(sim_seed)
    tank, tow = tables.setdefault("tank", {}), tables.setdefault("tow", {})
    if p["tank_size_m"] is not None:
        _resize(tank, p["tank_size_m"])
    if p["tow_speed_mps"] is not None:
        tow["speed_mps"] = p["tow_speed_mps"]
    if p["tow_repeats"] is not None:
        tow["repeats"] = p["tow_repeats"]
    if p["direction"] is not None:
        _orient(tank, tow, p["direction"])
    for key, section, name in (
        ("noise_level_db", "simulation", "noise_level_db"),
        ("image_order", "simulation", "image_order"),
        ("receiver", "receiver", "name"),
        ("m_hops", "receiver", "m_hops"),
    ):
        if p[key] is not None:
            tables.setdefault(section, {})[name] = p[key]
    _room_for_the_tow(tables.setdefault("run", {}), tow)
    return dumps_tables(tables), source


def _resize(tank: dict[str, Any], size: Any) -> None:
    ok = (
        isinstance(size, list)
        and len(size) == 3
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in size)
        and all(math.isfinite(v) and v > 0 for v in size)
    )
    if not ok:
        raise ConfigError("tank_size_m", size, "[L, W, D]: three lengths > 0, m")
    old = tank.get("size_m", [12.0, 4.0, 2.5])
    length, width = float(size[0]), float(size[1])
    for key, from_far_end in (("transducer_position_m", False), ("stage_origin_m", True)):
        if key in tank:
            x, _, z = tank[key]
            # Distance from the near (x = 0) or the far (x = L) end wall kept.
            new_x = length - (float(old[0]) - x) if from_far_end else x
            tank[key] = [new_x, width / 2.0, z]
    tank["size_m"] = [float(v) for v in size]


def _orient(tank: dict[str, Any], tow: dict[str, Any], direction: Any) -> None:
    if direction not in DIRECTIONS:
        raise ConfigError("direction", direction, f"one of {', '.join(DIRECTIONS)}")
    origin = np.asarray(tank.get("stage_origin_m", [11.0, 2.0, -1.2]), dtype=float)
    axis = np.asarray(tank.get("stage_axis", [1.0, 0.0, 0.0]), dtype=float)
    at = np.asarray(tank.get("transducer_position_m", [0.5, 2.0, -1.2]), dtype=float)
    start, end = float(tow.get("start_m", -2.0)), float(tow.get("end_m", -5.0))
    r_start = float(np.linalg.norm(origin + start * axis - at))
    r_end = float(np.linalg.norm(origin + end * axis - at))
    closing = r_end < r_start
    if closing != (direction == "closing"):
        tow["start_m"], tow["end_m"] = end, start


def _room_for_the_tow(run: dict[str, Any], tow: dict[str, Any]) -> None:
    """Raise ``run.max_duration_s`` to twice the tow's least duration plus 30 s if shorter."""
    try:
        path = abs(float(tow["end_m"]) - float(tow["start_m"]))
        path += float(tow.get("run_up_m", 0.0)) + float(tow.get("run_down_m", 0.0))
        least = int(tow.get("repeats", 1)) * path / float(tow["speed_mps"])
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return  # the experiment's own validation names the bad tow value
    if not math.isfinite(least) or least <= 0:
        return
    needed = 2.0 * least + 30.0
    if float(run.get("max_duration_s", 120.0)) < needed:
        run["max_duration_s"] = round(needed, 1)


def dumps_tables(tables: dict[str, dict[str, Any]]) -> str:
    """TOML text of one level of tables holding numbers, strings, booleans, arrays of them and
    inline tables (the shape of an experiment file).

    >>> print(dumps_tables({"tow": {"speed_mps": 1.5, "repeats": 2}, "x": {"o": {"a": "b"}}}))
    [tow]
    speed_mps = 1.5
    repeats = 2
    <BLANKLINE>
    [x]
    o = {a = "b"}
    <BLANKLINE>
    """
    lines: list[str] = []
    for name, table in tables.items():
        lines.append(f"[{name}]")
        lines += [f"{key} = {_toml_value(value)}" for key, value in table.items()]
        lines.append("")
    return "\n".join(lines)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a valid TOML basic string
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"no TOML form for {type(value).__name__}")


def build_experiment(params: Params, sim_seed: int) -> Experiment:
    """The validated experiment of one trial; a :class:`ConfigError` names the trial
    parameter an experiment field came from."""
    text, source = experiment_text(params, sim_seed)
    try:
        return parse_experiment(text, f"tank_run trial ({source})")
    except ConfigError as exc:
        raise _as_parameter_error(exc, params, source) from None


def _as_parameter_error(exc: ConfigError, params: Params, source: str) -> ConfigError:
    """The experiment's error ``exc`` named after the trial parameter it comes from."""
    errors = exc.errors if isinstance(exc, ConfigErrors) else (exc,)
    for err in errors:
        param = _FIELD_PARAM.get(err.field)
        if param is not None and params.get(param) is not None:
            hint = f"experiment field {err.field}" + (f"; {err.hint}" if err.hint else "")
            return ConfigError(param, params[param], err.allowed, hint)
        if err.field == "receiver.max_speed_mps" and params.get("tow_speed_mps") is not None:
            return ConfigError(
                "tow_speed_mps", params["tow_speed_mps"],
                f"<= receiver.max_speed_mps = {err.value} m/s of the experiment {source}",
                "the receiver's Doppler search must cover the tow speed",
            )  # fmt: skip
        given = [p for p in _GEOMETRY_PARAMS if params.get(p) is not None]
        if given and err.field.startswith(_GEOMETRY_FIELDS):
            return ConfigError(
                given[0], params[given[0]], f"a tow that fits the tank ({err})",
                f"in the experiment {source} with this point's parameters",
            )  # fmt: skip
    first = errors[0]
    return ConfigError(
        first.field, first.value, first.allowed,
        f"in the experiment {source} with this point's parameters"
        + (f"; {first.hint}" if first.hint else ""),
    )  # fmt: skip


def validate_tank_params(params: Params) -> None:
    """Check one grid point of :func:`tank_run_trial` by building its experiment.

    >>> validate_tank_params({"direction": "sideways"})
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: direction = 'sideways' is not allowed: must be one of closing, opening
    """
    build_experiment(params, 0)


def simulation_seed(seed: np.random.SeedSequence) -> int:
    """The ``simulation.seed`` of a trial: 32 bits drawn from its seed sequence.

    >>> simulation_seed(np.random.SeedSequence(5, spawn_key=(0, 1)))
    2805290992
    """
    return int(seed.generate_state(1, np.uint32)[0])


def tank_run_trial(params: Params, seed: np.random.SeedSequence) -> dict[str, Any]:
    """One tank run on virtual time (module docstring); its scores and error lists.

    Returns the summary's counts and figures (``detection_rate`` = detected / expected hop
    boundaries, ``false_alarm_rate`` = false alarms / scored estimates, RMSEs and biases over
    the scored estimates, m and m/s), ``sim_seed``, ``signal_s`` (s of signal) and
    ``range_errors_m`` / ``speed_errors_mps``: estimate − truth of every scored estimate.
    A run that stops on an error raises (the sweep records it as a failed trial).
    """
    from hil.experiments import api
    from hil.experiments.run_scoring import score_run

    sim_seed = simulation_seed(seed)
    exp = build_experiment(params, sim_seed)
    with tempfile.TemporaryDirectory(prefix="hil-tank-trial-") as tmp:
        outcome, summary = api.run(exp, folder=Path(tmp) / "run", figures=False, virtual_time=True)
        score = score_run(outcome)
    if summary.get("error"):
        raise RuntimeError(f"the tank run stopped: {summary['error']}")
    scored = score.scored
    n_scored = int(scored.sum())
    # The rates and RMSEs first: `hil sweep` shows the first numeric fields in its table.
    result: dict[str, Any] = {
        "detection_rate": summary.get("detection_rate"),
        "false_alarm_rate": summary["false_alarms"] / n_scored if n_scored else None,
    }
    for key in (
        "range_rmse_m", "speed_rmse_mps", "range_bias_m", "speed_bias_mps", "estimates",
        "estimates_with_truth", "wrong_estimates", "scored_estimates", "false_alarms",
        "expected_boundaries", "detected_boundaries", "range_rmse_gated_m", "wrong_gate_m",
        "planned_adc_peak_fs", "adc_clipped_samples", "dropped_samples", "signal_s",
    ):  # fmt: skip
        result[key] = summary.get(key)
    result["sim_seed"] = sim_seed
    result["range_errors_m"] = np.round(score.range_error_m[scored], _RANGE_DECIMALS)
    result["speed_errors_mps"] = np.round(score.speed_error_mps[scored], _SPEED_DECIMALS)
    return result


tank_run_trial.validate_params = validate_tank_params  # type: ignore[attr-defined]
tank_run_trial.write_report = write_tank_report  # type: ignore[attr-defined]
