"""Does a recording follow a schedule's hop code? A check before estimating with it.

A receiver given the schedule of another seed or run estimates confidently and wrongly. The
check looks at the first hops of the input: per hop window (one hop long) the energy at each
of the schedule's tones, Doppler-shifted over a grid of speeds in ``±max_speed``; the
*score* of a (speed, code lag) hypothesis is the mean share of each hop's tone energy at the
tone the code names. A recording of this schedule (any delay, any speed in range) has one
hypothesis far above the rest; a recording of another code scores like random codes do.
The verdict compares the best score with the best scores of ``n_null`` random codes of the
same length and alphabet (seeded): matched when it beats all of them by ``margin``.

Applies to tone-hopping families with equal hops (``random-cyclic``, ``three-state``);
others return None.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from hil.signals.schedule import HopSchedule

TONE_HOP_FAMILIES = ("random-cyclic", "three-state")


@dataclass(frozen=True)
class ScheduleMatch:
    """Outcome of :func:`match_schedule`.

    ``score``: best mean share of hop energy at the code's tones (1 = all of it);
    ``null``: the best score of the random codes; ``chance``: 1 / number of tones;
    ``n_hops``: hop windows used.
    """

    score: float
    null: float
    chance: float
    n_hops: int
    matched: bool


def _best_scores(share: NDArray[np.float64], codes: NDArray[np.int64]) -> NDArray[np.float64]:
    """Best mean share over every cyclic lag, per code: ``share`` (V, n, K), codes (C, P)."""
    n_speeds, n, n_tones = share.shape
    period = codes.shape[1]
    # Fold the hop windows onto the code period: A[v, q, k] = sum of share over n = q mod P.
    folded = np.zeros((n_speeds, period, n_tones))
    np.add.at(folded.transpose(1, 0, 2), np.arange(n) % period, share.transpose(1, 0, 2))
    lags = (np.arange(period)[:, None] + np.arange(period)[None, :]) % period  # (L, p)
    # score[v, c, L] = sum_p folded[v, (p + L) % P, code_c[p]] / n
    gathered = folded[:, lags[None, :, :], codes[:, None, :]]  # (V, C, L, P)
    return np.asarray(gathered.sum(axis=-1).max(axis=(0, 2)) / n)


def match_schedule(
    x: NDArray[np.float64],
    fs_hz: float,
    schedule: HopSchedule,
    *,
    sound_speed_mps: float,
    max_speed_mps: float,
    max_hops: int = 400,
    n_speeds: int = 41,
    n_null: int = 19,
    margin: float = 1.05,
    seed: int = 0,
) -> ScheduleMatch | None:
    """Check that ``x`` (samples at ``fs_hz``, t = 0 at the schedule's start) follows
    ``schedule``; None when the family is not a tone-hopping one or ``x`` is under 2 periods.
    """
    if schedule.family not in TONE_HOP_FAMILIES:
        return None
    hop_s = float(schedule.duration_s[0])
    if not np.allclose(schedule.duration_s, hop_s):
        return None
    hop = int(round(hop_s * fs_hz))
    code = np.asarray(schedule.code, dtype=np.int64)
    period = code.shape[0]
    n = min(int(x.shape[0] * (1.0 - max_speed_mps / sound_speed_mps)) // hop - 1, max_hops)
    if hop < 8 or n < 2 * period:
        return None
    speeds = np.linspace(-max_speed_mps, max_speed_mps, n_speeds)
    tones = np.asarray(schedule.tones_hz, dtype=np.float64)
    window = np.hanning(hop)
    share = np.empty((n_speeds, n, tones.shape[0]))
    x = np.asarray(x, dtype=np.float64)
    for i, v in enumerate(speeds):
        # A target at speed v stretches time by alpha: transmit hop k arrives over
        # [k T / alpha, (k + 1) T / alpha) (plus the delay, absorbed by the code lag).
        alpha = 1.0 + 2.0 * v / sound_speed_mps
        starts = np.round(np.arange(n) * hop / alpha).astype(np.int64)
        starts = starts[starts + hop <= x.shape[0]]
        frames = x[starts[:, None] + np.arange(hop)[None, :]] * window
        power = np.abs(np.fft.rfft(frames, axis=1)) ** 2
        bins = np.clip(np.round(tones * alpha * hop / fs_hz).astype(np.int64), 0, hop // 2)
        energy = np.zeros((n, tones.shape[0]))
        energy[: starts.shape[0]] = power[:, bins]
        share[i] = energy / (energy.sum(axis=1, keepdims=True) + 1e-300)
    rng = np.random.default_rng(seed)
    nulls = rng.integers(0, tones.shape[0], size=(n_null, period))
    scores = _best_scores(share, np.vstack([code[None, :], nulls]))
    score, null = float(scores[0]), float(scores[1:].max())
    return ScheduleMatch(score, null, 1.0 / tones.shape[0], n, score > margin * null)
