"""The GCAS time–codeword map as a PNG (seed Fig 5.17 style), for `hil estimate --map` and
the tank run's report."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from matplotlib.figure import Figure

# Columns drawn at most: longer maps are thinned evenly (the PNG has fewer pixels anyway).
MAX_COLUMNS = 4000


def save_time_codeword_map(
    path: Path,
    times: Sequence[npt.ArrayLike],
    power: Sequence[npt.ArrayLike],
    truth: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
) -> None:
    """Save :func:`time_codeword_map_figure` to ``path`` (its folder created if needed)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    time_codeword_map_figure(times, power, truth).savefig(path)


def time_codeword_map_figure(
    times: Sequence[npt.ArrayLike],
    power: Sequence[npt.ArrayLike],
    truth: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
) -> Figure:
    """Codeword sums against receive time, in dB re their maximum (−30 … 0 dB).

    ``times``: chunks of receive times (s), shape ``(n_i,)``; ``power``: the matching chunks
    of codeword sums, shape ``(n_i, J)``, as the receiver's ``on_map`` callback gives them;
    ``truth``: the true hop boundaries, receive times (s) and codewords (shape ``(b,)``
    each), drawn as open circles.
    """
    from hil.figures import new_figure

    t = np.concatenate([np.asarray(c, dtype=float) for c in times])
    p = np.concatenate([np.asarray(c, dtype=float) for c in power], axis=0)
    stride = max(1, p.shape[0] // MAX_COLUMNS)
    t, p = t[::stride], p[::stride]
    db = 10 * np.log10(np.maximum(p / max(float(p.max()), 1e-300), 1e-6))
    fig, ax = new_figure(figsize=(10, 4.5), dpi=110)
    extent = (float(t[0]), float(t[-1]), -0.5, p.shape[1] - 0.5)
    im = ax.imshow(db.T, origin="lower", aspect="auto", extent=extent, vmin=-30, vmax=0)
    fig.colorbar(im, ax=ax, label="accumulated sum (dB re max)")
    if truth is not None:
        t_true, j_true = (np.asarray(a, dtype=float) for a in truth)
        inside = (t_true >= extent[0]) & (t_true <= extent[1])
        ax.plot(
            t_true[inside], j_true[inside], "o", mfc="none", mec="w", ms=4, mew=0.8,
            label="true boundaries (telemetry)",
        )  # fmt: skip
        ax.legend(loc="upper right", fontsize=7)
    ax.set_xlabel("receive time (s)")
    ax.set_ylabel("codeword j")
    ax.set_title("GCAS time–codeword map")
    fig.tight_layout()
    return fig
