"""Sweep files (TOML) and their validation, done in full before any trial runs.

Layout (docs/sweeps.md)::

    [sweep]
    name = "psl-vs-length"            # required, text
    trial = "waveform_af_sidelobe"     # required: name, module:function or file.py:function
    trials_per_point = 20              # integer >= 1 (default 1)
    seed = 20240601                    # required: root entropy, integer >= 0
    description = "..."                # optional

    [grid]                             # swept: every combination is one grid point
    code_length = [17, 31]
    window = [3, 4]

    [fixed]                            # the same for every point
    n_tones = 4

    [quick]                            # optional: what --quick runs instead
    trials_per_point = 1               # integer >= 1
    [quick.grid]                       # replaces these parameters' values in [grid]
    code_length = [17]

Every error is a :class:`~hil.errors.ConfigError` naming the field by its dotted path
(``grid.window``, ``sweep.trials_per_point``) and what is allowed.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

from hil.data import sweeps_dir
from hil.errors import ConfigError
from hil.evaluation.registry import load_trial, resolve_trial, trial_validator
from hil.evaluation.seeds import check_entropy
from hil.evaluation.spec import SweepSpec
from hil.toml_table import read_toml

_SECTIONS = ("sweep", "grid", "fixed", "quick")
_QUICK_KEYS = ("trials_per_point", "grid")
_SWEEP_KEYS = ("name", "trial", "trials_per_point", "seed", "description")
_PARAM_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_VALUE_KINDS = "numbers, strings, booleans, or arrays/tables of them (no dates, no NaN)"


def shipped_sweeps() -> dict[str, Path]:
    """The sweep files shipped with the package (``hil/data/sweeps/``): name -> path.

    >>> "tank-mc" in shipped_sweeps()
    True
    """
    return {p.stem: p for p in sorted(sweeps_dir().glob("*.toml"))}


def find_sweep_file(name: str | Path) -> Path:
    """``name`` itself when it is a file, else the shipped sweep file of that name.

    >>> find_sweep_file("tank-mc").name
    'tank-mc.toml'
    """
    path = Path(name)
    if path.is_file():
        return path
    shipped = shipped_sweeps()
    if str(name) in shipped:
        return shipped[str(name)]
    raise ConfigError(
        "SWEEP",
        str(name),
        f"a sweep file, or a shipped sweep: one of {', '.join(shipped)}",
        f"{path.resolve()} is not a file",
    )


def load_sweep_file(path: str | Path, *, quick: bool = False) -> SweepSpec:
    """Read and validate the sweep file ``path`` (a file, or a shipped sweep's name:
    :func:`find_sweep_file`; relative trial files are found next to it). ``quick`` applies
    its ``[quick]`` table."""
    path = find_sweep_file(path)
    doc = read_toml(path, "sweep")
    if quick:
        doc = quick_document(doc)
    return sweep_from_dict(doc, base_dir=path.resolve().parent)


def quick_document(doc: dict[str, Any]) -> dict[str, Any]:
    """``doc`` with its ``[quick]`` table applied: its ``trials_per_point`` and its grid values
    in place of the full ones (the table itself removed).

    >>> quick_document({"sweep": {"trials_per_point": 5}, "grid": {"a": [1, 2], "b": [3]},
    ...                 "quick": {"trials_per_point": 1, "grid": {"a": [2]}}})
    {'sweep': {'trials_per_point': 1}, 'grid': {'a': [2], 'b': [3]}}
    """
    quick = doc.get("quick")
    if not isinstance(quick, dict):
        raise ConfigError(
            "--quick", True, "a sweep file with a [quick] table",
            "add [quick] (trials_per_point, [quick.grid]) to the file, or leave --quick out",
        )  # fmt: skip
    _check_quick(quick, doc.get("grid", {}))
    out = {key: value for key, value in doc.items() if key != "quick"}
    head = dict(out.get("sweep", {}))
    if "trials_per_point" in quick:
        head["trials_per_point"] = quick["trials_per_point"]
    out["sweep"] = head
    out["grid"] = {**out.get("grid", {}), **quick.get("grid", {})}
    return out


def _check_quick(quick: dict[str, Any], grid: Any) -> None:
    _check_keys(quick, _QUICK_KEYS, "quick.")
    reps = quick.get("trials_per_point", 1)
    if isinstance(reps, bool) or not isinstance(reps, int) or reps < 1:
        raise ConfigError("quick.trials_per_point", reps, "an integer >= 1")
    table = quick.get("grid", {})
    if not isinstance(table, dict):
        raise ConfigError("quick.grid", table, "a table: write [quick.grid]")
    for key, values in table.items():
        if not isinstance(grid, dict) or key not in grid:
            raise ConfigError(
                f"quick.grid.{key}", values, "a parameter swept in [grid]",
                "quick mode replaces values of the grid; it adds no parameter",
            )  # fmt: skip


def sweep_from_dict(doc: dict[str, Any], base_dir: Path | None = None) -> SweepSpec:
    """Validate a parsed sweep document and build the :class:`SweepSpec`.

    Checks unknown sections and keys, types and ranges, that the trial exists and can be
    imported here, and the trial's own parameter check (if it has one) on every grid point.

    >>> s = sweep_from_dict({"sweep": {"name": "d", "trial": "waveform_af_sidelobe", "seed": 3},
    ...                      "grid": {"code_length": [17, 19]}})
    >>> s.n_trials, s.point_params(1)
    (2, {'code_length': 19})
    >>> try:
    ...     sweep_from_dict({"sweep": {"name": "d", "trial": "waveform_af_sidelobe", "seed": 3},
    ...                      "grid": {"code_length": 17}})
    ... except ConfigError as exc:
    ...     print(exc.field, "|", exc.allowed)
    grid.code_length | a non-empty array of values
    """
    _check_keys(doc, _SECTIONS, "")
    for section in _SECTIONS:
        if section in doc and not isinstance(doc[section], dict):
            raise ConfigError(section, doc[section], f"a table: write [{section}]")
    if "sweep" not in doc:
        raise ConfigError("sweep", None, "a [sweep] table with name, trial and seed")
    head = doc["sweep"]
    _check_keys(head, _SWEEP_KEYS, "sweep.")
    for key in ("name", "trial", "seed"):
        if key not in head:
            raise ConfigError(f"sweep.{key}", None, "given (it is required)")
    name = _text(head["name"], "sweep.name")
    trial_name = _text(head["trial"], "sweep.trial")
    description = _text(head["description"], "sweep.description") if "description" in head else ""
    reps = head.get("trials_per_point", 1)
    if isinstance(reps, bool) or not isinstance(reps, int) or reps < 1:
        raise ConfigError("sweep.trials_per_point", reps, "an integer >= 1")
    seed = check_entropy(head["seed"], "sweep.seed")

    grid = _grid(doc.get("grid", {}))
    fixed = _fixed(doc.get("fixed", {}), grid)
    if "quick" in doc:
        _check_quick(doc["quick"], grid)

    target = resolve_trial(trial_name, base_dir, "sweep.trial")
    trial = load_trial(target, "sweep.trial")
    spec = SweepSpec(
        name=name,
        trial=trial_name,
        target=target,
        trials_per_point=reps,
        seed=seed,
        grid=grid,
        fixed=fixed,
        description=description,
    )
    validate = trial_validator(trial)
    if validate is not None:
        for point in range(spec.n_points):
            _validate_point(validate, spec, point)
    return spec


def _check_keys(table: dict[str, Any], allowed: tuple[str, ...], prefix: str) -> None:
    for key in table:
        if key not in allowed:
            where = f"[{prefix.rstrip('.')}]" if prefix else "the top level"
            raise ConfigError(
                f"{prefix}{key}",
                table[key],
                f"a known key of {where}: one of {', '.join(allowed)}",
                "check the spelling",
            )


def _text(value: Any, field: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(field, value, "a non-empty string")
    return value


def _param_name(key: str, field: str) -> None:
    if not _PARAM_NAME.match(key):
        raise ConfigError(field, key, "a parameter name: letters, digits and _, not first digit")


def _check_value(value: Any, field: str) -> None:
    """Refuse values that JSON cannot carry faithfully (dates, NaN)."""
    if isinstance(value, (bool, int, str)):
        return
    if isinstance(value, float):
        if math.isnan(value):
            raise ConfigError(field, value, _VALUE_KINDS)
        return
    if isinstance(value, list):
        for i, item in enumerate(value):
            _check_value(item, f"{field}[{i}]")
        return
    if isinstance(value, dict):
        for key, item in value.items():
            _check_value(item, f"{field}.{key}")
        return
    raise ConfigError(field, value, _VALUE_KINDS)


def _grid(table: dict[str, Any]) -> dict[str, list[Any]]:
    grid: dict[str, list[Any]] = {}
    for key, values in table.items():
        field = f"grid.{key}"
        _param_name(key, field)
        if not isinstance(values, list) or not values:
            hint = (
                f"write {key} = [{_toml_literal(values)}] to sweep over one value"
                if not isinstance(values, list)
                else "give at least one value, or move the parameter to [fixed]"
            )
            raise ConfigError(field, values, "a non-empty array of values", hint)
        seen: set[str] = set()
        for i, value in enumerate(values):
            _check_value(value, f"{field}[{i}]")
            # Compared as JSON text: 1, 1.0 and true are different values of a parameter.
            text = json.dumps(value, sort_keys=True)
            if text in seen:
                raise ConfigError(
                    f"{field}[{i}]", value, "a value not listed before", "remove the duplicate"
                )
            seen.add(text)
        grid[key] = values
    return grid


def _toml_literal(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)


def _fixed(table: dict[str, Any], grid: dict[str, list[Any]]) -> dict[str, Any]:
    for key, value in table.items():
        field = f"fixed.{key}"
        _param_name(key, field)
        if key in grid:
            raise ConfigError(
                field, value, "a parameter not also swept in [grid]", "keep it in one table"
            )
        _check_value(value, field)
    return dict(table)


def _table_path(tables: dict[str, Any], name: str) -> str | None:
    """The dotted path of the key ``name`` inside one of the tables the sweep gave (a
    receiver's options); None if none holds it."""
    for key, table in tables.items():
        if not isinstance(table, dict):
            continue
        if name in table:
            return f"{key}.{name}"
        inner = _table_path(table, name)
        if inner is not None:
            return f"{key}.{inner}"
    return None


def _where(spec: SweepSpec, point: int, field: str) -> str | None:
    """Where the sweep file gave what the trial refused as ``field`` (its last dotted part:
    ``receiver.options.refine`` is ``refine``): the dotted path in the file (``grid.m_hops``,
    ``fixed.receiver_options.refine``); None for a trial default."""
    name = field.rsplit(".", 1)[-1]
    for section, table in (("grid", spec.point_values(point)), ("fixed", spec.fixed)):
        if name in table:
            return f"{section}.{name}"
    for section, table in (("grid", spec.point_values(point)), ("fixed", spec.fixed)):
        inner = _table_path(table, name)
        if inner is not None:
            return f"{section}.{inner}"
    return None


def _validate_point(validate: Any, spec: SweepSpec, point: int) -> None:
    try:
        validate(spec.point_params(point))
    except ConfigError as exc:
        at = f"at grid point {spec.point_values(point)}"
        given = _where(spec, point, exc.field)
        if given is not None and given.startswith("grid."):
            where, notes = given, [at]
        elif given is not None:
            where, notes = given, []
        elif not _PARAM_NAME.match(exc.field):  # a field of a file the trial reads
            where, notes = exc.field, [at]
        else:  # a value the trial defaults, unsuitable with the sweep's other values
            where = f"{exc.field} (the trial's default)"
            notes = [at, f"set {exc.field} in [fixed] or [grid]"]
        hint = "; ".join([*notes, exc.hint] if exc.hint else notes)
        raise ConfigError(where, exc.value, exc.allowed, hint) from None
