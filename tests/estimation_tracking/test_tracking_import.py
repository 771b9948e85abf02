"""The tracker imports numba only when a tracker is made: reading recordings never tracks."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _numba_loaded_after(code: str) -> bool:
    """Whether numba is imported after running ``code`` in a fresh interpreter."""
    probe = f"{code}\nimport json, sys\nprint(json.dumps('numba' in sys.modules))"
    proc = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, check=True
    )
    loaded: bool = json.loads(proc.stdout.strip().splitlines()[-1])
    return loaded


def test_importing_the_recording_package_does_not_import_numba() -> None:
    assert not _numba_loaded_after("import hil.recording, hil.estimation.tracking")


@pytest.mark.slow
def test_making_a_tracker_imports_its_compiled_association() -> None:
    assert _numba_loaded_after("from hil.estimation.tracking import Tracker\nTracker(0.01)")
