"""GCAS on the tank's input less its empty-tank background (receiver ``"gcas-bg"``).

With a continuous transmission repeating every code period ``P`` (samples, an integer), a
still tank answers with the same ``P`` samples every period: the direct blast, the walls,
surface and bottom, the late tail, the volume reverberation. Recorded once with no target in
the water (or the target parked out of the beam) and averaged over periods, that is the
**background** ``b[k]``, ``k = n mod P`` on the receiver's sample index ``n`` (sample 0 = the
transmit start plus the loopback latency). Subtracting it

    y[n] = x[n] − b[n mod P]

leaves the target's echo and its images, and nothing of the target's own past: unlike the
one-period canceller of ``"gcas-mti"`` (:mod:`hil.estimation.clutter`), whose sign-flipped copy
of a moving echo one period back arrives *before* the echo of an opening target (so its first
arrival is the target a period ago), and which cancels a target at rest. Here an opening, a
closing and a resting target read the same.

GCAS detects on ``y`` (its peak readout, no refinement: the tank's images are not one echo),
and each detection is re-read by the first-arrival readout
(:class:`~hil.estimation.first_arrival.FirstArrivalReadout` without its own canceller) on the
same ``y``: the direct path's onset and Doppler. A detection whose onset the readout cannot
find is dropped, not reported at the images' centroid (:attr:`BackgroundGcas.unread_count`):
no estimate rather than a wrong range.

What the background does not remove: anything that changed since it was captured (a moved
transducer, a different water temperature, a different amplitude or waveform): the residue is
as loud as the change. The capture: :mod:`hil.experiments.calibration.background`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.estimation.first_arrival import RANGE_READOUTS, FirstArrivalReadout
from hil.estimation.option_types import check_option_types
from hil.signals.schedule import HopSchedule


def load_background(path: str | Path, period_samples: int) -> NDArray[np.float64]:
    """The background saved at ``path`` (``.npy``, one code period: shape ``(P,)``, input
    full-scale units, receiver sample index ``n`` at element ``n mod P``)."""
    p = Path(path)
    try:
        b = np.load(p, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ConfigError(
            "receiver.options.background",
            str(path),
            "a .npy file of one code period",
            f"it cannot be read ({exc}); capture one: hil docs tank-run, 'Empty-tank background'",
        ) from None
    b = np.asarray(b, dtype=np.float64)
    if b.shape != (period_samples,) or not np.all(np.isfinite(b)):
        raise ConfigError(
            "receiver.options.background",
            str(path),
            f"{period_samples} finite samples (one code period of this waveform and rate)",
            f"it holds shape {b.shape}: capture it again with this experiment's waveform",
        )
    return b


class BackgroundSubtractor:
    """``y[n] = x[n] − b[n mod P]`` on a stream (``n`` the absolute input index).

    >>> s = BackgroundSubtractor(np.array([1.0, 2.0, 3.0]))
    >>> s.process(np.array([1.0, 2.0, 3.0, 1.0]), first_index=0).tolist()
    [0.0, 0.0, 0.0, 0.0]
    >>> s.process(np.array([5.0]), first_index=5).tolist()
    [2.0]
    """

    def __init__(self, background: ArrayLike) -> None:
        self.background = np.asarray(background, dtype=np.float64).reshape(-1)
        if self.background.size < 1:
            raise ConfigError("background", "empty", "one code period of samples (>= 1)")

    def process(self, x: ArrayLike, first_index: int) -> NDArray[np.float64]:
        """``x`` (shape ``(n,)``, starting at absolute input index ``first_index``) less the
        background at the same phases."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        p = self.background.size
        phase = (int(first_index) + np.arange(x.size)) % p
        return np.asarray(x - self.background[phase], dtype=np.float64)


