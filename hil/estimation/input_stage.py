"""GCAS behind an input stage: a transform of the input stream in front of the detector,
each detection optionally re-read at its first arrival on the transformed stream.

Two receivers are built this way, each with a stage that acts on whole code periods ``P``
(samples, an integer): ``"gcas-mti"`` (:mod:`hil.estimation.clutter`, ``y[n] = x[n] −
x[n − P]``) and ``"gcas-bg"`` (:mod:`hil.estimation.background`, ``y[n] = x[n] − b[n mod
P]``). The stage adds no delay: sample ``n`` of ``y`` is sample ``n`` of ``x``, so GCAS's
sample count, decision index and estimate times are those of the input.

A stage is anything with the two methods of :class:`InputStage`. A subclass of
:class:`StagedGcas` names its receiver and builds its stage from the receiver's options
(:meth:`StagedGcas.stage_from_options`); the rest (the period check, GCAS's construction,
streaming, gaps, the re-reading and every other attribute, which are GCAS's) is here.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar, Protocol, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.estimation.first_arrival import FirstArrivalReadout
from hil.estimation.option_types import OptionNames, check_option_types
from hil.signals.schedule import HopSchedule


class InputStage(Protocol):
    """A sample-aligned transform of the input stream (shape ``(n,)`` in and out)."""

    def process(
        self, x: NDArray[np.float64], *, first_index: int, gap_before: int
    ) -> NDArray[np.float64]:
        """The transformed ``x``, whose first sample is absolute input index
        ``first_index``; ``gap_before`` samples went missing just before it."""
        ...

    def reset(self) -> None:
        """Forget all history."""
        ...


@dataclasses.dataclass(frozen=True)
class StageSetting:
    """What a stage is built for: the transmit schedule, the input rate ``fs_hz`` (Hz), the
    code period ``period_samples`` (input samples), ``sound_speed_mps`` (m/s) and GCAS's
    correlator length ``m_hops``."""

    schedule: HopSchedule
    fs_hz: float
    period_samples: int
    sound_speed_mps: float
    m_hops: int


@dataclasses.dataclass(frozen=True)
class StageParts:
    """What a subclass builds from its options: the stage, the first-arrival readout that
    re-reads each detection on the stage's output (None: GCAS's own readout stands) and the
    options left for GCAS."""

    stage: InputStage
    readout: FirstArrivalReadout | None
    gcas_options: dict[str, Any]


class StagedGcas:
    """GCAS (``inner``) on the output of ``stage``; each estimate re-read at its first
    arrival by ``readout`` when one is given (see the module docstring).

    A re-read estimate keeps GCAS's transmit time and hop index and takes the readout's
    arrival time, range and Doppler. One whose onset the readout cannot find, or whose onset
    lies beyond ``max_range_m``, is dropped (:attr:`unread_count`): no estimate rather than
    one at the images' centroid.
    """

    #: The registry name of the receiver.
    name: ClassVar[str] = "gcas-staged"
    #: Why the stage needs a code period of a whole number of samples (its refusal's hint).
    period_reason: ClassVar[str] = "the input stage works on whole code periods"
    #: GCAS's ``refine`` unless the options set it: a staged input is not the one echo the
    #: coherent refinement fits (two copies of a moving echo, or the tank's images).
    refine_default: ClassVar[bool] = False
    #: The stage's own options (the others are GCAS's): checked by name before a run.
    STAGE_OPTIONS: ClassVar[tuple[str, ...]] = ()

    def __init__(
        self, inner: Any, stage: InputStage, readout: FirstArrivalReadout | None = None
    ) -> None:
        self.inner = inner
        self.stage = stage
        self.first_arrival = readout
        if readout is not None:
            # GCAS's estimates come out up to its decision lag after their samples arrived.
            readout.allow_lag(inner.decision_lag_samples)
        self.fs_hz = float(inner.fs_hz)
        self.sound_speed_mps = float(inner.sound_speed_mps)
        self.max_range_m = float(inner.max_range_m)
        self._seen = 0
        #: Detections dropped because the first-arrival readout found no onset in range.
        self.unread_count = 0

    # ------------------------------------------------------------------ construction
    @classmethod
    def option_names(cls) -> OptionNames:
        """The stage's options (``STAGE_OPTIONS``) and GCAS's, which it hands on."""
        from hil.estimation.gcas.options import OPTION_NAMES

        return OptionNames(frozenset(cls.STAGE_OPTIONS), OPTION_NAMES)

    @classmethod
    def stage_from_options(cls, where: StageSetting, options: dict[str, Any]) -> StageParts:
        """The stage of this receiver from its own ``options`` (the rest go to GCAS)."""
        raise NotImplementedError(f"{cls.__name__} names no input stage")

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
        **extra: Any,
    ) -> Self:
        """The registry's common constructor (:mod:`hil.estimation.registry`)."""
        from hil.estimation.gcas import GcasReceiver

        period = schedule.period_samples(fs_hz)
        if period is None:
            raise ConfigError(
                "receiver",
                cls.name,
                "a code period of a whole number of samples",
                f"period {schedule.period_s} s × {fs_hz} Hz = "
                f"{schedule.period_s * fs_hz:.4f} samples: {cls.period_reason}; use gcas",
            )
        where = StageSetting(schedule, float(fs_hz), period, float(sound_speed_mps), int(m_hops))
        parts = cls.stage_from_options(where, dict(extra))
        check_option_types(GcasReceiver, parts.gcas_options, cls.name, "receiver.options.")
        common: dict[str, Any] = {
            "sound_speed_mps": sound_speed_mps, "max_speed_mps": max_speed_mps,
            "max_range_m": max_range_m, "m_hops": m_hops,
        }  # fmt: skip
        options = {"refine": cls.refine_default, **parts.gcas_options}
        inner = GcasReceiver.from_options(schedule, fs_hz, **common, **options)
        return cls(inner, parts.stage, parts.readout)

    # ------------------------------------------------------------------ streaming
    def process(self, block: ArrayLike, *, gap_before: int = 0) -> list[Estimate]:
        """Transform, detect, re-read (shape ``(n,)`` real samples; ``gap_before`` samples
        went missing before the block)."""
        x = np.asarray(block, dtype=np.float64).reshape(-1)
        out: list[Estimate] = []
        if gap_before:
            out += self._read(self.inner.flush())  # read before the history restarts
            self._seen += int(gap_before)
            if self.first_arrival is not None:
                self.first_arrival.reset(self._seen)
        y = self.stage.process(x, first_index=self._seen, gap_before=int(gap_before))
        if self.first_arrival is not None:
            self.first_arrival.push(y, self._seen)
        self._seen += x.size
        out += self._read(self.inner.process(y, gap_before=gap_before))
        return out

    def flush(self) -> list[Estimate]:
        """GCAS's held estimates, re-read."""
        return self._read(self.inner.flush())

    def reset(self) -> None:
        """Forget all state (stage, GCAS, readout); the next sample is sample 0 again."""
        self.stage.reset()
        self.inner.reset()
        self._seen = 0
        self.unread_count = 0
        if self.first_arrival is not None:
            self.first_arrival.reset(0)

    def _read(self, estimates: list[Estimate]) -> list[Estimate]:
        """Each estimate at its first arrival (dropped where none is found or it lies past
        the maximum range); GCAS's own estimates without a readout."""
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
        """GCAS's next decision index (the stage adds no delay)."""
        return int(self.inner.next_decision_index)

    def __getattr__(self, name: str) -> Any:
        # Only reached for names this wrapper does not define: GCAS's own (counts, maps,
        # settings). ``inner`` itself is refused so a half-built object cannot recurse.
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)
