"""Per-trial random streams fixed by the sweep's root entropy and the trial's place in the grid.

Trial ``(point, rep)`` of a sweep with root entropy ``E`` gets
``SeedSequence(E, spawn_key=(point, rep))``: the same child that
``SeedSequence(E).spawn(n_points)[point].spawn(reps)[rep]`` gives, but computed directly, so it
depends on nothing else: not on the execution order, the runner or the number of workers.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.errors import ConfigError


def check_entropy(entropy: Any, field: str = "sweep.seed") -> int:
    """``entropy`` as a root seed: a non-negative integer (bool refused)."""
    if isinstance(entropy, bool) or not isinstance(entropy, (int, np.integer)) or entropy < 0:
        raise ConfigError(
            field, entropy, "an integer >= 0 (the root entropy)", "e.g. seed = 20240601"
        )
    return int(entropy)


def trial_seed(entropy: int, point: int, rep: int) -> np.random.SeedSequence:
    """The SeedSequence of repetition ``rep`` at grid point ``point``.

    >>> a = trial_seed(7, 2, 1)
    >>> b = np.random.SeedSequence(7).spawn(3)[2].spawn(2)[1]
    >>> bool((a.generate_state(4) == b.generate_state(4)).all())
    True
    """
    return np.random.SeedSequence(check_entropy(entropy), spawn_key=(int(point), int(rep)))


def seed_record(seed: np.random.SeedSequence) -> dict[str, Any]:
    """JSON-ready description from which :func:`seed_from_record` rebuilds ``seed``."""
    return {"entropy": seed.entropy, "spawn_key": list(seed.spawn_key)}


def seed_from_record(record: dict[str, Any]) -> np.random.SeedSequence:
    """The SeedSequence described by :func:`seed_record`, to replay one trial.

    >>> s = trial_seed(11, 4, 0)
    >>> seed_from_record(seed_record(s)).generate_state(2).tolist() == s.generate_state(2).tolist()
    True
    """
    return np.random.SeedSequence(record["entropy"], spawn_key=tuple(record["spawn_key"]))