class BackgroundGcas:
    """GCAS behind a :class:`BackgroundSubtractor`, each detection re-read at its first
    arrival (see the module docstring). Options: ``background`` (path of the ``.npy``
    capture), ``range_readout`` (``"first-arrival"``, default, or ``"peak"``: GCAS's own),
    ``max_spread_s``, and GCAS's others; ``refine`` is False unless given."""

    name = "gcas-bg"

    def __init__(
        self,
        inner: Any,
        subtractor: BackgroundSubtractor,
        readout: FirstArrivalReadout | None,
    ) -> None:
        self.inner = inner
        self.subtractor = subtractor
        self.first_arrival = readout
        self.fs_hz = float(inner.fs_hz)
        self.sound_speed_mps = float(inner.sound_speed_mps)
        self.max_range_m = float(inner.max_range_m)
        self._seen = 0
        #: Detections dropped because the first-arrival readout found no onset.
        self.unread_count = 0

    @classmethod
    def from_options(
        cls,
        schedule: HopSchedule,
        fs_hz: float,
        *,
        sound_speed_mps: float,
        max_speed_mps: float,
        max_range_m: float,
        m_hops: int,
        background: str | None = None,
        range_readout: str = "first-arrival",
        max_spread_s: float | None = None,
        **extra: Any,
    ) -> BackgroundGcas:
        """The registry's common constructor (:mod:`hil.estimation.registry`)."""
        from hil.estimation.gcas import GcasReceiver

        check_option_types(GcasReceiver, extra, "gcas-bg")
        period = schedule.period_samples(fs_hz)
        if period is None:
            raise ConfigError(
                "receiver",
                "gcas-bg",
                "a code period of a whole number of samples",
                f"period {schedule.period_s} s × {fs_hz} Hz = "
                f"{schedule.period_s * fs_hz:.4f} samples: the background repeats every "
                "period; use gcas",
            )
        if background is None:
            raise ConfigError(
                "receiver.options.background",
                None,
                "the path of an empty-tank background (.npy)",
                "capture one first: hil docs tank-run, 'Empty-tank background'",
            )
        if range_readout not in RANGE_READOUTS:
            raise ConfigError("range_readout", range_readout, f"one of {', '.join(RANGE_READOUTS)}")
        subtractor = BackgroundSubtractor(load_background(background, period))
        inner = GcasReceiver.from_options(
            schedule,
            fs_hz,
            sound_speed_mps=sound_speed_mps,
            max_speed_mps=max_speed_mps,
            max_range_m=max_range_m,
            m_hops=m_hops,
            **{"refine": False, **extra, "range_readout": "peak"},
        )
        readout = (
            FirstArrivalReadout(
                schedule,
                float(fs_hz),
                int(m_hops),
                float(sound_speed_mps),
                max_spread_s,
                cancel_period=False,
            )
            if range_readout == "first-arrival"
            else None
        )
        return cls(inner, subtractor, readout)

    def process(self, block: ArrayLike, *, gap_before: int = 0) -> list[Estimate]:
        """Subtract, detect, re-read (shape ``(n,)`` real samples)."""
        x = np.asarray(block, dtype=np.float64).reshape(-1)
        out: list[Estimate] = []
        if gap_before:
            out += self._read(self.inner.flush())  # read before the history restarts
            self._seen += int(gap_before)
            if self.first_arrival is not None:
                self.first_arrival.reset(self._seen)
        y = self.subtractor.process(x, self._seen)
        if self.first_arrival is not None:
            self.first_arrival.push(y, self._seen)
        self._seen += x.size
        out += self._read(self.inner.process(y, gap_before=gap_before))
        return out

    def flush(self) -> list[Estimate]:
        """GCAS's held estimates, re-read."""
        return self._read(self.inner.flush())

    def reset(self) -> None:
        """Forget all state; the next sample is sample 0 again."""
        self.inner.reset()
        self._seen = 0
        self.unread_count = 0
        if self.first_arrival is not None:
            self.first_arrival.reset(0)

    def _read(self, estimates: list[Estimate]) -> list[Estimate]:
        """Each estimate at its first arrival (dropped where none is found or it lies past
        the maximum range)."""
        if self.first_arrival is None:
            return estimates
        c = self.sound_speed_mps
        out: list[Estimate] = []
        for e in estimates:
            first = self.first_arrival.first_arrival(e.t_s, e.alpha, e.hop_index)
            if first is None:
                self.unread_count += 1
                continue
            range_m = c * (first.t_s - e.t_tx_s) / 2.0
            if not 0.0 <= range_m <= self.max_range_m:
                self.unread_count += 1
                continue
            alpha = first.alpha
            out.append(
                dataclasses.replace(
                    e,
                    t_s=first.t_s,
                    range_m=range_m,
                    speed_mps=c * (alpha - 1.0) / (alpha + 1.0),
                    alpha=alpha,
                )
            )
        return out

    @property
    def samples_seen(self) -> int:
        """Samples consumed so far (GCAS's count)."""
        return int(self.inner.samples_seen)

    @property
    def next_decision_index(self) -> int:
        """GCAS's next decision index (the subtraction adds no delay)."""
        return int(self.inner.next_decision_index)

    def __getattr__(self, name: str) -> Any:
        # Everything else (counts, maps, settings) is GCAS's.
        return getattr(self.inner, name)
