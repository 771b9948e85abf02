"""Simulated devices behind the same interfaces as the real ones.

The simulated board, GRBL stage, audio interface and the tank acoustics. They may import
:mod:`firmware_protocol` and the host's pure signal code (:mod:`hil.signals`,
:mod:`hil.errors`), never host drivers.
"""
