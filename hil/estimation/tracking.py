"""Tracks over range and speed: a track identity for every estimate a receiver emits.

A receiver reports echoes hop boundary by hop boundary; a :class:`Tracker` links the
estimates of one target into a **track** and stamps each with the track's id
(:attr:`~hil.estimation.base.Estimate.track_id`, ``-1`` while its track is unconfirmed).
The estimates themselves are not changed (the tracker smooths nothing the user reads).

Model
-----
Constant velocity in the bounce-instant time base: an estimate's range is the range at its
bounce instant ``t_b = (t_s + t_tx_s)/2`` (``t_s`` where ``t_tx_s`` is NaN) and its speed is
positive closing, so a target's range changes as ``dr/dt_b = −speed_mps``. A track's state is
``(range m, closing speed m/s)`` with a 2×2 covariance, propagated with white-noise
acceleration of standard deviation :attr:`TrackerSettings.accel_mps2` and updated with the
estimate's own ``(range_m, speed_mps)`` by a Kalman step. The estimate's measurement noise is
its Cramér–Rao bound (``crlb_range_m``, ``crlb_speed_mps``) raised to the floors
:attr:`~TrackerSettings.min_range_sigma_m`, :attr:`~TrackerSettings.min_speed_sigma_mps`
(a bound is reached only without bias or multipath); a receiver that gives no bound (NaN)
gets :attr:`~TrackerSettings.default_range_sigma_m` and
:attr:`~TrackerSettings.default_speed_sigma_mps`.

Rules (each estimate, in the order the receiver emits them)
-----------------------------------------------------------
1. **Association gate.** An estimate may join a track when its Mahalanobis distance to the
   track's prediction at its bounce instant (range predicted with the track's own speed, so
   range rate and speed must agree) is at most :attr:`~TrackerSettings.gate_sigmas`, and the
   track holds no estimate of this or a later hop boundary (``hop_index``): **one estimate
   per track per hop**. Confirmed tracks are tried first, then tentative ones; the nearest
   (smallest distance) wins. An estimate no track takes starts a new tentative track.
2. **Birth (M of N).** A tentative track is confirmed when it holds
   :attr:`~TrackerSettings.confirm_hits` (M) estimates within the first
   :attr:`~TrackerSettings.confirm_hops` (N) hop boundaries from its first one. It then gets
   the next id (0, 1, 2, … in order of confirmation); the confirming estimate and every later
   one of the track carry it. The estimates before confirmation keep ``-1``: the output is
   streamed, never rewritten.
3. **Death.** A confirmed track is deleted once it has missed more than
   :attr:`~TrackerSettings.max_missed_hops` (K) hop boundaries in a row: when an estimate
   arrives more than ``K + 1.5`` hop periods of receive time after the track's last one
   (the next boundary is due one period later; half a period of slack). A tentative track is
   deleted when one arrives more than ``N − ½`` hop periods after its first (it can no
   longer be confirmed). A deleted track's id is never
   reused; a target seen again starts a new track.
4. An estimate with a non-finite range, speed or time joins no track (``-1``).

Streaming: :meth:`Tracker.update` takes estimates in emission order and returns them
stamped; any split of a sequence into chunks gives the same result as one call on the whole.
The rules run in one compiled loop per batch (:mod:`hil.estimation.tracking_kernel`):
each estimate is compared with every live track at a cost of a few floating-point operations
per track (``benchmarks/bench_tracking.py``).

Why not Stone Soup: it would add a runtime dependency (with its own dependencies) for a
2-state linear filter and a gate that take a hundred lines here, and its trackers work scan
by scan, while a receiver's estimates of one hop boundary arrive spread over the range
window's receive times (one estimate at a time is what streams).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation.base import Estimate, Receiver

TRACK_OPTION_PREFIX = "track_"
"""Receiver settings starting with this prefix set the tracker (``track_confirm_hits=4``
sets :attr:`TrackerSettings.confirm_hits`); they are recorded with the receiver's."""

NO_TRACK = -1
"""``track_id`` of an estimate on no confirmed track."""


