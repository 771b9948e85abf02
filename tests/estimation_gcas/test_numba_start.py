"""numba's start without its BLAS check, scipy, cffi and yaml (hil.estimation.numba_start): no
compiled kernel of the package uses what the check is for, a compiled np.dot still works after
it, the others import as usual afterwards, and a numba settings file is still read."""

from __future__ import annotations

import importlib
import inspect
import json
import os
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest
from numba.core.registry import CPUDispatcher

import hil
import sim_devices

ROOT = Path(__file__).resolve().parents[2]
#: What numba's BLAS check serves in compiled code: BLAS products (np.dot, np.vdot, np.inner,
#: np.outer, np.kron, np.matmul, np.linalg, the @ operator) and np.correlate / np.convolve.
BLAS_USES = re.compile(
    r"np\.(dot|vdot|inner|outer|kron|matmul|linalg|correlate|convolve)\b|[\w\)\]]\s*@\s*[\w\(]"
)


def _kernels() -> list[CPUDispatcher]:
    """Every numba kernel defined in a module of hil or sim_devices that mentions numba."""
    found = []
    for package in (hil, sim_devices):
        for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
            spec = importlib.util.find_spec(info.name)
            if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
                continue
            if "numba" not in Path(spec.origin).read_text(encoding="utf-8"):
                continue
            module = importlib.import_module(info.name)
            found += [
                v for v in vars(module).values()
                if isinstance(v, CPUDispatcher) and v.py_func.__module__ == info.name
            ]  # fmt: skip
    return found


@pytest.mark.slow
def test_no_compiled_kernel_uses_blas_or_correlate() -> None:
    kernels = _kernels()
    assert len(kernels) >= 40  # the receivers', the tracker's, the simulator's
    users = [
        f"{k.py_func.__module__}.{k.py_func.__name__}"
        for k in kernels
        if BLAS_USES.search(inspect.getsource(k.py_func))
    ]
    assert users == []


@pytest.mark.slow
def test_the_check_is_skipped_and_a_compiled_dot_still_works() -> None:
    code = (
        "import json, sys\n"
        "import numpy as np\n"
        "from hil.estimation.numba_start import skip_blas_check\n"
        "done = skip_blas_check()\n"
        "linalg_after_skip = 'scipy.linalg' in sys.modules\n"
        "again = skip_blas_check()\n"
        "import numba\n"
        "from numba.np import arraymath\n"
        "@numba.njit(cache=False)\n"
        "def dot(a, b):\n"
        "    return np.dot(a, b)\n"
        "value = float(dot(np.arange(3.0), np.arange(3.0)))\n"
        "print(json.dumps([done, again, linalg_after_skip, arraymath._HAVE_BLAS, value,\n"
        "                  'scipy.linalg' in sys.modules]))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    done, again, linalg_after_skip, have_blas, value, linalg_at_end = json.loads(
        proc.stdout.splitlines()[-1]
    )
    assert (done, again, linalg_after_skip, have_blas) == (True, False, False, False)
    # np.dot compiles through scipy.linalg's BLAS, imported then: 0 + 1 + 4.
    assert value == 5.0 and linalg_at_end


def _fresh(code: str, cwd: Path) -> list[object]:
    """The JSON list ``code`` prints last, run in a fresh interpreter in ``cwd``."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, check=True, env=env
    )
    result: list[object] = json.loads(proc.stdout.splitlines()[-1])
    return result


_START = (
    "import json, sys\n"
    "from hil.estimation.numba_start import start_numba\n"
    "held = start_numba()\n"
    "loaded = sorted(m for m in ('scipy', 'cffi', 'yaml') if m in sys.modules)\n"
    "from numba.core import config\n"
    "from numba.core.typing import cffi_utils\n"
    "from numba.np import arraymath\n"
    "import scipy\n"
    "import numba, numpy as np\n"
    "@numba.njit(cache=False)\n"
    "def total(a):\n"
    "    return a.sum()\n"
    "print(json.dumps([held, loaded, cffi_utils.SUPPORTED, arraymath._HAVE_BLAS,\n"
    "                  float(total(np.arange(4.0))), config.BOUNDSCHECK, start_numba()]))\n"
)


@pytest.mark.slow
def test_numba_starts_without_scipy_cffi_and_yaml_and_they_import_after(tmp_path: Path) -> None:
    held, loaded, cffi, blas, value, _, again = _fresh(_START, tmp_path)
    assert (held, loaded) == (["scipy", "cffi", "yaml"], [])
    # numba takes cffi and BLAS as absent, compiles and runs a kernel; scipy imports after.
    assert (cffi, blas, value, again) == (False, False, 6.0, [])


@pytest.mark.slow
def test_a_numba_config_file_is_still_read(tmp_path: Path) -> None:
    # yaml is not held out where the working folder has numba's settings: they are read.
    (tmp_path / ".numba_config.yaml").write_text("BOUNDSCHECK: 1\n", encoding="utf-8")
    held, loaded, _, _, _, bounds, _ = _fresh(_START, tmp_path)
    assert (held, loaded, bounds) == (["scipy", "cffi"], ["yaml"], 1)
