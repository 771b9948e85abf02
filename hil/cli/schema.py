"""``hil schema [KIND]``: the JSON Schema of a config file, for editors' completion.

The schemas are generated from the dataclasses that read the files
(:mod:`hil.config_sections`) and ship in the package as ``hil/data/schema/KIND.schema.json``.
Without KIND the command lists them and their installed paths; with one it prints the schema;
``--write`` regenerates the shipped files from the code (a developer's step after changing a
file's keys; a test checks that they agree).
"""

from __future__ import annotations

import argparse
import importlib
import json
from pathlib import Path
from typing import Any

from hil.errors import ConfigError

#: Config file kind -> the dataclass of the whole file ("module:Class"), and its title.
SCHEMAS: dict[str, tuple[str, str]] = {
    "experiment": (
        "hil.experiments.experiment_sections:ExperimentFile",
        "hil tank-run experiment file",
    ),
    "scenario": (
        "sim_devices.acoustics.scenario_sections:ScenarioFile",
        "hil simulate scenario file",
    ),
}
#: Base of the schemas' ``$id`` (the file name is appended).
SCHEMA_ID = "https://cas-hil.invalid/schema/"


def register(sub: Any) -> None:
    """Add the ``schema`` sub-command."""
    p: argparse.ArgumentParser = sub.add_parser(
        "schema",
        help="print the JSON Schema of a config file (for editor completion)",
        description="Print the JSON Schema of an experiment or scenario file (without KIND: "
        "the shipped schema files). Point your editor's TOML support at the file, e.g. "
        "with a first line #:schema PATH (Taplo, Even Better TOML).",
    )
    p.add_argument("kind", nargs="?", help=f"one of {', '.join(SCHEMAS)}")
    p.add_argument(
        "--write",
        action="store_true",
        help="regenerate the shipped schema files from the code (developers)",
    )
    p.set_defaults(func=run)


def schema_dir() -> Path:
    """The installed schemas' folder (``hil/data/schema``)."""
    from importlib.resources import files

    return Path(str(files("hil.data") / "schema"))


def schema_path(kind: str) -> Path:
    """The shipped schema file of ``kind``."""
    return schema_dir() / f"{kind}.schema.json"


def schema(kind: str) -> dict[str, Any]:
    """The JSON Schema of the ``kind`` file, generated from its dataclasses."""
    from hil.config_sections import json_schema

    if kind not in SCHEMAS:
        from hil.toml_table import did_you_mean

        raise ConfigError(
            "KIND", kind, f"one of {', '.join(SCHEMAS)}", "hil schema lists them" +
            did_you_mean(kind, tuple(SCHEMAS)),
        )  # fmt: skip
    target, title = SCHEMAS[kind]
    module, _, name = target.partition(":")
    cls = getattr(importlib.import_module(module), name)
    return json_schema(cls, title, SCHEMA_ID + schema_path(kind).name)


def schema_text(kind: str) -> str:
    """:func:`schema` as the shipped file's text (indented JSON, a final newline)."""
    return json.dumps(schema(kind), indent=2, ensure_ascii=False) + "\n"


def run(args: argparse.Namespace) -> int:
    """Execute ``hil schema``; 0."""
    kinds = list(SCHEMAS) if args.kind is None or args.write else [args.kind]
    if args.write:
        for kind in kinds:
            schema_path(kind).write_text(schema_text(kind), encoding="utf-8")
            print(f"wrote {schema_path(kind)}")
        return 0
    if args.kind is None:
        for kind in kinds:
            print(f"{kind:<11} {schema_path(kind)}")
        return 0
    print(schema_text(args.kind), end="")
    return 0
