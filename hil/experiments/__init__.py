"""Experiments run on the testbench: calibration routines (and, later, towed runs)."""
