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
The per-estimate work is a few NumPy operations over all live tracks at once (prediction,
gate and distance are vectorised over tracks).

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
        self.reset()

    def reset(self) -> None:
        """Forget every track; the next confirmed track gets id 0."""
        # One entry per live track. State (range m, closing speed m/s) at t_ref and its
        # covariance, kept as its three distinct entries (prr m², prv m²/s, pvv m²/s²).
        self._r = np.zeros(0)
        self._v = np.zeros(0)
        self._prr = np.zeros(0)
        self._prv = np.zeros(0)
        self._pvv = np.zeros(0)
        self._t_ref = np.zeros(0)  # bounce instant of the last update, s
        self._t_last = np.zeros(0)  # receive time of the last update, s
        self._t_first = np.zeros(0)  # receive time of the first estimate, s
        self._hop_last = np.zeros(0, dtype=np.int64)
        self._hop_first = np.zeros(0, dtype=np.int64)
        self._hits = np.zeros(0, dtype=np.int64)
        self._id = np.zeros(0, dtype=np.int64)  # NO_TRACK while tentative
        self.next_id = 0

    _COLUMNS = ("_r", "_v", "_prr", "_prv", "_pvv", "_t_ref", "_t_last", "_t_first",
                "_hop_last", "_hop_first", "_hits", "_id")  # fmt: skip

    @property
    def n_tracks(self) -> int:
        """Live tracks (tentative and confirmed)."""
        return int(self._id.size)

    @property
    def confirmed_ids(self) -> list[int]:
        """Ids of the live confirmed tracks, ascending."""
        return sorted(int(i) for i in self._id[self._id >= 0])

    def update(self, estimates: Iterable[Estimate]) -> list[Estimate]:
        """Associate ``estimates`` (in emission order) and return them with ``track_id``."""
        return [_with_track(e, self._one(e)) for e in estimates]

    # ------------------------------------------------------------------ one estimate
    def _one(self, e: Estimate) -> int:
        """Associate one estimate; its track id."""
        t_rx = float(e.t_s)
        t_b = 0.5 * (t_rx + float(e.t_tx_s)) if math.isfinite(e.t_tx_s) else t_rx
        if not (math.isfinite(t_rx) and math.isfinite(e.range_m) and math.isfinite(e.speed_mps)):
            return NO_TRACK
        self._prune(t_rx)
        s = self.settings
        var_r = self._sigma(e.crlb_range_m, s.min_range_sigma_m, s.default_range_sigma_m) ** 2
        var_v = self._sigma(e.crlb_speed_mps, s.min_speed_sigma_mps, s.default_speed_sigma_mps) ** 2
        hop = int(e.hop_index)
        if self._id.size:
            # Every track predicted to the bounce instant (vectorised over tracks).
            dt = t_b - self._t_ref
            a = np.abs(dt)  # a late estimate widens the gate as an early one does
            q = s.accel_mps2**2
            r_pred = self._r - self._v * dt
            prr = self._prr - 2.0 * dt * self._prv + dt * dt * self._pvv + q * a**4 / 4.0
            prv = self._prv - dt * self._pvv - q * a**3 / 2.0
            pvv = self._pvv + q * a * a
            y_r, y_v = e.range_m - r_pred, e.speed_mps - self._v
            s_rr, s_vv = prr + var_r, pvv + var_v
            det = s_rr * s_vv - prv * prv
            d2 = (s_vv * y_r * y_r - 2.0 * prv * y_r * y_v + s_rr * y_v * y_v) / det
            tentative = self._id < 0
            eligible = (
                (d2 <= s.gate_sigmas**2)
                & (self._hop_last < hop)
                & (~tentative | (hop - self._hop_first < s.confirm_hops))
            )
            for group in (eligible & ~tentative, eligible & tentative):
                if group.any():
                    k = int(np.argmin(np.where(group, d2, np.inf)))
                    self._kalman_update(
                        k, float(y_r[k]), float(y_v[k]), float(r_pred[k]),
                        (float(prr[k]), float(prv[k]), float(pvv[k])), var_r, var_v,
                    )  # fmt: skip
                    self._t_ref[k], self._t_last[k], self._hop_last[k] = t_b, t_rx, hop
                    self._hits[k] += 1
                    return self._confirm(k)
        self._birth(e.range_m, e.speed_mps, var_r, var_v, t_b, t_rx, hop)
        return self._confirm(self.n_tracks - 1)

    def _kalman_update(
        self,
        k: int,
        y_r: float,
        y_v: float,
        r_pred: float,
        p: tuple[float, float, float],
        var_r: float,
        var_v: float,
    ) -> None:
        """Kalman step of track ``k`` from its prediction (range ``r_pred``, covariance
        ``p`` = (prr, prv, pvv)) with innovation ``(y_r, y_v)``."""
        prr, prv, pvv = p
        s_rr, s_vv = prr + var_r, pvv + var_v
        det = s_rr * s_vv - prv * prv
        # Gain K = P S⁻¹ (2×2, S⁻¹ = [[s_vv, −prv], [−prv, s_rr]] / det).
        k_rr = (prr * s_vv - prv * prv) / det
        k_rv = (prv * s_rr - prr * prv) / det
        k_vr = (prv * s_vv - pvv * prv) / det
        k_vv = (pvv * s_rr - prv * prv) / det
        self._r[k] = r_pred + k_rr * y_r + k_rv * y_v
        self._v[k] = self._v[k] + k_vr * y_r + k_vv * y_v
        # P = (I − K) P.
        self._prr[k] = (1.0 - k_rr) * prr - k_rv * prv
        self._prv[k] = (1.0 - k_rr) * prv - k_rv * pvv
        self._pvv[k] = -k_vr * prv + (1.0 - k_vv) * pvv

    def _confirm(self, k: int) -> int:
        """Apply the birth rule to track ``k``; its id."""
        if self._id[k] < 0 and self._hits[k] >= self.settings.confirm_hits:
            self._id[k] = self.next_id
            self.next_id += 1
        return int(self._id[k])

    @staticmethod
    def _sigma(bound: float, floor: float, default: float) -> float:
        return max(float(bound), floor) if math.isfinite(bound) else default

    def _birth(
        self, r: float, v: float, var_r: float, var_v: float, t_b: float, t_rx: float, hop: int
    ) -> None:
        """A tentative track at the estimate, with the estimate's own noise."""
        row = (r, v, var_r, 0.0, var_v, t_b, t_rx, t_rx, hop, hop, 1, NO_TRACK)
        for name, value in zip(self._COLUMNS, row, strict=True):
            setattr(self, name, np.append(getattr(self, name), value))

    def _prune(self, t_rx: float) -> None:
        """Delete the tracks the death rules end by receive time ``t_rx``."""
        s = self.settings
        dead = np.where(
            self._id >= 0,
            t_rx - self._t_last > (s.max_missed_hops + 1.5) * self.hop_s,
            t_rx - self._t_first > (s.confirm_hops - 0.5) * self.hop_s,
        )
        if dead.any():
            keep = ~dead
            for name in self._COLUMNS:
                setattr(self, name, getattr(self, name)[keep])


def _with_track(e: Estimate, track_id: int) -> Estimate:
    """``e`` with ``track_id`` (``e`` itself when it has it already)."""
    if e.track_id == track_id:
        return e
    return dataclasses.replace(e, track_id=track_id)


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
