"""Figures without pyplot: library plots never touch matplotlib's global state.

Every plotting function of the package builds a :class:`matplotlib.figure.Figure` directly
(no ``pyplot``, no ``matplotlib.use``), returns it and, when asked, saves it. Saving a PNG
needs no backend (the figure renders itself through Agg), so this works headless in a
script, in a test and in a notebook, where the returned figure is shown inline and the
user's chosen backend is left alone.

>>> fig, ax = new_figure(figsize=(2, 1))
>>> _ = ax.plot([0, 1], [0, 1])
>>> type(fig).__name__, fig.get_size_inches().tolist()
('Figure', [2.0, 1.0])
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def new_figure(nrows: int = 1, ncols: int = 1, **kwargs: Any) -> tuple[Figure, Any]:
    """A new figure and its axes, as ``pyplot.subplots`` would give them.

    ``figsize`` (inches) and ``dpi`` go to the figure, the rest (``sharex``, ...) to
    :meth:`~matplotlib.figure.Figure.subplots`.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=kwargs.pop("figsize", None), dpi=kwargs.pop("dpi", None))
    return fig, fig.subplots(nrows, ncols, **kwargs)


def save_figure(fig: Figure, path: Path, **kwargs: Any) -> Path:
    """Save ``fig`` to ``path`` (format from the suffix) and return the path."""
    fig.savefig(path, **kwargs)
    return path
