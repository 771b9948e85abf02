"""Compile the suite's numba kernels into numba's on-disk cache before the test workers start.

``python tests/numba_warm_up.py PART`` runs a small workload that reaches the kernels of one
part (``tank``: a short built-in tank run on virtual time, i.e. the simulated world's echo and
reverberation kernels, COBS, GCAS's detection kernels and the tracker; ``receivers``: GCAS with
its coherent refinement and the matched-filter bank on an exact echo). Every kernel is compiled
with ``cache=True``, so a fresh checkout compiles each one once here and every later process
loads it from the cache instead of compiling it again (from an empty cache the ``tank`` part
took 19 s of CPU and the ``receivers`` part 28 s; with the cache filled 3.7 s and 3.0 s).
The root ``conftest.py`` runs the parts in parallel, one process each, while the pytest-xdist
workers import and collect the tests; a worker waits for them before its first test. The
workloads assert nothing: the tests check these paths.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

PARTS = ("tank", "receivers")


def warm_tank() -> None:
    """A 0.2 m built-in tank pass on virtual time (no live view), in a scratch folder."""
    from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
    from hil.experiments.tank_run import LiveView, run_experiment

    exp = parse_experiment(DEFAULT_EXPERIMENT.replace("end_m = -5.0", "end_m = -1.6"))
    with tempfile.TemporaryDirectory() as scratch:
        run_experiment(
            exp, folder=Path(scratch) / "run", view=LiveView(enabled=False), virtual_time=True
        )


def warm_receivers() -> None:
    """GCAS (coherent refinement on, its default; 30 m/s, 100 m) and a small matched-filter
    bank (2 m/s, 20 m: its kernels compile alike, its search costs far less) on 0.4 s of an
    exact echo at 10 m closing at 1 m/s (the ``att`` preset, 100 kHz) with seeded noise."""
    import numpy as np

    from hil.estimation.registry import make_receiver
    from hil.signals.presets import check_design, get_preset
    from sim_devices.acoustics.delay import TwoWayPath
    from sim_devices.acoustics.echo import AnalyticEcho
    from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed

    fs, c = 100_000.0, 1500.0
    schedule = check_design(get_preset("att").spec("random-cyclic"))
    path = TwoWayPath.monostatic(
        Fixed((0.0, 0.0, 0.0)), ConstantVelocity((10.0, 0.0, 0.0), (-1.0, 0.0, 0.0)), c
    )
    x = AnalyticEcho(schedule, path, fs).block(0, 40_000)
    x = x + np.random.default_rng(0).normal(0.0, 0.1, x.shape)
    for name, speed, far, extra in (
        ("gcas", 30.0, 100.0, {"m_hops": 10}),
        ("mfbank", 2.0, 20.0, {"m_hops": 2, "n_doppler": 3}),
    ):
        rx = make_receiver(
            name, schedule, fs, sound_speed_mps=c, max_speed_mps=speed, max_range_m=far, **extra
        )
        for i in range(0, x.shape[0], 10_000):
            rx.process(x[i : i + 10_000])
        rx.flush()


def main(argv: list[str]) -> int:
    """Run the parts named in ``argv`` (each of :data:`PARTS`); 0 when they ran."""
    for part in argv:
        {"tank": warm_tank, "receivers": warm_receivers}[part]()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
