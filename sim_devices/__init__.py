"""Simulated devices behind the same interfaces as the real ones.

The simulated board (:mod:`.board`), GRBL stage (:mod:`.stage`), audio interface
(:mod:`.audio`) and the tank acoustics (:mod:`.acoustics`). They may import
:mod:`firmware_protocol`, the host's pure signal code (:mod:`hil.signals`,
:mod:`hil.errors`) and the contracts they implement (the audio callback contract of
:mod:`hil.devices.audio`, the :class:`~hil.devices.clock.Clock`), never host drivers.
"""
