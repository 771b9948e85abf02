"""Host side of the CAS hardware-in-the-loop testbench.

Signals (HFC-CW and comparison waveforms), estimators (GCAS and baselines), device drivers,
acquisition, experiments and the ``hil`` command line. The host never imports
:mod:`sim_devices` at module level: simulated devices are reached lazily through the
transport URL registry (``sim://...``) and the evaluation engine.
"""

__version__ = "0.1.0"
