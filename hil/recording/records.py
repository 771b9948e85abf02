"""The records a run recording holds, as the writer takes them and the reader returns them."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError


@dataclass(frozen=True)
class RunEvent:
    """Something that happened on the stream at board sample ``sample_index``.

    ``kind`` is one of :data:`~hil.recording.schema.EVENT_KINDS`; ``length`` is the number of
    samples the event covers (a gap's missing samples; 0 for instantaneous events).
    """

    kind: str
    sample_index: int
    length: int = 0
    text: str = ""

    def __post_init__(self) -> None:
        # Imported here: the schema imports h5py, which building a receiver does not need.
        from hil.recording.schema import EVENT_KINDS

        if self.kind not in EVENT_KINDS:
            raise ConfigError("event.kind", self.kind, f"one of {', '.join(EVENT_KINDS)}")
        if self.length < 0:
            raise ConfigError("event.length", self.length, ">= 0 samples")


@dataclass(frozen=True)
class StageTelemetry:
    """One stage status report.

    ``host_time_s`` is the host clock time the report describes (s; the GRBL driver dates a
    report by the status query it answers, see ``StageStatus.host_time``), ``sample_index``
    that time mapped to the board's sample clock, ``position_m`` and ``velocity_mps`` the carriage's
    position (m) and velocity (m/s) along the tow axis, ``state`` the controller's state as
    it reports it (GRBL: ``"Run"``, ``"Hold:0"``, ...), ``reply_s`` how long the report took to
    come back after its query (s; a late one is left out of a tank run's truth; 0 when not
    measured, and in recordings made before it was a column).
    """

    host_time_s: float
    sample_index: int
    position_m: float
    velocity_mps: float
    state: str
    reply_s: float = 0.0


@dataclass(frozen=True)
class SyncPairs:
    """Board sample index ↔ host time pairs (for :class:`hil.acquisition.SampleClockFit`).

    ``sample_index`` (int64) and ``host_time_s`` (float64, s) have shape ``(n,)``.
    """

    sample_index: NDArray[np.int64]
    host_time_s: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.sample_index.shape[0])


@dataclass(frozen=True)
class SampleBlock:
    """Contiguous received samples: ``data`` (shape ``(n, n_channels)``, dtype as captured)
    starting at board sample ``first_index``."""

    first_index: int
    data: NDArray[Any]

    @property
    def stop_index(self) -> int:
        """Board sample index one past the last sample of the block."""
        return self.first_index + int(self.data.shape[0])


COMMON_SETTINGS: dict[str, float | int] = {
    "max_speed_mps": 30.0,
    "max_range_m": 100.0,
    "m_hops": 10,
}
"""Defaults of the registry's common receiver options other than the sound speed (which
defaults to the schedule's); the same as ``hil estimate``'s."""


@dataclass(frozen=True)
class ReceiverSetup:
    """The receiver run live and how its input was formed.

    ``settings`` are the keyword arguments of :func:`hil.estimation.registry.make_receiver`
    (``sound_speed_mps``, ``max_speed_mps``, ``max_range_m``, ``m_hops`` and the receiver's
    own options), JSON-serialisable. The receiver's input is column ``channel`` of the raw
    samples, converted to float64 and multiplied by ``scale`` (e.g. ``2**-15`` for int16
    codes to full scale).
    """

    name: str
    settings: Mapping[str, Any] = field(default_factory=dict)
    channel: int = 0
    scale: float = 1.0

    def __post_init__(self) -> None:
        if self.channel < 0:
            raise ConfigError("receiver.channel", self.channel, ">= 0")
        if not (math.isfinite(self.scale) and self.scale != 0.0):
            raise ConfigError("receiver.scale", self.scale, "a finite, non-zero factor")
        for key, value in self.settings.items():
            try:
                json.dumps(value, allow_nan=False)
            except (TypeError, ValueError):
                hint = (
                    "give a finite number"
                    if isinstance(value, float)
                    else "callbacks such as on_map are not recorded: pass them to replay"
                )
                raise ConfigError(
                    f"receiver.settings.{key}",
                    value,
                    "a JSON value: a finite number, a string, a list or a table of them",
                    hint,
                ) from None

    def to_json(self) -> str:
        """The setup as one JSON object."""
        return json.dumps(
            {
                "name": self.name,
                "settings": dict(self.settings),
                "channel": self.channel,
                "scale": self.scale,
            }
        )

    @classmethod
    def from_json(cls, text: str) -> ReceiverSetup:
        """Inverse of :meth:`to_json`."""
        d = json.loads(text)
        return cls(str(d["name"]), dict(d["settings"]), int(d["channel"]), float(d["scale"]))


@dataclass(frozen=True)
class RunMetadata:
    """What a recording says about its run.

    ``fs_hz`` is the ADC sample rate (Hz); ``n_channels`` and ``sample_dtype`` the sample
    layout; ``origin_sample`` the board sample index that is the receiver's sample 0 (the
    schedule's t = 0); ``versions`` the software that wrote it; ``calibration_ids`` the
    calibrations in force; ``receiver`` the live receiver (None when none ran).
    """

    fs_hz: float
    n_channels: int
    sample_dtype: str
    origin_sample: int | None
    experiment_toml: str
    versions: dict[str, Any]
    calibration_ids: tuple[str, ...]
    receiver: ReceiverSetup | None
    created_utc: str
