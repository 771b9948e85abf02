"""Per-track figures of a list of estimates: what each confirmed track held, and how far its
estimates were from the truth where the truth is known.

Used by ``hil estimate`` / ``hil replay`` (one line per track) and the tank run's
``summary.json`` (its ``tracks`` section). Estimates on no confirmed track (``track_id`` −1)
are counted apart.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.estimation.base import Estimate


def track_figures(
    estimates: Sequence[Estimate],
    true_range_m: NDArray[np.floating] | None = None,
    true_speed_mps: NDArray[np.floating] | None = None,
) -> dict[str, Any]:
    """Figures of every confirmed track of ``estimates``.

    ``true_range_m``, ``true_speed_mps``: the truth at each estimate (shape
    ``(n_estimates,)``, NaN where unknown), or None.

    Returns ``{"confirmed": number of tracks, "untracked_estimates": count of track_id −1,
    "per_track": [...]}``, one entry per track in id order with ``track_id``, ``estimates``,
    ``first_t_s`` / ``last_t_s`` (receive times, s), ``span_s``, ``first_hop`` /
    ``last_hop``, ``range_first_m`` / ``range_last_m``, ``speed_median_mps``, the median of
    its estimates' own Cramér–Rao bounds ``crlb_range_median_m`` / ``crlb_speed_median_mps``
    (None where no estimate carries one: a receiver without refinement); with a truth
    also ``estimates_with_truth``, ``range_rmse_m`` and ``speed_rmse_mps`` (over the track's
    estimates whose truth is known; None without any).

    >>> e = [Estimate(0.1 * k, 10.0 - k, 1.0, k, 1.0, 0.0, 1.0, 0.0, 0, "x", track_id=0)
    ...      for k in range(3)]
    >>> f = track_figures(e, np.array([10.0, 9.1, np.nan]), np.array([1.0, 1.0, 1.0]))
    >>> round(f["per_track"][0]["range_rmse_m"], 4), f["per_track"][0]["estimates_with_truth"]
    (0.0707, 2)
    """
    n = len(estimates)
    ids = np.array([e.track_id for e in estimates], dtype=np.int64)
    t = np.array([e.t_s for e in estimates], dtype=float)
    r = np.array([e.range_m for e in estimates], dtype=float)
    v = np.array([e.speed_mps for e in estimates], dtype=float)
    hop = np.array([e.hop_index for e in estimates], dtype=np.int64)
    crlb_r = np.array([e.crlb_range_m for e in estimates], dtype=float)
    crlb_v = np.array([e.crlb_speed_mps for e in estimates], dtype=float)
    has_truth = true_range_m is not None and true_speed_mps is not None
    err_r = r - np.asarray(true_range_m, dtype=float) if has_truth else np.full(n, np.nan)
    err_v = v - np.asarray(true_speed_mps, dtype=float) if has_truth else np.full(n, np.nan)
    per_track = []
    for k in np.unique(ids[ids >= 0]):
        on = ids == k
        entry: dict[str, Any] = {
            "track_id": int(k),
            "estimates": int(on.sum()),
            "first_t_s": float(t[on][0]),
            "last_t_s": float(t[on][-1]),
            "span_s": float(t[on][-1] - t[on][0]),
            "first_hop": int(hop[on][0]),
            "last_hop": int(hop[on][-1]),
            "range_first_m": float(r[on][0]),
            "range_last_m": float(r[on][-1]),
            "speed_median_mps": float(np.median(v[on])),
            "crlb_range_median_m": _median(crlb_r[on]),
            "crlb_speed_median_mps": _median(crlb_v[on]),
        }
        if has_truth:
            known = on & np.isfinite(err_r) & np.isfinite(err_v)
            entry["estimates_with_truth"] = int(known.sum())
            entry["range_rmse_m"] = _rmse(err_r[known])
            entry["speed_rmse_mps"] = _rmse(err_v[known])
        per_track.append(entry)
    return {
        "confirmed": len(per_track),
        "untracked_estimates": int(np.count_nonzero(ids < 0)),
        "per_track": per_track,
    }


def _rmse(x: NDArray[np.float64]) -> float | None:
    return float(np.sqrt(np.mean(x * x))) if x.size else None


def _median(x: NDArray[np.float64]) -> float | None:
    """Median of the finite values of ``x``; None where there is none."""
    finite = x[np.isfinite(x)]
    return float(np.median(finite)) if finite.size else None


def track_lines(figures: dict[str, Any]) -> list[str]:
    """``figures`` (:func:`track_figures`) as text: one line per track, then the untracked.

    >>> track_lines({"confirmed": 1, "untracked_estimates": 2, "per_track": [
    ...     {"track_id": 0, "estimates": 40, "first_t_s": 0.05, "last_t_s": 0.44,
    ...      "span_s": 0.39, "first_hop": 2, "last_hop": 41, "range_first_m": 39.9,
    ...      "range_last_m": 38.1, "speed_median_mps": 4.6}]})
    ['track 0: 40 estimates, t 0.050–0.440 s, range 39.900 → 38.100 m, speed 4.600 m/s \
(median)', '2 estimates on no confirmed track']
    """
    lines = []
    for tr in figures["per_track"]:
        line = (
            f"track {tr['track_id']}: {tr['estimates']} estimates, "
            f"t {tr['first_t_s']:.3f}–{tr['last_t_s']:.3f} s, "
            f"range {tr['range_first_m']:.3f} → {tr['range_last_m']:.3f} m, "
            f"speed {tr['speed_median_mps']:.3f} m/s (median)"
        )
        if tr.get("crlb_range_median_m") is not None:
            line += (
                f", CRLB {1e3 * tr['crlb_range_median_m']:.2f} mm / "
                f"{1e3 * tr['crlb_speed_median_mps']:.2f} mm/s (median)"
            )
        if tr.get("range_rmse_m") is not None:
            line += (
                f", RMSE {tr['range_rmse_m']:.4f} m / {tr['speed_rmse_mps']:.4f} m/s over "
                f"{tr['estimates_with_truth']} with truth"
            )
        lines.append(line)
    lines.append(f"{figures['untracked_estimates']} estimates on no confirmed track")
    return lines
