"""Type check of receiver-specific options against the receiver's constructor annotations.

Options arrive untyped from ``--option KEY=VALUE`` and from an experiment file's
``[receiver] options`` table; a wrong type is refused here with one line naming the option,
the value, the type its constructor declares and an example (the constructor default),
before it can reach arithmetic as a bare ``TypeError``. Unknown keys are left to the
receiver's ``from_options`` (which lists the known ones).

>>> from hil.estimation.gcas import GcasReceiver
>>> check_option_types(GcasReceiver, {"n_doppler": 32, "reverb_speed_mps": 0.8}, "gcas")
>>> check_option_types(GcasReceiver, {"n_doppler": np.int64(32), "pfa": np.float32(1e-3)}, "gcas")
>>> check_option_types(GcasReceiver, {"cfar_lambda": None, "search": "full"}, "gcas")
>>> check_option_types(GcasReceiver, {"coherent": "yes"}, "gcas")
Traceback (most recent call last):
...
hil.errors.ConfigError: coherent = 'yes' is not allowed: must be true or false (a gcas option); \
e.g. coherent=false
>>> check_option_types(GcasReceiver, {"n_doppler": 2.5}, "gcas", "receiver.options.")
Traceback (most recent call last):
...
hil.errors.ConfigError: receiver.options.n_doppler = 2.5 is not allowed: must be an integer \
(a gcas option); e.g. n_doppler=64
>>> check_option_types(GcasReceiver, {"n_doppler": "abc"}, "gcas")
Traceback (most recent call last):
...
hil.errors.ConfigError: n_doppler = 'abc' is not allowed: must be an integer (a gcas option); \
e.g. n_doppler=64
"""

from __future__ import annotations

import inspect
import math
import numbers
from typing import Any, NamedTuple

import numpy as np

from hil.errors import ConfigError

_WORDS = {"bool": "true or false", "int": "an integer", "float": "a finite number",
          "str": "a string"}  # fmt: skip


class OptionNames(NamedTuple):
    """The option names a receiver class takes (``receiver.options`` keys, ``--option KEY=``),
    from its ``option_names()`` classmethod (:mod:`hil.estimation.registry`).

    ``own``: read by the receiver class itself (a baseline's or GCAS's constructor keywords,
    or an input stage's options); ``gcas``: handed on to the GCAS it is built on, typed by
    GCAS's constructor (empty for a receiver not built on GCAS). A name in both is its own.

    >>> sorted(OptionNames(frozenset({"still_periods"}), frozenset({"pfa"})).all)
    ['pfa', 'still_periods']
    """

    own: frozenset[str]
    gcas: frozenset[str] = frozenset()

    @property
    def all(self) -> frozenset[str]:
        """Every name the receiver accepts."""
        return self.own | self.gcas


def _kinds(annotation: str) -> set[str] | None:
    """The plain types of an annotation string (``"float | None"`` -> {float, None})."""
    parts = {p.strip() for p in annotation.split("|")}
    plain = parts - {"None"}
    if not plain or not plain <= set(_WORDS):
        return None  # a callable, an object: not a value the user types
    return parts


def _fits(value: Any, kinds: set[str]) -> bool:
    """Whether ``value`` (NumPy scalars included) is of one of ``kinds``."""
    if value is None:
        return "None" in kinds
    if isinstance(value, bool | np.bool_):
        return "bool" in kinds
    if isinstance(value, numbers.Integral):
        return bool(kinds & {"int", "float"})
    if isinstance(value, numbers.Real):
        return "float" in kinds and math.isfinite(float(value))
    if isinstance(value, str):
        return "str" in kinds
    return False


def check_option_types(cls: Any, options: dict[str, Any], receiver: str, prefix: str = "") -> None:
    """Refuse an option of ``options`` whose value does not fit ``cls.__init__``'s annotation.

    ``prefix`` is prepended to the option name in messages (``"receiver.options."``).
    """
    params = inspect.signature(cls.__init__).parameters
    for key, value in options.items():
        param = params.get(key)
        if param is None:
            continue
        annotation = param.annotation
        text = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", "")
        kinds = _kinds(text)
        if kinds is None or _fits(value, kinds):
            continue
        allowed = " or ".join(_WORDS[k] for k in sorted(kinds - {"None"}))
        if "None" in kinds:
            allowed += " (or left out)"
        example = param.default if param.default not in (None, inspect.Parameter.empty) else ""
        shown = str(example).lower() if isinstance(example, bool) else example
        hint = f"e.g. {key}={shown}" if shown != "" else ""
        raise ConfigError(f"{prefix}{key}", value, f"{allowed} (a {receiver} option)", hint)
