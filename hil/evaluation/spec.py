"""A sweep: which trial, the grid of parameters, the repetitions and the root seed.

Grid points are the cartesian product of the grid's value lists in the order the grid lists
its parameters, the last parameter varying fastest (:func:`itertools.product`); point ``p``
holds repetitions ``rep = 0 … trials_per_point − 1`` with trial id
``p · trials_per_point + rep``.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from hil.evaluation.worker import TrialTask

#: Version of the manifest / results layout written by this module's users.
FORMAT = "hil-sweep/1"


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep (build one with :func:`hil.evaluation.sweep_file.sweep_from_dict`).

    ``trial`` is the name as written, ``target`` its import target (``module:function`` or
    ``/abs/file.py:function``); ``grid`` maps each swept parameter to its values, ``fixed``
    holds the parameters common to all points.

    >>> s = SweepSpec("demo", "t", "m:t", 2, 1, {"a": [1, 2], "b": ["x", "y", "z"]}, {"c": 0})
    >>> s.n_points, s.n_trials, s.point_values(4), s.point_params(4)
    (6, 12, {'a': 2, 'b': 'y'}, {'c': 0, 'a': 2, 'b': 'y'})
    """

    name: str
    trial: str
    target: str
    trials_per_point: int
    seed: int
    grid: dict[str, list[Any]]
    fixed: dict[str, Any] = field(default_factory=dict)
    description: str = ""

    @property
    def n_points(self) -> int:
        """Number of grid points (1 for an empty grid)."""
        n = 1
        for values in self.grid.values():
            n *= len(values)
        return n

    @property
    def n_trials(self) -> int:
        """Grid points times repetitions."""
        return self.n_points * self.trials_per_point

    def points(self) -> list[dict[str, Any]]:
        """The swept values of every grid point, in point order."""
        keys = list(self.grid)
        return [
            dict(zip(keys, combo, strict=True)) for combo in itertools.product(*self.grid.values())
        ]

    def point_values(self, point: int) -> dict[str, Any]:
        """The swept values of grid point ``point``."""
        values: dict[str, Any] = {}
        rest = point
        for key in reversed(self.grid):
            options = self.grid[key]
            rest, index = divmod(rest, len(options))
            values[key] = options[index]
        return {key: values[key] for key in self.grid}

    def point_params(self, point: int) -> dict[str, Any]:
        """The full parameters of grid point ``point``: fixed, then swept."""
        return {**self.fixed, **self.point_values(point)}

    def tasks(self, skip: Sequence[int] | set[int] = ()) -> Iterator[TrialTask]:
        """Every trial not in ``skip`` (trial ids), in trial-id order."""
        done = set(skip)
        for point in range(self.n_points):
            params = self.point_params(point)
            for rep in range(self.trials_per_point):
                trial_id = point * self.trials_per_point + rep
                if trial_id not in done:
                    yield TrialTask(trial_id, point, rep, params, self.seed)

    def definition(self) -> dict[str, Any]:
        """What makes two sweeps the same (a resumed sweep must match it exactly)."""
        return {
            "name": self.name,
            "trial": self.trial,
            "target": self.target,
            "trials_per_point": self.trials_per_point,
            "seed": self.seed,
            "grid": self.grid,
            "fixed": self.fixed,
        }
