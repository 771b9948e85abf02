"""``import hil`` is cheap and exports the main entry points lazily (PEP 562)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

import hil

ROOT = Path(__file__).resolve().parents[1]


def test_import_hil_loads_no_heavy_module() -> None:
    code = "import json, sys, hil; print(json.dumps(sorted(sys.modules)))"
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, check=True)  # fmt: skip
    loaded = {m.split(".")[0] for m in json.loads(proc.stdout)}
    assert loaded.isdisjoint({"numpy", "scipy", "matplotlib", "h5py", "numba"})


@pytest.mark.parametrize("name", hil.__all__)
def test_every_export_resolves_to_its_module_object(name: str) -> None:
    value = getattr(hil, name)
    module = hil._EXPORTS[name]
    assert value is getattr(sys.modules[module], name)


def test_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="module 'hil' has no attribute 'nope'"):
        hil.nope  # noqa: B018


def test_exports_work_together() -> None:
    schedule = hil.check_design(hil.get_preset("att").spec("random-cyclic"))
    assert isinstance(schedule, hil.HopSchedule)
    fig = hil.spectrogram_figure(schedule, 100_000.0, 0.05)
    assert type(fig).__name__ == "Figure"
