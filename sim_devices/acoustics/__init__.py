"""Acoustic channel and environment: geometry, delay/Doppler, propagation, noise,
reverberation, tank."""
