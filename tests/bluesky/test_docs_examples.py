"""The examples of docs/bluesky.md run as written: its Python blocks, in order, as one
script in a fresh folder (a subprocess: the RunEngine installs its Ctrl-C handler)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parents[2] / "docs" / "bluesky.md"


def _python_blocks(text: str) -> str:
    return "\n".join(re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL))


@pytest.mark.slow
def test_the_documented_towed_pass_and_list_scan_run_as_written(tmp_path: Path) -> None:
    script = _python_blocks(DOC.read_text(encoding="utf-8"))
    assert "towed_pass(tank" in script and "list_scan" in script
    done = subprocess.run(
        [sys.executable, "-c", script],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    lines = done.stdout.splitlines()
    assert re.fullmatch(r"runs/sim-towed-pass-\d{8}-\d{6}/run\.h5", lines[0])
    assert re.fullmatch(
        r"\d+ estimates, range RMSE 0\.0\d\d m, speed RMSE 0\.0\d\d m/s", lines[1]
    ), lines[1]
    # As the doc says: from the start of the run-up to the end of the run-down.
    assert lines[2] == "stage -1.40 .. -5.60 m"
    assert lines[3] == "success"
    assert (tmp_path / lines[0]).exists()
