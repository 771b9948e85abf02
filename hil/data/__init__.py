"""Data files shipped inside the package: chapter-6 sweep files and example scenarios.

Found through :mod:`importlib.resources`, so they are there the same way in a source checkout,
an editable install and an installed wheel:

- ``sweeps/*.toml``: the sweep files of ``hil reproduce`` and ``hil sweep NAME`` (``tank-mc``,
  ``scenes``; format: docs/sweeps.md);
- ``scenarios/*.toml``: example scenarios of ``hil simulate`` (format: hil docs scenarios).

The package is installed as plain files (setuptools never zips it), so each folder is a real
directory on disk and is handed out as a :class:`~pathlib.Path`.

>>> sorted(shipped_scenarios())
['att', 'tank-audio', 'tank-board']
>>> scenario_path("att").name
'att.toml'
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from hil.errors import ConfigError

__all__ = ["scenario_path", "scenarios_dir", "shipped_scenarios", "sweeps_dir"]


def _folder(name: str) -> Path:
    """The shipped folder ``name`` as a path on disk."""
    folder = files(__name__) / name
    path = Path(str(folder))
    if not path.is_dir():  # pragma: no cover - only if the package were imported from a zip
        raise FileNotFoundError(2, "shipped data folder missing", str(folder))
    return path


def sweeps_dir() -> Path:
    """The folder of the shipped sweep files: the chapter-6 items (``<item id>.toml``),
    ``tank-mc.toml`` and ``scenes.toml``."""
    return _folder("sweeps")


def scenarios_dir() -> Path:
    """The folder of the example scenarios (``<name>.toml``)."""
    return _folder("scenarios")


def shipped_scenarios() -> dict[str, Path]:
    """Example scenario name -> its TOML file."""
    return {p.stem: p for p in sorted(scenarios_dir().glob("*.toml"))}


def scenario_path(name: str) -> Path:
    """The shipped scenario called ``name`` (``att``, ``tank-audio``, ``tank-board``)."""
    known = shipped_scenarios()
    if name not in known:
        raise ConfigError(
            "scenario", name, f"a TOML file or one of {', '.join(known)}",
            "give the path of a scenario file (format: hil docs scenarios)",
        )  # fmt: skip
    return known[name]
