"""The end of a TPO run: which phase's final policy answers (docs/design.md §5).

Where the leaf is indifferent (its goal out of reach within the slack), the
leaf's phase leaves its policy to chance, while the tie rule of
docs/design.md §2 (lexicographic completion) gives the remaining freedom to the
ancestors, roots first. The policies the ancestors' own phases ended with are
often exactly that completion (measured in docs/notes/tpo-learning.md), so the
run ends by choosing among the phases' final policies, judged by their greedy
Monte Carlo returns: the tie rule, applied to the candidates the run already has.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp

from tpo.tabular.judge import ABS_TOL, REL_TOL


def choose(returns: jax.Array, penalty: jax.Array, order: Sequence[int],
           penalty_tolerance: float | jax.Array, held: jax.Array | None = None) -> jax.Array:
    """The index of the answering candidate, lexicographically.

    ``returns [N, P]``: candidate ``n``'s return of phase ``p``'s objective;
    ``penalty [N]``: its total violation of the leaf's constraints (the leaf
    phase's own checks); the reference candidate, the leaf's own policy, is the
    last. A candidate is admissible when its penalty is at most the reference's
    plus ``penalty_tolerance``, and when on its own phase's objective it is no
    worse than the reference: a phase's policy stands in for
    that objective's optimum under constraints the leaf keeps too, so one that
    the leaf's own policy beats there is not what it stands for. ``held [P]``
    (bool) marks the objectives the leaf keeps at zero slack: on them, taken in
    ``order``, a candidate must be lexicographically no worse than the reference
    (worse on one only where better on one before it), a check in the returns
    themselves where the penalty's allowance (the critics' noise) could hide a
    real loss of a few reward units. Among the
    admissible ones, keep those tied with the best return of phase ``p`` for each
    ``p`` in ``order`` (the leaf's objective first, then its ancestors roots
    first), and of those the latest (the reference where it is still tied).
    Returns tie as the judge's verdicts do: within 2 % of the reference's, or 0.5
    (:func:`tpo.tabular.judge.tolerance`).
    """
    n = returns.shape[0]
    tolerance = jnp.maximum(REL_TOL * jnp.abs(returns[-1]), ABS_TOL)
    own = jnp.diagonal(returns) >= returns[-1] - tolerance
    keep = own & (penalty <= penalty[-1] + penalty_tolerance)
    if held is not None:  # lexicographically no worse on the held objectives
        held = jnp.asarray(held, bool)
        decided = jnp.zeros(n, bool)
        for p in order:
            worse = held[p] & (returns[:, p] < returns[-1, p] - tolerance[p])
            keep = keep & (decided | ~worse)
            decided = decided | held[p] & (returns[:, p] > returns[-1, p] + tolerance[p])
    for p in order:
        best = jnp.max(jnp.where(keep, returns[:, p], -jnp.inf))
        keep = keep & (returns[:, p] >= best - tolerance[p])
    return jnp.max(jnp.where(keep, jnp.arange(n), -1))


def stack_snapshot(snapshots: dict, phase: jax.Array, actor: dict) -> dict:
    """``snapshots`` (every leaf ``[P, ...]``) with ``actor`` written at ``phase``."""
    return jax.tree.map(lambda s, a: s.at[phase].set(a), snapshots, actor)
