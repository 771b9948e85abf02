"""numba's start without the imports no kernel here needs, for a short command's start-up
(``hil estimate``).

numba imports, on its way to the first compiled kernel, four things none of this package's
kernels use (``benchmarks/bench_estimate_start.py --breakdown`` measures each):

- ``scipy.linalg``, through ``numba.np.arraymath``'s check that a BLAS is there (0.15-0.3 s
  of CPU, the largest single part of ``hil estimate``'s start-up). No kernel of this package
  needs it: none calls ``np.dot``, ``np.vdot``, ``np.linalg`` or ``@`` on arrays inside
  compiled code, and the check's only use is to pick BLAS's dot product for compiled
  ``np.correlate`` and ``np.convolve``, which none calls either (tested). numba then records
  "no BLAS" for those two and goes on; a compiled ``np.dot`` still works (numba imports
  ``scipy.linalg`` when it compiles one: tested).
- ``scipy``'s base package, only to check that its version is at least 1.0 (``import numba``).
- ``cffi`` and its C parser, to type cffi functions passed to a kernel (at the first call of
  any kernel); none of this package's kernels takes one.
- ``yaml``, to read a ``.numba_config.yaml`` in the working folder; held out only where there
  is no such file, so a user's numba settings are read as ever.

:func:`start_numba` imports numba's modules that would import them with each held out of
reach (``None`` in ``sys.modules``) meanwhile: numba takes each as not installed and goes
on. A module imported later imports them as usual.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

#: The module numba's BLAS check imports; held out of reach during :func:`skip_blas_check`.
BLAS_MODULE = "scipy.linalg.cython_blas"
#: The numba module whose import runs the check.
CHECKING_MODULE = "numba.np.arraymath"
#: numba's module that imports cffi (at the first typing of a kernel's arguments).
CFFI_TYPING_MODULE = "numba.core.typing.cffi_utils"
#: The file numba reads its settings from (in the working folder), with ``yaml``.
NUMBA_CONFIG_FILE = ".numba_config.yaml"


@contextmanager
def _held_out(names: list[str]) -> Iterator[None]:
    """Imports of the top-level modules ``names`` fail (ImportError) within the block; each
    one already loaded is left as it is."""
    held = [n for n in names if n not in sys.modules]
    for name in held:
        sys.modules[name] = None  # type: ignore[assignment]
    try:
        yield
    finally:
        for name in held:
            if sys.modules.get(name, 0) is None:
                del sys.modules[name]


def skip_blas_check() -> bool:
    """Import :data:`CHECKING_MODULE` with its BLAS check failing: True where it was done
    now; False where numba had already run the check, where ``scipy.linalg`` is loaded
    anyway (the check then costs nothing) or where the module cannot be imported without
    BLAS (numba then imports it, and checks, as it would have)."""
    if CHECKING_MODULE in sys.modules or BLAS_MODULE in sys.modules:
        return False
    sys.modules[BLAS_MODULE] = None  # type: ignore[assignment]
    try:
        importlib.import_module(CHECKING_MODULE)
    except ImportError:
        return False
    finally:
        del sys.modules[BLAS_MODULE]
    return True


def start_numba() -> list[str]:
    """Import numba, its cffi typing and :data:`CHECKING_MODULE` (:func:`skip_blas_check`)
    with ``scipy``, ``cffi`` and (where the working folder holds no
    :data:`NUMBA_CONFIG_FILE`) ``yaml`` held out; return the names held out, none where
    numba was already imported (it has then imported what it would)."""
    if "numba" in sys.modules:
        skip_blas_check()
        return []
    names = ["scipy", "cffi"] + ([] if os.path.exists(NUMBA_CONFIG_FILE) else ["yaml"])
    held = [n for n in names if n not in sys.modules]
    with _held_out(held):
        importlib.import_module("numba")
        importlib.import_module(CFFI_TYPING_MODULE)
        skip_blas_check()
    return held
