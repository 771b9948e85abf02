"""Estimators: streaming GCAS, the comparison receivers, and the Cramér–Rao bounds.

Every receiver implements :class:`hil.estimation.base.Receiver` and emits
:class:`hil.estimation.base.Estimate` records, so simulations, recordings and live runs use the
same code and the same output format.
"""
