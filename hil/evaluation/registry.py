"""Trials by name, found lazily by ``"module:function"`` target so worker processes can load them.

A trial is a pure function ``trial(params: dict, seed: numpy.random.SeedSequence) -> dict``
whose values are ``float``, ``int``, ``bool``, ``str``, ``None`` or lists of those; it touches
no hardware and draws every random number from ``seed``. A sweep names its trial in one of three
ways, all resolved by :func:`resolve_trial` to a *target* string that a fresh worker process can
import without the parent's state:

- a registered name: ``"waveform_af_sidelobe"`` (the built-in table :data:`TRIALS`, or a
  function decorated with :func:`register_trial`);
- an importable function: ``"package.module:function"``;
- a function in a Python file: ``"path/to/trials.py:function"`` (relative paths are taken from
  ``base_dir``, the sweep file's folder; workers on other machines need the same path).

A trial may carry a parameter check, ``validate_params(params) -> None`` raising
:class:`~hil.errors.ConfigError` named after the parameter; the sweep loader calls it for every
grid point before any trial runs (:func:`register_trial` ``validate=`` attaches it). It may
also carry a report, ``write_report(spec, records, out_dir) -> list[Path]``, which
:func:`~hil.evaluation.engine.run_sweep` calls once every trial has a record (``report=``).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import re
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any, TypeVar

from hil.errors import ConfigError

Params = dict[str, Any]
TrialResult = dict[str, Any]
Trial = Callable[..., TrialResult]
Validator = Callable[[Params], None]
Reporter = Callable[..., list[Path]]

#: Built-in trials: name -> ``"module:function"``, imported on first use so that adding a trial
#: that needs the simulator or a receiver costs nothing until a sweep uses it.
TRIALS: dict[str, str] = {
    "waveform_af_sidelobe": "hil.evaluation.trials_waveform:waveform_af_sidelobe",
    "ch6_receiver": "hil.evaluation.trials_ch6:ch6_receiver_trial",
    "ch6_fmcw": "hil.evaluation.trials_ch6:ch6_fmcw_trial",
    "ch6_cost": "hil.evaluation.trials_ch6:ch6_cost_trial",
    "tank_run": "hil.evaluation.trials_tank:tank_run_trial",
    "scene": "hil.evaluation.trials_scene:scene_trial",
}

# An importable module name: dotted identifiers, no path separators, no leading dot.
_MODULE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")

# Modules loaded from a file path get this prefix plus a hash of the path as module name.
_FILE_MODULE_PREFIX = "_hil_trial_file_"
_file_modules: dict[str, Path] = {}

F = TypeVar("F", bound=Callable[..., Any])


def register_trial(
    name: str, *, validate: Validator | None = None, report: Reporter | None = None
) -> Callable[[F], F]:
    """Decorator: make ``fn`` available to sweeps as ``name``.

    The registration stores the function's import target, not the function, so worker
    processes load it from its module. ``validate`` (optional) checks one grid point's
    parameters before any trial runs; ``report`` (optional) writes the sweep's report.

    >>> @register_trial("doc_example_square")
    ... def square(params, seed):
    ...     return {"y": params["x"] ** 2}
    >>> TRIALS["doc_example_square"].endswith(":square")
    True
    >>> unregister_trial("doc_example_square")
    """

    def decorate(fn: F) -> F:
        target = _target_of(fn)
        known = TRIALS.get(name)
        if known is not None and known != target:
            raise ConfigError(
                "trial name",
                name,
                "a name not yet registered",
                f"{name!r} is already {known}; choose another name",
            )
        if validate is not None:
            fn.validate_params = validate  # type: ignore[attr-defined]
        if report is not None:
            fn.write_report = report  # type: ignore[attr-defined]
        TRIALS[name] = target
        return fn

    return decorate


def unregister_trial(name: str) -> None:
    """Forget a registration made with :func:`register_trial` (tests, interactive use)."""
    TRIALS.pop(name, None)


def _target_of(fn: Callable[..., Any]) -> str:
    module = fn.__module__
    if module in _file_modules:
        return f"{_file_modules[module]}:{fn.__qualname__}"
    return f"{module}:{fn.__qualname__}"


def resolve_trial(spec: str, base_dir: Path | None = None, field: str = "sweep.trial") -> str:
    """The import target of the trial named ``spec`` (a name, ``module:function`` or
    ``file.py:function``); a file path is made absolute against ``base_dir``.

    Raises :class:`ConfigError` naming ``field`` when ``spec`` is none of these.

    >>> resolve_trial("waveform_af_sidelobe")
    'hil.evaluation.trials_waveform:waveform_af_sidelobe'
    """
    if spec in TRIALS:
        return TRIALS[spec]
    module, sep, attr = spec.rpartition(":")
    if not sep or not module or not attr:
        raise ConfigError(
            field,
            spec,
            f"a registered trial (one of {', '.join(sorted(TRIALS))}), "
            "'package.module:function' or 'file.py:function'",
            "register the trial with @register_trial or name its module and function",
        )
    if module.endswith(".py"):
        path = Path(module)
        if not path.is_absolute():
            path = (base_dir or Path.cwd()) / path
        return f"{path.resolve()}:{attr}"
    if not _MODULE_NAME.match(module):
        # A path-like module ('../trials', './x', 'a/b') cannot be imported by name; the
        # file form with its .py suffix can, relative to the sweep file's folder.
        raise ConfigError(
            field,
            spec,
            "'package.module:function' (dotted names) or 'file.py:function' (a path)",
            f"to load a file, write its name with .py: '{module}.py:{attr}'"
            if module.strip("./")
            else "to load a file, write its name with .py, e.g. '../trials.py:function'",
        )
    return spec


def load_trial(target: str, field: str = "sweep.trial") -> Trial:
    """Import and return the trial function of ``target`` (from :func:`resolve_trial`)."""
    module_name, _, attr = target.rpartition(":")
    module = _load_module(module_name, field, target)
    obj: Any = module
    for part in attr.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            raise ConfigError(
                field, target, f"a function that exists; {module_name} has no {attr!r}"
            )
    if not callable(obj):
        raise ConfigError(field, target, "a callable trial(params, seed)")
    trial: Trial = obj
    return trial


def _load_module(module_name: str, field: str, target: str) -> ModuleType:
    if module_name.endswith(".py"):
        return _load_file_module(Path(module_name), field, target)
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        missing = exc.name or ""
        if module_name == missing or module_name.startswith(missing + "."):
            raise ConfigError(
                field,
                target,
                "a trial in an importable module",
                f"module {missing!r} is not installed here (workers need it too)",
            ) from None
        raise


def _load_file_module(path: Path, field: str, target: str) -> ModuleType:
    digest = hashlib.sha1(str(path).encode()).hexdigest()[:16]
    name = _FILE_MODULE_PREFIX + digest
    if name in sys.modules:
        return sys.modules[name]
    if not path.is_file():
        raise ConfigError(field, target, "a trial in an existing Python file", f"{path} not found")
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:  # pragma: no cover - .py files always have one
        raise ConfigError(field, target, "a Python source file")
    module = importlib.util.module_from_spec(spec)
    # Registered before exec so that pickling by reference and @register_trial inside the
    # file see a module that can be found again by name.
    sys.modules[name] = module
    _file_modules[name] = path
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        del _file_modules[name]
        raise
    return module


def trial_validator(trial: Trial) -> Validator | None:
    """The trial's parameter check, if it has one."""
    validate: Validator | None = getattr(trial, "validate_params", None)
    return validate


def trial_reporter(trial: Trial) -> Reporter | None:
    """The trial's report writer, if it has one."""
    report: Reporter | None = getattr(trial, "write_report", None)
    return report
