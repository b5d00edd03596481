"""The end of a TPO run: which phase's final policy answers (docs/design.md §5).

Where the leaf is indifferent (its goal out of reach within the slack), the
leaf's phase leaves its policy to chance, while the tie rule of
docs/design.md §2 (lexicographic completion) gives the remaining freedom to the
ancestors, roots first. The policies the ancestors' own phases ended with are
often exactly that completion (measured in docs/notes/tpo-learning.md; a fan's
roots keep nothing of each other, so there a phase after the leaf learns it:
:class:`tpo.algo.phases.Problem`), so the
run ends by choosing among the phases' final policies, judged by their greedy
Monte Carlo returns: the tie rule, applied to the candidates the run already has.
The answer must also keep the leaf's ancestral edges by LAR's own rule on the
candidates' returns (:func:`keepers`), where one of them does. A population of
independent learners (:class:`tpo.algo.TPO`'s ``population``) then answers with
the member whose answer that rule prefers, judged on the same returns
(:func:`choose_member`).
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp

from tpo.tabular.judge import ABS_TOL, REL_TOL


def choose(returns: jax.Array, penalty: jax.Array, order: Sequence[int],
           penalty_tolerance: float | jax.Array, held: jax.Array | None = None,
           reference: int = -1, edges: Sequence[tuple[int, int]] = (),
           allowance: jax.Array | None = None) -> jax.Array:
    """The index of the answering candidate, lexicographically.

    ``returns [N, P]``: candidate ``n``'s return of phase ``p``'s objective;
    ``penalty [N]``: its total violation of the leaf's constraints (the leaf
    phase's own checks); ``reference`` is the candidate that is the run's own
    policy (the leaf's; by default the last). A candidate is admissible when its
    penalty is at most the reference's plus ``penalty_tolerance``, and when on its
    own phase's objective it is no
    worse than the reference: a phase's policy stands in for
    that objective's optimum under constraints the leaf keeps too, so one that
    the leaf's own policy beats there is not what it stands for. ``held [P]``
    (bool) marks the objectives the leaf keeps at zero slack: on them, taken in
    ``order``, a candidate must be lexicographically no worse than the reference
    (worse on one only where better on one before it), a check in the returns
    themselves where the penalty's allowance (the critics' noise) could hide a
    real loss of a few reward units. With ``edges`` and ``allowance`` (as in
    :func:`choose_member`), a candidate must also keep the leaf's ancestral edges
    by LAR's rule on the candidates' returns, if an admissible one does: the
    reference may itself have lost a zero-slack parent's best. Where it lost one
    of an objective's ancestral edges by that rule, its return of the objective
    bounds nothing (a leaf that never reaches the monitored room keeps off the rug
    for free), so that objective's phase need not match it there. Among the
    admissible ones, keep those tied with the best return of phase ``p`` for each
    ``p`` in ``order`` (the leaf's objective first, then its ancestors roots
    first), and of those the reference if it is still tied, else the latest.
    Returns tie as the judge's verdicts do: within 2 % of the reference's, or 0.5
    (:func:`tpo.tabular.judge.tolerance`).
    """
    if edges and allowance is None:
        raise ValueError("choose: edges need their allowance")
    n = returns.shape[0]
    ref = returns[reference]
    tolerance = _tolerance(ref)
    own = jnp.diagonal(returns) >= ref - tolerance
    if edges:  # [objective, candidate]: keeps the objective's ancestral edges
        kept = keepers(returns, returns, edges, allowance, max(order) + 1)
        # a reference that loses an objective's parents says nothing of its optimum
        own = own | jnp.zeros(n, bool).at[:kept.shape[0]].set(~kept[:, reference])
    keep = own & (penalty <= penalty[reference] + penalty_tolerance)
    if held is not None:  # lexicographically no worse on the held objectives
        held = jnp.asarray(held, bool)
        decided = jnp.zeros(n, bool)
        for p in order:
            worse = held[p] & (returns[:, p] < ref[p] - tolerance[p])
            keep = keep & (decided | ~worse)
            decided = decided | held[p] & (returns[:, p] > ref[p] + tolerance[p])
    if edges:
        lar = kept[-1]
        keep = jnp.where((keep & lar).any(), keep & lar, keep)
    for p in order:
        best = jnp.max(jnp.where(keep, returns[:, p], -jnp.inf))
        keep = keep & (returns[:, p] >= best - tolerance[p])
    index = jnp.arange(n)
    return jnp.where(keep[reference], index[reference], jnp.max(jnp.where(keep, index, -1)))


def choose_member(returns: jax.Array, picks: jax.Array, edges: Sequence[tuple[int, int]],
                  allowance: jax.Array, order: Sequence[int]) -> jax.Array:
    """The index of the answering member of a population, by LAR's rule on their returns.

    ``returns [M, N, P]``: member ``m``'s candidate ``n``'s return of phase ``p``'s
    objective (the objectives' phases first, in topological order); ``picks [M]``:
    each member's own answer (:func:`choose`). ``edges``: every edge of the graph
    as ``(parent, child)`` phases; ``allowance [E]``: the most each edge lets the
    child lose of the parent's value at the start (a local slack ``eta`` allows
    ``eta / (1 - gamma)``). Taking the objectives in topological order, the best
    value of ``w`` is the largest return of ``w`` among *all* candidates (every
    member's every phase) that keep ``w``'s ancestral edges, and a policy keeps an
    edge ``(w, v)`` when its return of ``w`` is at least that best less the
    allowance and the judge's tolerance. Among the answers that keep the leaf's
    ancestral edges (all of them if none does), the best on ``order`` (the leaf
    first, then its ancestors roots first), ties as in :func:`choose`; the first
    such member.
    """
    m, n = returns.shape[:2]
    answers = returns[jnp.arange(m), picks]
    lar = keepers(returns.reshape(m * n, -1), answers, edges, allowance, max(order) + 1)[-1]
    keep = lar | ~lar.any()
    for p in order:
        top = jnp.max(jnp.where(keep, answers[:, p], -jnp.inf))
        keep = keep & (answers[:, p] >= top - _tolerance(top))
    return jnp.argmax(keep)


def keepers(pool: jax.Array, values: jax.Array, edges: Sequence[tuple[int, int]],
            allowance: jax.Array, objectives: int) -> jax.Array:
    """Which of ``values [N, P]`` keep each objective's ancestral edges by LAR's
    rule on the policies' returns ``pool [M, P]`` (:func:`choose_member`): taking the
    objectives (the first ``objectives`` columns) in topological order, ``w``'s best
    is its largest return among the policies of ``pool`` that keep ``w``'s ancestral
    edges, and a policy keeps the edge ``(w, v)`` (``edges[e]``) when its return of
    ``w`` is at least that best less ``allowance[e]`` and the judge's tolerance.
    ``[objectives, N]`` bool (a root's row all true)."""
    in_pool, in_values, best = [], [], []
    for v in range(objectives):
        keep_pool = jnp.ones(pool.shape[0], bool)
        keep_values = jnp.ones(values.shape[0], bool)
        for e, (w, child) in enumerate(edges):
            if child == v:
                floor = best[w] - allowance[e] - _tolerance(best[w])
                keep_pool = keep_pool & in_pool[w] & (pool[:, w] >= floor)
                keep_values = keep_values & in_values[w] & (values[:, w] >= floor)
        in_pool.append(keep_pool)
        in_values.append(keep_values)
        best.append(jnp.max(jnp.where(keep_pool, pool[:, v], -jnp.inf)))
    return jnp.stack(in_values)


def _tolerance(value: jax.Array) -> jax.Array:
    """The judge's tolerance around ``value``: 2 %, or 0.5."""
    return jnp.maximum(REL_TOL * jnp.abs(value), ABS_TOL)


def stack_snapshot(snapshots: dict, phase: jax.Array, actor: dict) -> dict:
    """``snapshots`` (every leaf ``[P, ...]``) with ``actor`` written at ``phase``."""
    return jax.tree.map(lambda s, a: s.at[phase].set(a), snapshots, actor)
