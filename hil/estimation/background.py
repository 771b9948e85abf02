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
as loud as the change. The capture: :mod:`hil.experiments.calibration.background`. The
streaming and the re-reading are :class:`~hil.estimation.input_stage.StagedGcas`'s.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from hil.estimation.first_arrival import RANGE_READOUTS, FirstArrivalReadout
from hil.estimation.input_stage import StagedGcas, StageParts, StageSetting
from hil.estimation.still_period import checked_still_period, still_period


def check_background_path(path: Any) -> None:
    """Refuse a ``background`` option that is not a path (a number, a table)."""
    if not isinstance(path, str | Path):
        raise ConfigError(
            "receiver.options.background",
            path,
            "the path of an empty-tank background (.npy), a string",
            "write it in quotes; capture one: hil docs tank-run, 'Empty-tank background'",
        )


def load_background(path: str | Path, period_samples: int) -> NDArray[np.float64]:
    """The background saved at ``path`` (``.npy``, one still period: shape ``(P,)``, input
    full-scale units, receiver sample index ``n`` at element ``n mod P``,
    :class:`BackgroundSubtractor`)."""
    check_background_path(path)
    p = Path(path)
    field, allowed = "receiver.options.background", "a .npy file of one code period"
    capture = "capture one: hil docs tank-run, 'Empty-tank background'"
    npy_magic = np.lib.format.MAGIC_PREFIX  # the first bytes of every .npy file
    try:
        with open(p, "rb") as f:
            magic = f.read(len(npy_magic))
    except OSError as exc:
        raise ConfigError(
            field, str(path), allowed, f"it cannot be read ({exc}); {capture}"
        ) from None
    if magic != npy_magic:
        what = (
            "it is empty"
            if not magic
            else f"it is not a NumPy .npy file (it starts with {magic!r})"
        )
        raise ConfigError(field, str(path), allowed, f"{what}; {capture}")
    try:
        b = np.load(p, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:  # EOFError: a .npy cut short
        raise ConfigError(
            field, str(path), allowed, f"it cannot be read ({exc}); {capture}"
        ) from None
    b = np.asarray(b, dtype=np.float64)
    if b.shape != (period_samples,) or not np.all(np.isfinite(b)):
        raise ConfigError(
            field,
            str(path),
            f"{period_samples} finite samples (one code period of this waveform and rate)",
            f"it holds shape {b.shape}: capture it again with this experiment's waveform",
        )
    return b


class BackgroundSubtractor:
    """``y[n] = x[n] − σ^⌊n/P⌋ b[n mod P]`` on a stream (``n`` the absolute input index;
    ``P`` the still period and ``σ`` its sign, :func:`~hil.estimation.still_period.
    still_period`: ``b`` is the still water of the even periods, the odd ones hold ``σ b``).

    >>> s = BackgroundSubtractor(np.array([1.0, 2.0, 3.0]))
    >>> s.process(np.array([1.0, 2.0, 3.0, 1.0]), first_index=0).tolist()
    [0.0, 0.0, 0.0, 0.0]
    >>> s.process(np.array([5.0]), first_index=5).tolist()
    [2.0]
    >>> BackgroundSubtractor(np.array([1.0, 2.0]), sign=-1).process(
    ...     np.array([1.0, 2.0, -1.0, -2.0, 1.0]), first_index=0).tolist()
    [0.0, 0.0, 0.0, 0.0, 0.0]
    """

    def __init__(self, background: ArrayLike, sign: int = 1) -> None:
        #: One still period, shape ``(P,)``, input full-scale units.
        self.background = np.asarray(background, dtype=np.float64).reshape(-1)
        #: The still water's sign from one period to the next.
        _, self.sign = checked_still_period(max(self.background.size, 1), sign)
        if self.background.size < 1:
            raise ConfigError("background", "empty", "one code period of samples (>= 1)")

    def reset(self) -> None:
        """Nothing to forget: the output depends on the sample and its phase only."""

    def process(self, x: ArrayLike, first_index: int, gap_before: int = 0) -> NDArray[np.float64]:
        """``x`` (shape ``(n,)``, starting at absolute input index ``first_index``) less the
        background at the same phases. ``gap_before`` changes nothing: the subtraction
        keeps no history."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        p = self.background.size
        n = int(first_index) + np.arange(x.size)
        b = self.background[n % p]
        if self.sign < 0:
            b = np.where((n // p) % 2 == 1, -b, b)
        return np.asarray(x - b, dtype=np.float64)


class BackgroundGcas(StagedGcas):
    """GCAS behind a :class:`BackgroundSubtractor`, each detection re-read at its first
    arrival (see the module docstring). Options: ``background`` (path of the ``.npy``
    capture), ``range_readout`` (``"first-arrival"``, default, or ``"peak"``: GCAS's own),
    ``max_spread_s``, and GCAS's others; ``refine`` is False unless given."""

    name = "gcas-bg"
    STAGE_OPTIONS = ("background", "range_readout", "max_spread_s")
    period_reason = "the background repeats every period"

    def __init__(
        self,
        inner: Any,
        subtractor: BackgroundSubtractor,
        readout: FirstArrivalReadout | None,
    ) -> None:
        super().__init__(inner, subtractor, readout)
        #: The background subtraction in front of GCAS.
        self.subtractor = subtractor

    @classmethod
    def stage_from_options(cls, where: StageSetting, options: dict[str, Any]) -> StageParts:
        """The subtraction of the background at ``options["background"]`` and, unless
        ``range_readout = "peak"``, the first-arrival readout on its output (GCAS itself
        reads the peak)."""
        background = options.pop("background", None)
        range_readout = options.pop("range_readout", "first-arrival")
        max_spread_s = options.pop("max_spread_s", None)
        if background is None:
            raise ConfigError(
                "receiver.options.background",
                None,
                "the path of an empty-tank background (.npy)",
                "capture one first: hil docs tank-run, 'Empty-tank background'",
            )
        if range_readout not in RANGE_READOUTS:
            raise ConfigError("range_readout", range_readout, f"one of {', '.join(RANGE_READOUTS)}")
        period, sign = still_period(where.schedule, where.period_samples)
        subtractor = BackgroundSubtractor(load_background(background, period), sign)
        readout = (
            FirstArrivalReadout(
                where.schedule,
                where.fs_hz,
                where.m_hops,
                where.sound_speed_mps,
                max_spread_s,
                cancel_period=False,
            )
            if range_readout == "first-arrival"
            else None
        )
        return StageParts(subtractor, readout, {**options, "range_readout": "peak"})