@dataclass(frozen=True)
class TrackerSettings:
    """The tracker's rules (see the module docstring for how each is used).

    Attributes
    ----------
    confirm_hits, confirm_hops:
        Birth rule M of N: a tentative track is confirmed by ``confirm_hits`` estimates
        within ``confirm_hops`` hop boundaries from its first (1 <= M <= N).
    max_missed_hops:
        Death rule: a confirmed track is deleted after more than this many hop periods
        without an estimate (>= 0).
    gate_sigmas:
        Association gate, Mahalanobis distance in standard deviations (> 0).
    accel_mps2:
        Standard deviation of the target's acceleration, m/s² (>= 0): how fast a followed
        target may brake or turn.
    min_range_sigma_m, min_speed_sigma_mps:
        Floors on an estimate's range (m) and speed (m/s) noise (> 0).
    default_range_sigma_m, default_speed_sigma_mps:
        An estimate's range (m) and speed (m/s) noise where its bound is NaN (> 0).
    """

    confirm_hits: int = 3
    confirm_hops: int = 5
    max_missed_hops: int = 5
    gate_sigmas: float = 4.0
    accel_mps2: float = 10.0
    min_range_sigma_m: float = 0.01
    min_speed_sigma_mps: float = 0.02
    default_range_sigma_m: float = 0.05
    default_speed_sigma_mps: float = 0.2

    def __post_init__(self) -> None:
        for name, low in (("confirm_hits", 1), ("confirm_hops", 1), ("max_missed_hops", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
                raise ConfigError(_option(name), value, f"an integer >= {low}", _example(name))
        if self.confirm_hits > self.confirm_hops:
            raise ConfigError(
                _option("confirm_hits"),
                self.confirm_hits,
                f"<= track_confirm_hops = {self.confirm_hops} (M of N)",
                "lower track_confirm_hits or raise track_confirm_hops",
            )
        for name in (
            "gate_sigmas",
            "accel_mps2",
            "min_range_sigma_m",
            "min_speed_sigma_mps",
            "default_range_sigma_m",
            "default_speed_sigma_mps",
        ):
            value = getattr(self, name)
            zero_ok = name == "accel_mps2"
            ok = (
                not isinstance(value, bool)
                and isinstance(value, int | float | np.integer | np.floating)
                and math.isfinite(float(value))
                and (float(value) >= 0.0 if zero_ok else float(value) > 0.0)
            )
            if not ok:
                allowed = "a finite number >= 0" if zero_ok else "a finite number > 0"
                raise ConfigError(_option(name), value, allowed, _example(name))

    @classmethod
    def from_options(cls, options: Mapping[str, Any]) -> TrackerSettings:
        """Settings from receiver options named ``track_<field>`` (others are ignored).

        >>> TrackerSettings.from_options({"track_confirm_hits": 2, "n_doppler": 64})
        ... # doctest: +ELLIPSIS
        TrackerSettings(confirm_hits=2, confirm_hops=5, ...)
        """
        fields = {f.name for f in dataclasses.fields(cls)}
        values: dict[str, Any] = {}
        for key, value in options.items():
            if not key.startswith(TRACK_OPTION_PREFIX):
                continue
            name = key[len(TRACK_OPTION_PREFIX) :]
            if name not in fields:
                raise ConfigError(
                    key,
                    value,
                    "a tracker setting: " + ", ".join(_option(f) for f in sorted(fields)),
                    "check the spelling",
                )
            values[name] = value
        return cls(**values)


def _option(name: str) -> str:
    return TRACK_OPTION_PREFIX + name


def _example(name: str) -> str:
    default = {f.name: f.default for f in dataclasses.fields(TrackerSettings)}[name]
    return f"e.g. {_option(name)}={default}"


def split_track_options(settings: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """``settings`` split into (receiver settings, tracker options ``track_*``)."""
    track = {k: v for k, v in settings.items() if k.startswith(TRACK_OPTION_PREFIX)}
    rest = {k: v for k, v in settings.items() if not k.startswith(TRACK_OPTION_PREFIX)}
    return rest, track


def _kernel() -> ModuleType:
    """:mod:`hil.estimation.tracking_kernel`, imported when a tracker is first made: it
    imports numba (0.3-0.4 s of CPU), which a reader of recordings (``hil.recording``
    imports this module) that never tracks must not pay."""
    from hil.estimation import tracking_kernel

    return tracking_kernel


class Tracker:
    """Constant-velocity tracks over (range, closing speed); streaming.

    Parameters
    ----------
    hop_s:
        Mean hop period of the transmit schedule, s (> 0): the unit of the birth and death
        rules' hop counts in receive time.
    settings:
        The rules (default :class:`TrackerSettings`).
    """

    def __init__(self, hop_s: float, settings: TrackerSettings | None = None) -> None:
        if not (isinstance(hop_s, int | float) and math.isfinite(hop_s) and hop_s > 0.0):
            raise ConfigError("hop_s", hop_s, "a finite hop period > 0 s", "pass the schedule's")
        self.hop_s = float(hop_s)
        self.settings = settings if settings is not None else TrackerSettings()
        self._warm_up()

    def _warm_up(self) -> None:
        """Run the compiled association once on a made-up estimate, then forget it: the first
        call in a process loads its machine code from numba's cache (or compiles it, seconds),
        which must not happen at a live run's first estimate."""
        self.reset()
        made_up = Estimate(
            t_s=0.1, range_m=1.0, speed_mps=0.0, hop_index=0, score=1.0, snr_db=0.0,
            alpha=1.0, t_tx_s=0.099, codeword=0, receiver="warm-up",
        )  # fmt: skip
        self.update([made_up])
        self.reset()

    def reset(self) -> None:
        """Forget every track; the next confirmed track gets id 0."""
        # Live tracks are the first _n rows (columns: hil.estimation.tracking_kernel).
        self._table = np.zeros((16, _kernel().N_COLUMNS))
        self._n = 0
        self.next_id = 0

    @property
    def n_tracks(self) -> int:
        """Live tracks (tentative and confirmed)."""
        return self._n

    @property
    def confirmed_ids(self) -> list[int]:
        """Ids of the live confirmed tracks, ascending."""
        ids = self._table[: self._n, _kernel().ID]
        return sorted(int(i) for i in ids[ids >= 0])

    def update(self, estimates: Iterable[Estimate]) -> list[Estimate]:
        """Associate ``estimates`` (in emission order) and return them with ``track_id``."""
        est = list(estimates)
        n = len(est)
        if n == 0:
            return []
        s = self.settings

        def column(name: str) -> NDArray[np.float64]:
            return np.fromiter((getattr(e, name) for e in est), dtype=np.float64, count=n)

        t_rx, t_tx = column("t_s"), column("t_tx_s")
        z_r, z_v = column("range_m"), column("speed_mps")
        hop = np.fromiter((e.hop_index for e in est), dtype=np.int64, count=n)
        valid = np.isfinite(t_rx) & np.isfinite(z_r) & np.isfinite(z_v)
        t_b = np.where(np.isfinite(t_tx), 0.5 * (t_rx + t_tx), t_rx)
        var_r = _variance(column("crlb_range_m"), s.min_range_sigma_m, s.default_range_sigma_m)
        var_v = _variance(
            column("crlb_speed_mps"), s.min_speed_sigma_mps, s.default_speed_sigma_mps
        )
        if self._table.shape[0] < self._n + n:  # each estimate starts at most one track
            grown = np.zeros((max(2 * self._table.shape[0], self._n + n), _kernel().N_COLUMNS))
            grown[: self._n] = self._table[: self._n]
            self._table = grown
        ids = np.empty(n, dtype=np.int64)
        self._n, self.next_id = _kernel().associate(
            self._table, self._n, self.next_id, t_rx, t_b, z_r, z_v, var_r, var_v, hop, valid,
            float(s.accel_mps2) ** 2, float(s.gate_sigmas) ** 2, int(s.confirm_hits),
            int(s.confirm_hops), (s.max_missed_hops + 1.5) * self.hop_s,
            (s.confirm_hops - 0.5) * self.hop_s, ids,
        )  # fmt: skip
        return [_with_track(e, int(k)) for e, k in zip(est, ids, strict=True)]


def _variance(bound: NDArray[np.float64], floor: float, default: float) -> NDArray[np.float64]:
    """Noise variances of estimates with Cramér–Rao bounds ``bound``: the bound raised to
    ``floor``, ``default`` where it is NaN; squared."""
    sigma = np.where(np.isfinite(bound), np.maximum(bound, floor), default)
    return np.asarray(sigma * sigma, dtype=np.float64)


def _with_track(e: Estimate, track_id: int) -> Estimate:
    """``e`` with ``track_id`` (``e`` itself when it has it already)."""
    if e.track_id == track_id:
        return e
    # Its fields with the track's id, to its class: dataclasses.replace's field checks cost
    # half as much again as the construction itself, once per estimate.
    return type(e)(**{**e.__dict__, "track_id": track_id})


def mean_hop_s(schedule: Any) -> float:
    """A schedule's mean hop period, s (its period over its hops)."""
    return float(schedule.period_s) / int(schedule.period_hops)


class TrackedReceiver:
    """A receiver whose estimates leave through a :class:`Tracker` (same protocol as
    :class:`~hil.estimation.base.Receiver`; other attributes are the inner receiver's)."""

    def __init__(self, receiver: Receiver, tracker: Tracker) -> None:
        self.inner = receiver
        self.tracker = tracker
        self.name = receiver.name
        self.fs_hz = receiver.fs_hz

    @property
    def samples_seen(self) -> int:
        """Samples consumed so far (the inner receiver's)."""
        return self.inner.samples_seen

    @property
    def next_decision_index(self) -> int:
        """The inner receiver's next decision index."""
        return self.inner.next_decision_index

    def process(self, block: NDArray[np.floating], *, gap_before: int = 0) -> list[Estimate]:
        """The inner receiver's estimates of ``block``, each with its track id."""
        return self.tracker.update(self.inner.process(block, gap_before=gap_before))

    def flush(self) -> list[Estimate]:
        """The inner receiver's held-back estimates, each with its track id."""
        return self.tracker.update(self.inner.flush())

    def reset(self) -> None:
        """Reset the receiver and forget every track."""
        self.inner.reset()
        self.tracker.reset()

    def __getattr__(self, name: str) -> Any:
        # Only reached for names this wrapper does not define: the inner receiver's own.
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)
