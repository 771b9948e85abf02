"""numba's start without its BLAS check, for a short command's start-up (``hil estimate``).

When numba first compiles or loads a kernel it imports ``numba.np.arraymath``, which checks
at import that a BLAS is there by importing ``scipy.linalg.cython_blas``: the whole of
``scipy.linalg`` (0.15-0.3 s of CPU, the largest single part of ``hil estimate``'s
start-up; ``benchmarks/bench_estimate_start.py --breakdown``). No kernel of this package
needs it: none calls ``np.dot``, ``np.vdot``, ``np.linalg`` or ``@`` on arrays inside
compiled code, and the check's only use is to pick BLAS's dot product for compiled
``np.correlate`` and ``np.convolve``, which none calls either (tested). :func:`skip_blas_check`
imports that module with the check failing, so numba records "no BLAS" for those two and
goes on; a compiled ``np.dot`` still works (numba imports ``scipy.linalg`` when it compiles
one: tested).
"""

from __future__ import annotations

import importlib
import sys

#: The module numba's check imports; held out of reach (None in ``sys.modules``) meanwhile.
BLAS_MODULE = "scipy.linalg.cython_blas"
#: The numba module whose import runs the check.
CHECKING_MODULE = "numba.np.arraymath"


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
