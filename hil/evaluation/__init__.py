"""Monte Carlo sweeps: grids of trial parameters run on a process pool or a Dask cluster.

A *trial* is a pure function ``trial(params, seed) -> dict`` (no hardware) registered by name
(:mod:`hil.evaluation.registry`). A *sweep* (:class:`~hil.evaluation.spec.SweepSpec`, usually
read from a TOML file by :mod:`hil.evaluation.sweep_file`) is the cartesian product of its grid
values times ``trials_per_point`` repetitions; every trial draws its randomness from a
:class:`numpy.random.SeedSequence` child fixed by the sweep's root entropy and the trial's
(point, repetition) alone (:mod:`hil.evaluation.seeds`), so numbers do not depend on the runner,
the number of workers or the order of completion.

:func:`~hil.evaluation.engine.run_sweep` streams one JSON line per finished trial to disk
(:mod:`hil.evaluation.store`), resumes an interrupted sweep without redoing finished trials,
records failing trials and goes on, shows progress (:mod:`hil.evaluation.progress`) and writes
the per-point summary (:mod:`hil.evaluation.aggregate`). Runners live in
:mod:`hil.evaluation.runners`; Dask is imported only by the Dask runner.
"""
