"""The empty-tank background: one code period of what the hydrophone hears with no target.

A lab measures a tank's own response the way it measures anything steady: transmit the run's
schedule with the target out of the water (or parked out of the beam, behind the transducer),
record, and average the recording period by period. The steady returns (direct blast, walls,
surface, bottom, late tail, volume reverberation) repeat exactly every code period and add up;
the noise averages down as ``1/√K`` over ``K`` periods. Receiver ``"gcas-bg"``
(:mod:`hil.estimation.background`) subtracts it from the run's input.

- :func:`average_periods`: the averaging, on any recording (``x`` by receiver sample index).
- :func:`background_from_recording`: the background of a tank run recorded with the target
  out (``run.h5``: its hydrophone channel, after the tail has settled, gaps left out).
- :func:`simulated_background`: the built-in simulated tank's capture (its world with the
  target taken out), aligned as the run's receiver input is.
- :func:`save_background`: the ``.npy`` file the receiver option ``background`` names.

The background belongs to one set-up: waveform, amplitude, sample rate, transducer and
hydrophone positions, water temperature. Capture it again after changing any of them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from hil.estimation.still_period import still_period
from hil.experiments.experiment import Experiment

#: Periods a capture averages (the noise falls by 1/√K: 12 dB at 16).
BACKGROUND_PERIODS = 16
#: Periods left out at the start of a capture: the late tail of the first transmission is
#: still building up (0.17 s T60 in the built-in tank, one code period of tank-audio).
SETTLE_PERIODS = 2


def average_periods(
    x: ArrayLike, period_samples: int, first_index: int = 0, sign: int = 1
) -> NDArray[np.float64]:
    """The mean period of ``x`` (shape ``(n,)``, full scale; its first sample is receiver
    index ``first_index``): shape ``(P,)``, element ``k`` the mean of ``σ^q x`` over the
    samples whose index is ``qP + k``, over the whole periods ``x`` holds. ``P`` and
    ``σ = sign`` are the still period and its sign
    (:func:`~hil.estimation.still_period.still_period`): the still water of the even periods,
    as :class:`~hil.estimation.background.BackgroundSubtractor` subtracts it.

    >>> average_periods([1.0, 2.0, 3.0, 3.0, 4.0, 5.0], 3).tolist()
    [2.0, 3.0, 4.0]
    >>> average_periods([9.0, 1.0, 2.0, 3.0, 3.0, 4.0, 5.0], 3, first_index=2).tolist()
    [2.0, 3.0, 4.0]
    >>> average_periods([-1.0, -2.0, 1.0, 2.0, -1.0, -2.0], 2, first_index=2, sign=-1).tolist()
    [1.0, 2.0]
    """
    x = np.asarray(x, dtype=np.float64).reshape(-1)
    p = int(period_samples)
    if p < 1:
        raise ConfigError("period_samples", period_samples, ">= 1 sample")
    skip = (-int(first_index)) % p  # to the first sample of phase 0
    k = (x.size - skip) // p
    if k < 1:
        raise ConfigError(
            "background capture",
            f"{x.size} samples",
            f"at least one whole code period ({p} samples) after phase 0",
            "record longer: BACKGROUND_PERIODS periods after the tail has settled",
        )
    rows = x[skip : skip + k * p].reshape(k, p)
    if sign < 0:
        q0 = (int(first_index) + skip) // p  # the absolute period of the first row
        flip = (q0 + np.arange(k)) % 2 == 1
        rows = np.where(flip[:, None], -rows, rows)
    return np.asarray(rows.mean(axis=0), dtype=np.float64)


def simulated_background(exp: Experiment, periods: int = BACKGROUND_PERIODS) -> NDArray[np.float64]:
    """The built-in simulated tank of ``exp`` recorded with the target taken out: ``periods``
    code periods after :data:`SETTLE_PERIODS`, averaged (:func:`average_periods`), on the
    receiver's sample index (world sample ``n`` is receiver sample ``n −`` the converter
    latency, as in the run). Shape ``(P,)``, full scale."""
    from hil.experiments.sim_tank import CONVERTER_DELAY_SAMPLES, build_tank_world

    fs = float(exp.waveform.fs_hz)
    code_period = exp.schedule.period_samples(fs)
    if code_period is None:
        raise ConfigError(
            "waveform",
            exp.preset,
            "a code period of a whole number of samples",
            "the background repeats every period; this waveform has none",
        )
    p, sign = still_period(exp.schedule, code_period)
    if periods < 1:
        raise ConfigError("periods", periods, ">= 1")

    def parked(t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return np.zeros(t.shape), np.zeros(t.shape)

    world = build_tank_world(exp, parked, with_target=False)
    world.origin_index = 0
    x = world.channel.read_components((SETTLE_PERIODS + periods) * p, clip=False)["input_fs"]
    lead = SETTLE_PERIODS * p
    return average_periods(x[lead:], p, first_index=lead - CONVERTER_DELAY_SAMPLES, sign=sign)


def background_from_recording(
    path: str | Path, settle_periods: int = SETTLE_PERIODS
) -> NDArray[np.float64]:
    """The background of the recording at ``path`` (a ``hil tank-run`` of the empty tank):
    its receiver channel (the live receiver's, else channel 0; int16 codes as full scale)
    from ``settle_periods`` code periods after the receiver's sample 0 on, averaged over the
    whole periods of its longest stretch without a gap (:func:`average_periods`). Shape
    ``(P,)``, on the receiver's sample index, as receiver ``gcas-bg`` subtracts it."""
    from hil.recording.reader import RunRecording

    with RunRecording.open(path) as rec:
        schedule = rec.schedule()
        fs = rec.fs_hz
        code_period = schedule.period_samples(fs)
        if code_period is None:
            raise ConfigError(
                "recording",
                str(path),
                "a waveform whose code period is a whole number of samples",
                "the background repeats every period; this recording's waveform has none",
            )
        p, sign = still_period(schedule, code_period)
        live = rec.metadata.receiver
        channel = live.channel if live is not None else 0
        scale = live.scale if live is not None else 2.0**-15
        origin = rec.origin_sample
        start = origin + int(settle_periods) * p
        stretches = list(rec.iter_blocks(max_frames=None, start=start))
        if not stretches:
            raise ConfigError(
                "recording",
                str(path),
                f"samples from {settle_periods} code periods after the transmit start on",
                "record the empty tank for longer (BACKGROUND_PERIODS periods and more)",
            )
        longest = max(stretches, key=lambda b: b.data.shape[0])
        x = np.asarray(longest.data[:, channel], dtype=np.float64) * scale
        return average_periods(x, p, first_index=int(longest.first_index) - origin, sign=sign)


def save_background(path: str | Path, background: ArrayLike) -> Path:
    """Write ``background`` (shape ``(P,)``) as the ``.npy`` file receiver ``gcas-bg``
    reads; the path written."""
    p = Path(path)
    np.save(p, np.asarray(background, dtype=np.float64), allow_pickle=False)
    return p if p.suffix == ".npy" else p.with_name(p.name + ".npy")
