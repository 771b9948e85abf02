"""Receivers by name, imported lazily.

Every receiver class provides the common constructor::

    Cls.from_options(schedule, fs_hz, *, sound_speed_mps, max_speed_mps, max_range_m,
                     m_hops, **extra) -> Receiver

where ``schedule`` is the transmit :class:`~hil.signals.schedule.HopSchedule` (time base: the
first input sample is at the schedule's t = 0 unless the receiver is told otherwise through
``extra``), ``fs_hz`` the input sample rate, ``sound_speed_mps`` c, ``max_speed_mps`` the
Doppler search span (±), ``max_range_m`` the largest range reported, ``m_hops`` the correlator
length M (receivers without one ignore it). Unknown ``extra`` keys raise a ConfigError.

and names its options::

    Cls.option_names() -> OptionNames

(:class:`~hil.estimation.option_types.OptionNames`: its own, and GCAS's for a receiver built
on GCAS), which is all :func:`check_receiver_options` asks of it.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

from hil.errors import ConfigError
from hil.estimation.base import Receiver
from hil.estimation.option_types import OptionNames, check_option_types
from hil.signals.schedule import HopSchedule

RECEIVERS: dict[str, str] = {
    "gcas": "hil.estimation.gcas:GcasReceiver",
    "gcas-mti": "hil.estimation.clutter:ClutterCancelledGcas",
    "jifs": "hil.estimation.jifs:JifsReceiver",
    "stft": "hil.estimation.stft:StftReceiver",
    "mfbank": "hil.estimation.mfbank:MatchedFilterBank",
    "fmcw": "hil.estimation.fmcw:FmcwReceiver",
    "gcas-bg": "hil.estimation.background:BackgroundGcas",
    "gcas-still": "hil.estimation.still_water:StillWaterGcas",
}


def receiver_class(name: str) -> Any:
    """The class registered as ``name`` (imported on first use)."""
    try:
        target = RECEIVERS[name]
    except KeyError:
        raise ConfigError("receiver", name, f"one of {', '.join(RECEIVERS)}") from None
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name == module_name:
            raise ConfigError(
                "receiver", name, "an implemented receiver", f"{module_name} is not available"
            ) from None
        raise
    return getattr(module, attr)


def check_receiver_options(name: str, options: Mapping[str, Any]) -> None:
    """Refuse an option the receiver ``name`` does not have, or of the wrong type, before
    anything is built (an experiment file's, a sweep's): the first one, as
    ``receiver.options.KEY``. Options ``track_*`` are the tracker's, not the receiver's."""
    from hil.estimation._baseline_common import reject_unknown
    from hil.estimation.tracking import TRACK_OPTION_PREFIX

    cls = receiver_class(name)
    own = {k: v for k, v in options.items() if not k.startswith(TRACK_OPTION_PREFIX)}
    names: OptionNames = cls.option_names()
    check_option_types(cls, own, name, "receiver.options.")
    handed = {k: v for k, v in own.items() if k in names.gcas and k not in names.own}
    if handed:
        from hil.estimation.gcas import GcasReceiver

        check_option_types(GcasReceiver, handed, name, "receiver.options.")
    reject_unknown(own, names.all, name)
    if "background" in names.own and "background" in own:
        from hil.estimation.background import check_background_path

        check_background_path(own["background"])


def make_receiver(
    name: str,
    schedule: HopSchedule,
    fs_hz: float,
    *,
    sound_speed_mps: float,
    max_speed_mps: float,
    max_range_m: float,
    m_hops: int,
    **extra: Any,
) -> Receiver:
    """Build the receiver ``name`` with the common options and receiver-specific ``extra``."""
    cls = receiver_class(name)
    check_option_types(cls, extra, name, "receiver.options.")
    receiver: Receiver = cls.from_options(
        schedule,
        fs_hz,
        sound_speed_mps=sound_speed_mps,
        max_speed_mps=max_speed_mps,
        max_range_m=max_range_m,
        m_hops=m_hops,
        **extra,
    )
    return receiver
