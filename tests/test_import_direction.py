"""The import direction of DESIGN.md, checked on the source text of every module.

- ``firmware_protocol`` imports nothing from ``hil`` or ``sim_devices``, except the one
  lazy import that resolves the transport errors' old names (they moved to ``hil.errors``).
- ``sim_devices`` may import ``firmware_protocol`` and the host's pure code
  (``hil.signals``, ``hil.errors``, ``hil.toml_table``: the one TOML reader, and
  ``hil.config_sections``: its tables as dataclasses), and the contracts a simulated device
  implements (the audio callback contract, its settings and ring in ``hil.devices.audio``,
  the ``Clock`` of ``hil.devices.clock``: the simulated audio interface is one), never
  drivers or anything else of ``hil``.
- ``hil`` never imports ``sim_devices`` at module level (only inside functions, lazily; an
  ``if TYPE_CHECKING:`` block, which never runs, may name its types).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SIM_ALLOWED_FROM_HIL = (
    "hil.signals",
    "hil.errors",
    "hil.toml_table",
    "hil.config_sections",
    "hil.devices.audio.contract",
    "hil.devices.audio.settings",
    "hil.devices.audio.ring",
    "hil.devices.clock",
)
#: The compatibility import of the moved transport errors (inside a module ``__getattr__``).
PROTOCOL_COMPAT_IMPORT = ("firmware_protocol/errors.py", "hil")


def _modules(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


def _imports(path: Path, module_level_only: bool) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    nodes = tree.body if module_level_only else list(ast.walk(tree))
    found: list[tuple[int, str]] = []
    stack = list(nodes)
    while stack:
        node = stack.pop()
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module))
        elif module_level_only and isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)  # the body is for type checkers: it never runs
        elif module_level_only and isinstance(node, (ast.If, ast.Try, ast.With)):
            # Statements at module level that are not function bodies still run at import.
            stack.extend(ast.iter_child_nodes(node))
    return found


def _is_type_checking(test: ast.expr) -> bool:
    """``TYPE_CHECKING`` or ``typing.TYPE_CHECKING``."""
    name = test.attr if isinstance(test, ast.Attribute) else getattr(test, "id", None)
    return name == "TYPE_CHECKING"


def _top(name: str) -> str:
    return name.split(".")[0]


@pytest.mark.parametrize("path", _modules("firmware_protocol"), ids=str)
def test_firmware_protocol_imports_no_host_or_sim(path: Path) -> None:
    where = path.relative_to(ROOT).as_posix()
    bad = [
        (ln, m)
        for ln, m in _imports(path, False)
        if _top(m) in ("hil", "sim_devices") and (where, m) != PROTOCOL_COMPAT_IMPORT
    ]
    assert not bad, (
        f"{path.relative_to(ROOT)} imports {bad}: firmware_protocol must stay standalone"
    )


@pytest.mark.parametrize("path", _modules("sim_devices"), ids=str)
def test_sim_devices_import_only_pure_host_code(path: Path) -> None:
    bad = [
        (ln, m)
        for ln, m in _imports(path, False)
        if _top(m) == "hil" and not m.startswith(SIM_ALLOWED_FROM_HIL)
    ]
    assert not bad, f"{path.relative_to(ROOT)} imports {bad}: only {SIM_ALLOWED_FROM_HIL} allowed"


@pytest.mark.parametrize("path", _modules("hil"), ids=str)
def test_host_never_imports_sim_devices_at_module_level(path: Path) -> None:
    bad = [(ln, m) for ln, m in _imports(path, True) if _top(m) == "sim_devices"]
    assert not bad, f"{path.relative_to(ROOT)} imports sim_devices at module level: {bad}"


def test_checker_sees_violations(tmp_path: Path) -> None:
    # The checker itself must be able to fail: a module-level import is found, a lazy one not.
    src = tmp_path / "m.py"
    src.write_text("import sim_devices.board\n\ndef f():\n    import sim_devices.stage\n")
    assert _imports(src, True) == [(1, "sim_devices.board")]
    assert sorted(_imports(src, False)) == [(1, "sim_devices.board"), (4, "sim_devices.stage")]


def test_checker_lets_type_checking_blocks_name_types_only(tmp_path: Path) -> None:
    src = tmp_path / "m.py"
    src.write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    import sim_devices.audio\nelse:\n    import sim_devices.stage\n"
        "if True:\n    import sim_devices.board\n"
    )
    assert sorted(_imports(src, True)) == [
        (1, "typing"), (5, "sim_devices.stage"), (7, "sim_devices.board"),
    ]  # fmt: skip
