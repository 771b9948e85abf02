"""Plotting functions return figures and leave matplotlib's backend and pyplot alone, so they
work in a notebook with whatever backend the user chose."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = """
import sys
import matplotlib
matplotlib.use("svg")
import numpy as np
import pytest
from matplotlib.figure import Figure
from hil.experiments.codeword_map import save_time_codeword_map, time_codeword_map_figure
from hil.signals.plots import occupancy_figure, plot_spectrogram, spectrogram_figure
from hil.signals.presets import check_design, get_preset

schedule = check_design(get_preset("att").spec("random-cyclic"))
figures = [
    spectrogram_figure(schedule, 100_000.0, 0.05),
    occupancy_figure(schedule),
    time_codeword_map_figure([np.arange(5.0)], [np.ones((5, 3))]),
]
assert all(isinstance(f, Figure) for f in figures)
out = sys.argv[1]
plot_spectrogram(schedule, 100_000.0, 0.05, __import__("pathlib").Path(out) / "s.png")
save_time_codeword_map(__import__("pathlib").Path(out) / "m.png", [np.arange(5.0)],
                       [np.ones((5, 3))])
print(matplotlib.get_backend(), "matplotlib.pyplot" in sys.modules)
"""


@pytest.mark.slow
def test_figures_returned_backend_untouched_pyplot_never_imported(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(tmp_path)],
        cwd=ROOT, capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["svg", "False"]
    for name in ("s.png", "m.png"):
        assert (tmp_path / name).read_bytes().startswith(b"\x89PNG\r\n\x1a\n")


@pytest.mark.slow
def test_no_module_switches_the_backend_or_imports_pyplot() -> None:
    offenders = []
    for path in sorted((ROOT / "hil").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            func = node.func if isinstance(node, ast.Call) else None
            if (
                isinstance(func, ast.Attribute)
                and func.attr == "use"
                and getattr(func.value, "id", "") == "matplotlib"
            ):
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} matplotlib.use")
            if isinstance(node, ast.Import | ast.ImportFrom):
                names = [a.name for a in node.names]
                module = getattr(node, "module", None) or ""
                if "matplotlib.pyplot" in names or module == "matplotlib.pyplot":
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} imports pyplot")
    assert offenders == []
