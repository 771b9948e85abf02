"""Calibration routines (latency, response, level, sound speed, stage) and their store."""
