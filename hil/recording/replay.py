"""Run a receiver over a recording through the same path as live.

:class:`ReceiverFeed` is that path: it turns raw sample blocks with board sample indices into
receiver input (one channel, float64, scaled) and tells the receiver about missing samples
through ``gap_before``. A live loop feeds every received block to a ``ReceiverFeed`` (and the
same block to :meth:`hil.recording.RunWriter.append_samples`); :func:`replay` feeds the
recorded blocks to a fresh one. Receivers are chunk-invariant, so replay blocks need not match
the live ones; the gaps are the same because both come from the board sample indices.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import astuple
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation.base import Estimate, Receiver
from hil.estimation.registry import RECEIVERS, make_receiver
from hil.recording.reader import RunRecording
from hil.recording.records import COMMON_SETTINGS, ReceiverSetup
from hil.signals.schedule import HopSchedule

_COMMON = ("sound_speed_mps", "max_speed_mps", "max_range_m", "m_hops")

REPLAY_BLOCK_FRAMES = 65536
"""Frames per block fed to the receiver on replay (bounded memory for long runs)."""


class ReceiverFeed:
    """Feeds raw sample blocks indexed by board sample to a receiver.

    ``origin`` is the board sample index that is the receiver's sample 0 (the schedule's
    t = 0); samples before it are dropped, samples fed twice are refused. Column ``channel``
    of each block, converted to float64 and multiplied by ``scale``, is the receiver's input.
    """

    def __init__(self, receiver: Receiver, *, origin: int, channel: int = 0, scale: float = 1.0):
        self.receiver = receiver
        self.origin = int(origin)
        self.channel = int(channel)
        self.scale = float(scale)
        self._next = self.origin

    @property
    def next_index(self) -> int:
        """Board index of the next sample the receiver expects."""
        return self._next

    @property
    def next_useful_index(self) -> int:
        """Board index the stream must reach before the receiver can emit its next estimate
        (receivers with a ``next_decision_index``, such as the two-stage GCAS); otherwise
        :attr:`next_index`. A live loop that waits for it calls the receiver less often and
        gets every estimate as early (see :attr:`GcasReceiver.next_decision_index
        <hil.estimation.gcas.GcasReceiver.next_decision_index>`)."""
        hint = getattr(self.receiver, "next_decision_index", None)
        if hint is None:
            return self._next
        return max(self._next, self.origin + int(hint))

    def wait_index(self, max_block: int) -> int:
        """Board index a live loop waits for before it feeds again: the receiver's next
        decision (:attr:`next_useful_index`) when it comes within ``max_block`` samples of
        :attr:`next_index`, else ``max_block`` samples on. No estimate can come out before
        the decision index, and waiting past it only makes the estimate later; the cap keeps
        a receiver without decisions (or far from one) fed in bounded blocks.

        >>> class Deciding:  # decides at its sample 700 (board index 1700)
        ...     next_decision_index = 700
        >>> feed = ReceiverFeed(Deciding(), origin=1000)  # type: ignore[arg-type]
        >>> feed.wait_index(1920), feed.wait_index(500)
        (1700, 1500)
        """
        if max_block < 1:
            raise ConfigError("max_block", max_block, ">= 1 sample", "wait at least one sample")
        cap = self._next + int(max_block)
        useful = self.next_useful_index
        return useful if self._next < useful < cap else cap

    def feed(self, first_index: int, block: NDArray[Any]) -> list[Estimate]:
        """Process ``block`` (shape ``(n, n_channels)``) received from board sample
        ``first_index``; the samples since the previous block that never arrived go to the
        receiver as ``gap_before``."""
        if first_index < self.origin:
            # Samples before the receiver's sample 0 (captured while the loopback latency was
            # measured) are not the receiver's input: drop them, as live does.
            skip = min(block.shape[0], self.origin - int(first_index))
            block = block[skip:]
            first_index = int(first_index) + skip
            if block.shape[0] == 0:
                return []
        gap = int(first_index) - self._next
        if gap < 0:
            raise ConfigError(
                "first_index",
                int(first_index),
                f">= {self._next} (after the samples already fed and the origin {self.origin})",
            )
        if block.ndim != 2 or not 0 <= self.channel < block.shape[1]:
            raise ConfigError(
                "receiver.channel", self.channel, f"a column of blocks shaped {block.shape}"
            )
        x = block[:, self.channel].astype(np.float64) * self.scale
        self._next = int(first_index) + block.shape[0]
        return self.receiver.process(x, gap_before=gap)

    def finish(self) -> list[Estimate]:
        """End of input: the estimates the receiver still holds."""
        return self.receiver.flush()


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
    setup: ReceiverSetup, schedule: HopSchedule, fs_hz: float, **callbacks: Any
) -> Receiver:
    """The receiver ``setup`` describes (live and on replay): ``setup.settings`` must hold
    the registry's common options and may hold the receiver's own; ``callbacks`` are options
    a recording cannot hold (GCAS's ``on_map``)."""
    s = dict(setup.settings)
    missing = [k for k in _COMMON if k not in s]
    if missing:
        raise ConfigError("receiver.settings", sorted(s), f"settings including {missing}")
    common = {k: s.pop(k) for k in _COMMON}
    return make_receiver(setup.name, schedule, fs_hz, **common, **s, **callbacks)


def replay(
    recording: RunRecording | str | Path,
    receiver_name: str | None = None,
    *,
    channel: int | None = None,
    block_frames: int = REPLAY_BLOCK_FRAMES,
    **overrides: Any,
) -> list[Estimate]:
    """Run a receiver over the recorded samples and return its estimates.

    Default receiver and settings: those of the live run (see :func:`replay_setup`); with
    them the result equals the live estimates exactly. ``overrides`` are receiver settings
    (``m_hops=12``, ``n_doppler=64``, ...).
    """
    if not isinstance(recording, RunRecording):
        with RunRecording.open(recording) as rec:
            return replay(
                rec, receiver_name, channel=channel, block_frames=block_frames, **overrides
            )
    setup = replay_setup(recording, receiver_name, channel, **overrides)
    feed = ReceiverFeed(
        build_receiver(setup, recording.schedule(), recording.fs_hz),
        origin=recording.origin_sample,
        channel=setup.channel,
        scale=setup.scale,
    )
    out: list[Estimate] = []
    for block in recording.iter_blocks(block_frames):
        out.extend(feed.feed(block.first_index, block.data))
    out.extend(feed.finish())
    return out


def _same(a: Estimate, b: Estimate) -> bool:
    """Field-by-field equality where NaN equals NaN (a NaN SNR is still the same result)."""
    for x, y in zip(astuple(a), astuple(b), strict=True):
        both_nan = isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y)
        if not (both_nan or x == y):
            return False
    return True


Agreement = Literal["equal", "prefix", "differ"]


def compare_estimates(
    live: Sequence[Estimate], replayed: Sequence[Estimate]
) -> tuple[Agreement, str]:
    """How replayed estimates agree with the recorded live ones, and that in words.

    ``"equal"``: the same list. ``"prefix"``: fewer recorded than replayed (or the other way
    round) but equal as far as both go; a recording whose writer was killed holds the live
    estimates up to its last flush only. ``"differ"``: some pair differs (the first named).
    """
    for i, (a, b) in enumerate(zip(live, replayed, strict=False)):
        if not _same(a, b):
            return "differ", f"estimate {i} differs: recorded {a}, replayed {b}"
    if len(live) != len(replayed):
        return "prefix", (
            f"{len(live)} recorded and {len(replayed)} replayed estimates, equal as far as both go"
        )
    return "equal", f"all {len(live)} replayed estimates equal the recorded live ones"
