"""Run a receiver over a recording through the same path as live.

That path is :class:`~hil.acquisition.feed.ReceiverFeed`: a live capture loop feeds every
received block to one (and the same block to :meth:`hil.recording.RunWriter.append_samples`);
:func:`replay` feeds the recorded blocks to a fresh one. Receivers are chunk-invariant, so
replay blocks need not match the live ones; the gaps are the same because both come from the
board sample indices.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from hil.acquisition.feed import ReceiverFeed
from hil.errors import ConfigError
from hil.estimation.base import CountsRefusals, Estimate, Receiver, SaysNotices
from hil.estimation.registry import RECEIVERS, make_receiver
from hil.estimation.tracking import (
    TrackedReceiver,
    Tracker,
    TrackerSettings,
    mean_hop_s,
    split_track_options,
)
from hil.recording.records import COMMON_SETTINGS, ReceiverSetup
from hil.signals.schedule import HopSchedule

if TYPE_CHECKING:
    from hil.recording.reader import RunRecording

#: The settings every receiver takes (:func:`~hil.estimation.registry.make_receiver`'s).
_COMMON = ("sound_speed_mps", *COMMON_SETTINGS)

REPLAY_BLOCK_FRAMES = 65536
"""Frames per block fed to the receiver on replay (bounded memory for long runs)."""


def replay_setup(
    recording: RunRecording,
    receiver_name: str | None = None,
    channel: int | None = None,
    **overrides: Any,
) -> ReceiverSetup:
    """The receiver setup a replay uses.

    Default: the live receiver with its recorded settings. ``overrides`` replace settings;
    another receiver keeps the live common settings (sound speed, speed span, range, M) but
    none of the live receiver's own options. Without a live receiver the common settings
    default to the schedule's sound speed and :data:`COMMON_SETTINGS`.
    """
    live = recording.metadata.receiver
    name = receiver_name if receiver_name is not None else (live.name if live else None)
    if name is None:
        raise ConfigError(
            "receiver",
            None,
            f"one of {', '.join(RECEIVERS)}",
            "the recording holds no live receiver: name the one to run",
        )
    settings: dict[str, Any] = {
        "sound_speed_mps": float(recording.schedule_document()["sound_speed_mps"]),
        **COMMON_SETTINGS,
    }
    if live is not None:
        if live.name == name:
            settings.update(live.settings)
        else:
            settings.update({k: v for k, v in live.settings.items() if k in settings})
    settings.update(overrides)
    base = live if live is not None else ReceiverSetup(name)
    ch = base.channel if channel is None else channel
    if not 0 <= ch < recording.metadata.n_channels:
        raise ConfigError("channel", ch, f"0..{recording.metadata.n_channels - 1}")
    return ReceiverSetup(name, settings, ch, base.scale)


def build_receiver(
    setup: ReceiverSetup, schedule: HopSchedule, fs_hz: float, **hooks: Any
) -> Receiver:
    """The receiver ``setup`` describes, the one way every caller builds one (live, replay,
    benchmarks): ``setup.settings`` must hold the registry's common options and may hold the
    receiver's own; ``hooks`` are options that are not settings and are not recorded (a
    callback such as GCAS's ``on_map``).

    The receiver's estimates leave through a :class:`~hil.estimation.tracking.Tracker` (each
    carries its ``track_id``); settings named ``track_*`` set the tracker
    (:meth:`~hil.estimation.tracking.TrackerSettings.from_options`), the others the receiver."""
    s, track_options = split_track_options(setup.settings)
    missing = [k for k in _COMMON if k not in s]
    if missing:
        raise ConfigError("receiver.settings", sorted(s), f"settings including {missing}")
    tracker = Tracker(mean_hop_s(schedule), TrackerSettings.from_options(track_options))
    common = {k: s.pop(k) for k in _COMMON}
    receiver = make_receiver(setup.name, schedule, fs_hz, **common, **s, **hooks)
    return TrackedReceiver(receiver, tracker)


def replay(
    recording: RunRecording | str | Path,
    receiver_name: str | None = None,
    *,
    channel: int | None = None,
    block_frames: int = REPLAY_BLOCK_FRAMES,
    hooks: dict[str, Any] | None = None,
    notices: list[Any] | None = None,
    refusals: dict[str, int] | None = None,
    **overrides: Any,
) -> list[Estimate]:
    """Run a receiver over the recorded samples and return its estimates.

    Default receiver and settings: those of the live run (see :func:`replay_setup`); with
    them the result equals the live estimates exactly. ``overrides`` are receiver settings
    (``m_hops=12``, ``n_doppler=64``, ...); ``hooks`` are callbacks given to the receiver
    (GCAS's ``on_map``: its time-codeword map, as live). ``notices``, when given, is extended
    with what the receiver said of what it refused (:class:`~hil.estimation.base.SaysNotices`:
    GCAS's echoes beyond its Doppler span, the first per side, and its clutter); ``refusals``,
    when given, is updated with what the receiver refused instead of reporting, by reason
    (:class:`~hil.estimation.base.CountsRefusals`; left empty for a receiver that does not
    count them).
    """
    from hil.recording.reader import RunRecording  # with h5py: only where a file is read

    if not isinstance(recording, RunRecording):
        with RunRecording.open(recording) as rec:
            return replay(
                rec,
                receiver_name,
                channel=channel,
                block_frames=block_frames,
                hooks=hooks,
                notices=notices,
                refusals=refusals,
                **overrides,
            )
    setup = replay_setup(recording, receiver_name, channel, **overrides)
    receiver = build_receiver(setup, recording.schedule(), recording.fs_hz, **(hooks or {}))
    feed = ReceiverFeed(
        receiver, origin=recording.origin_sample, channel=setup.channel, scale=setup.scale
    )
    out: list[Estimate] = []
    for block in recording.iter_blocks(block_frames):
        out.extend(feed.feed(block.first_index, block.data))
    out.extend(feed.finish())
    if notices is not None and isinstance(receiver, SaysNotices):
        notices.extend(receiver.notices())
    if refusals is not None and isinstance(receiver, CountsRefusals):
        refusals.update(receiver.refusals())
    return out


Agreement = Literal["equal", "prefix", "differ"]


def compare_estimates(
    live: Sequence[Estimate], replayed: Sequence[Estimate], *, track_ids: bool = True
) -> tuple[Agreement, str]:
    """How replayed estimates agree with the recorded live ones, and that in words.

    ``"equal"``: the same list. ``"prefix"``: fewer recorded than replayed (or the other way
    round) but equal as far as both go; a recording whose writer was killed holds the live
    estimates up to its last flush only. ``"differ"``: some pair differs (the first named).
    ``track_ids=False`` compares without the track ids (a recording made before they were
    kept, :attr:`~hil.recording.RunRecording.has_track_ids`).
    """
    if not track_ids:
        replayed = [replace(e, track_id=live[i].track_id) if i < len(live) else e
                    for i, e in enumerate(replayed)]  # fmt: skip
    for i, (a, b) in enumerate(zip(live, replayed, strict=False)):
        if a != b:  # NaN-aware: Estimate.__eq__
            return "differ", f"estimate {i} differs: recorded {a}, replayed {b}"
    if len(live) != len(replayed):
        return "prefix", (
            f"{len(live)} recorded and {len(replayed)} replayed estimates, equal as far as both go"
        )
    return "equal", f"all {len(live)} replayed estimates equal the recorded live ones"
