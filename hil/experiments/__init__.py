"""Experiments run on the testbench: the towed-target tank run (:mod:`.tank_run`, its live
parts in :mod:`.live`, its scoring, report and rebuild from a recording, a Python API in
:mod:`.api`) and the calibration routines (:mod:`.calibration`)."""
