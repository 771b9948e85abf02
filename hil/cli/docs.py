"""``hil docs [TOPIC]``: the user documentation, from wherever the package is installed.

The documents (``docs/*.md`` of the source tree) ship in the package as ``hil/docs``.
Without TOPIC the command lists them (topic and title); with one it prints the document
(Markdown, which reads as plain text), or its path with ``--path`` (to open it in an editor
or a Markdown viewer).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from hil.errors import ConfigError


def register(sub: Any) -> None:
    """Add the ``docs`` sub-command."""
    p: argparse.ArgumentParser = sub.add_parser(
        "docs",
        help="print the installed documentation (hil docs lists the topics)",
        description="Print a document of the installed package: tank-run, calibration, "
        "bluesky, ... (without TOPIC: the list of topics and their titles).",
    )
    p.add_argument("topic", nargs="?", help="the document to print, e.g. tank-run")
    p.add_argument("--path", action="store_true", help="print the document's path instead")
    p.set_defaults(func=run)


def docs_dir() -> Path:
    """The installed documents' folder (``hil/docs``)."""
    from importlib.resources import files

    return Path(str(files("hil") / "docs"))


def topics() -> dict[str, Path]:
    """Topic name (the file's stem) -> document, sorted by name."""
    return {p.stem: p for p in sorted(docs_dir().glob("*.md"))}


def title(path: Path) -> str:
    """The document's first heading, without its ``#``."""
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            return line.lstrip("#").strip()
    return ""


def run(args: argparse.Namespace) -> int:
    """Execute ``hil docs``; 0."""
    from hil.toml_table import did_you_mean

    found = topics()
    if args.topic is None:
        width = max(len(name) for name in found)
        for name, path in found.items():
            print(f"{name:<{width}}  {title(path)}")
        print(f"(hil docs TOPIC prints one; they are in {docs_dir()})")
        return 0
    # The topics are the files' lower-case stems: TANK-RUN, docs/tank-run.md name one too.
    topic = args.topic.lower().removesuffix(".md").removeprefix("docs/")
    if topic not in found:
        raise ConfigError(
            "TOPIC",
            args.topic,
            f"one of {', '.join(found)}",
            "hil docs lists them with their titles" + did_you_mean(topic, tuple(found)),
        )
    path = found[topic]
    print(path if args.path else path.read_text(encoding="utf-8"), end="\n" if args.path else "")
    return 0
