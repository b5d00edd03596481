"""The NaN guard: training stops at the first non-finite loss, return or
parameter, naming the phase, the update and the quantity."""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from tpo.errors import TPOError

WATCHED = ("policy_loss", "value_loss", "entropy", "episode_return", "penalty")


class NonFiniteError(TPOError):
    """Training produced NaN or infinity."""


def check_finite(params: dict, metrics: dict[str, np.ndarray], done: int,
                 phases: Sequence[str]) -> None:
    """Raise :class:`NonFiniteError` if a chunk of updates that started after update
    ``done`` produced a non-finite metric (``metrics`` stacked over the chunk) or
    left non-finite ``params``; ``phases`` names the phases in order."""
    for name in WATCHED:
        values = np.asarray(metrics[name]).reshape(len(metrics["phase"]), -1)
        bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
        if bad.size:
            i = int(bad[0])
            raise NonFiniteError(f"non-finite {name} in phase "
                                 f"'{phases[int(metrics['phase'][i])]}' at update "
                                 f"{done + i + 1}; the last good state (update {done}) "
                                 "is kept")
    finite = jax.tree.map(lambda x: bool(jnp.isfinite(x).all()), params)
    for path, ok in jax.tree_util.tree_flatten_with_path(finite)[0]:
        if not ok:
            raise NonFiniteError(f"non-finite parameters {jax.tree_util.keystr(path)} "
                                 f"after update {done + len(metrics['phase'])}; the last "
                                 f"good state (update {done}) is kept")
