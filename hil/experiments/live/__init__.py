"""The parts of a live tank run, one job each, composed by
:func:`hil.experiments.tank_run.run_experiment`:

- :mod:`~hil.experiments.live.plan`: refusals before anything moves or transmits (the run
  folder, the tow against the stage's reported limits);
- :mod:`~hil.experiments.live.stops`: why a run stops (signals, lost devices) and the
  recording's event for it.
"""
