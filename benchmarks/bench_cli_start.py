"""Start-up time of the ``hil`` command against ``python -c "import numpy"``.

Target (issue 22): ``hil --help`` within 3x the time of importing NumPy, so commands start
fast (each command imports its own dependencies inside the command). Each figure is the best
of ``--repeat`` fresh interpreters (wall clock, s); ``hil_over_numpy`` is the ratio. The
heaviest imports of ``hil --help`` are listed from ``python -X importtime``.

Run: ``python benchmarks/bench_cli_start.py [--repeat 10] [--quick]``. The last line is one
JSON object with the figures.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_RATIO = 3.0
HELP = [sys.executable, "-m", "hil.cli.main", "--help"]
NUMPY = [sys.executable, "-c", "import numpy"]


def best_time(command: list[str], repeat: int) -> float:
    """Best wall-clock time (s) of ``repeat`` runs of ``command`` in a fresh interpreter."""
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        subprocess.run(command, cwd=ROOT, capture_output=True, check=True)
        best = min(best, time.perf_counter() - start)
    return best


def heaviest_imports(n: int) -> list[tuple[str, float]]:
    """The ``n`` top-level imports of ``hil --help`` with the largest cumulative time (ms)."""
    proc = subprocess.run(
        [sys.executable, "-X", "importtime", *HELP[1:]],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    )
    rows = []
    for line in proc.stderr.splitlines():
        if not line.startswith("import time:") or "cumulative" in line:
            continue
        _, cumulative, name = (part.strip() for part in line[len("import time:") :].split("|"))
        if not name.startswith(" "):
            rows.append((name.strip(), int(cumulative) / 1000.0))
    return sorted(rows, key=lambda r: -r[1])[:n]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10, help="runs per command (best kept)")
    parser.add_argument("--quick", action="store_true", help="3 runs per command")
    args = parser.parse_args()
    repeat = 3 if args.quick else args.repeat
    numpy_s = best_time(NUMPY, repeat)
    help_s = best_time(HELP, repeat)
    ratio = help_s / numpy_s
    print(f"python -c 'import numpy': {numpy_s * 1e3:7.1f} ms (best of {repeat})")
    print(f"hil --help              : {help_s * 1e3:7.1f} ms  ({ratio:.2f}x numpy)")
    print(f"target                  : <= {TARGET_RATIO:.0f}x numpy -> "
          f"{'met' if ratio <= TARGET_RATIO else 'NOT met'}")  # fmt: skip
    heavy = heaviest_imports(5)
    for name, ms in heavy:
        print(f"  import {name:<40} {ms:7.1f} ms cumulative")
    print(
        json.dumps(
            {
                "numpy_import_s": round(numpy_s, 4),
                "hil_help_s": round(help_s, 4),
                "hil_over_numpy": round(ratio, 3),
                "target_ratio": TARGET_RATIO,
                "met": ratio <= TARGET_RATIO,
                "heaviest_imports_ms": {name: ms for name, ms in heavy},
            }
        )
    )


if __name__ == "__main__":
    main()
