"""The parts of a live tank run, one job each, composed by
:func:`hil.experiments.tank_run.run_experiment`:

- :mod:`~hil.experiments.live.plan`: refusals before anything moves or transmits (the run
  folder, the tow against the stage's reported limits);
- :mod:`~hil.experiments.live.devices`: the devices opened in that order, and stopped safely;
- :mod:`~hil.experiments.live.session`: transmission, capture
  (:class:`~hil.acquisition.capture.CaptureLoop`) and tow, composed;
- :mod:`~hil.experiments.live.latency`: the loopback latency probe;
- :mod:`~hil.experiments.live.tow`: the tow controller, driven by stage reports;
- :mod:`~hil.experiments.live.recorder`: what is recorded, and when;
- :mod:`~hil.experiments.live.board_state`: the board's events, xruns and SYNC pairs;
- :mod:`~hil.experiments.live.stops`: why a run stops (signals, lost devices) and the
  recording's event for it.
"""
