"""``hil docs``: the documentation from wherever the package is installed, and every help
string or message that points at a document names it the way ``hil docs`` finds it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hil.cli.docs import docs_dir, topics
from hil.cli.main import main

ROOT = Path(__file__).resolve().parents[2]


def test_docs_lists_every_document_with_its_title(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["docs"]) == 0
    lines = capsys.readouterr().out.splitlines()
    shipped = sorted(p.stem for p in (ROOT / "docs").glob("*.md"))
    assert [line.split()[0] for line in lines[:-1]] == shipped
    assert "tank-run          The towed-target tank run (`hil tank-run`)" in lines
    assert lines[-1] == f"(hil docs TOPIC prints one; they are in {docs_dir()})"


def test_docs_topic_prints_the_document_and_path_names_it(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["docs", "tank-run"]) == 0
    assert capsys.readouterr().out == (ROOT / "docs" / "tank-run.md").read_text(encoding="utf-8")
    assert main(["docs", "docs/bluesky.md", "--path"]) == 0  # as older messages named it
    path = Path(capsys.readouterr().out.strip())
    assert (
        path.name == "bluesky.md" and path.read_bytes() == (ROOT / "docs/bluesky.md").read_bytes()
    )


def test_an_unknown_topic_is_refused_with_the_closest_one(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["docs", "tank-rn"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hil docs: error: TOPIC = 'tank-rn' is not allowed: must be one of ")
    assert err.endswith("hil docs lists them with their titles (did you mean tank-run?)\n")


def _strings(path: Path) -> list[str]:
    """The string literals of a module (not its docstrings' prose only: every literal)."""
    import ast

    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [
        n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)
    ]


@pytest.mark.slow
def test_every_document_named_in_help_or_messages_is_an_installed_topic() -> None:
    named: set[str] = set()
    stale: list[str] = []
    for path in sorted((ROOT / "hil").rglob("*.py")):
        if "docs" in path.relative_to(ROOT / "hil").parts[:1]:
            continue
        body = path.read_text(encoding="utf-8")
        named |= set(re.findall(r"hil docs ([a-z][a-z-]+)", body))
        if path.parent.name == "cli" or "ConfigError(" in body:
            for text in _strings(path):
                if re.search(r"docs/[a-z-]+\.md", text) and "\n" not in text.strip():
                    stale.append(f"{path.relative_to(ROOT)}: {text[:60]}")
    assert named and named <= set(topics()) | {"lists", "topic"}, named - set(topics())
    assert stale == [], "user-facing strings naming docs/*.md: say hil docs TOPIC"


def test_the_package_is_marked_typed() -> None:
    from importlib.resources import files

    assert (Path(str(files("hil"))) / "py.typed").is_file()
