"""The end of a TPO run: which policy answers (docs/design.md §5).

Where the leaf is indifferent (its goal out of reach within the slack), the
leaf's phase leaves its policy to chance, while the tie rule of
docs/design.md §2 gives the remaining freedom to the ancestors, roots first.
The policies the ancestors' own phases ended with are often exactly that
completion, so a run ends by selecting among the phases' final policies (the
*candidates*), judged by their greedy Monte Carlo returns: the tie rule, applied
to the policies the run has (:func:`select_phase`). The answer must also keep
the leaf's ancestral edges by LAR's own rule on the candidates' returns
(:func:`keepers`), where one of them does. A population of independent learners
then answers with the member whose answer that rule prefers (:func:`select_member`).

:func:`select` is the one entry point, for a JAX env (traceable: jit or vmap it)
and for a host-stepped Gymnasium env (its :class:`tpo.algo.runners.HostRunner`).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial

import jax
import jax.numpy as jnp

from tpo.algo.constraints import penalty
from tpo.algo.evaluate import Episodes, discounted, episodes
from tpo.algo.lagrangian import ancestral_advantages
from tpo.algo.phases import reward_ranges
from tpo.algo.runners import HostRunner
from tpo.algo.train import Trainer, TrainState
from tpo.tabular.judge import ABS_TOL, RANGE_SHARE, REL_TOL

SELECT_EPISODES = 16  # greedy episodes per candidate


def select(trainer: Trainer, state: TrainState, slack: jax.Array,
           env: object) -> TrainState:
    """A finished run's answer: ``state`` acting with the candidate that
    :func:`select_phase` selects (``config.select``; else ``state`` unchanged), or
    for a population's members stacked ``[M, ...]`` the state of the member that
    :func:`select_member` selects, acting with its own answer. ``env``, a JAX env
    of the task (e.g. from its start) or a :class:`HostRunner`, plays the
    candidates' greedy episodes. Depends only on the phases' final policies, so
    selecting twice is selecting once."""
    if jnp.ndim(state.update) == 1:  # a population's members
        if isinstance(env, HostRunner):  # one member's episodes at a time
            returns, pen = (jnp.stack(x) for x in zip(*(
                candidates(trainer, jax.tree.map(lambda x, m=m: x[m], state), slack, env)
                for m in range(state.update.shape[0])), strict=True))
        else:
            returns, pen = jax.vmap(lambda s: candidates(trainer, s, slack, env))(state)
        absolute = absolute_tolerance(trainer, returns)
        picks = (jax.vmap(lambda r, p: selected(trainer, slack, r, p, absolute))(returns, pen)
                 if selects(trainer) else jnp.full(returns.shape[0], trainer.problem.reference))
        member = select_member(returns, picks, edges(trainer), allowance(trainer, slack),
                               tie_order(trainer), absolute)
        return _acting_with(jax.tree.map(lambda x: x[member], state), picks[member])
    if not selects(trainer):
        return state
    returns, pen = candidates(trainer, state, slack, env)
    return _acting_with(state, selected(trainer, slack, returns, pen,
                                        absolute_tolerance(trainer, returns)))


def selects(trainer: Trainer) -> bool:
    """Whether a finished run selects its answer among the phases' policies."""
    return trainer.config.select and trainer.problem.n_phases > 1


def candidates(trainer: Trainer, state: TrainState, slack: jax.Array, env: object
               ) -> tuple[jax.Array, jax.Array]:
    """Every phase's final policy, acting greedily as the run's policy does (under
    the reference phase's constraints) for ``SELECT_EPISODES`` episodes of ``env``
    (the same for each), scored by :func:`score`: ``[P, P]`` and ``[P]``. On a JAX
    env one candidate at a time (their episodes' critic activations are the
    memory)."""
    acting = trainer.acting(state, slack, jnp.int32(trainer.problem.reference))
    if isinstance(env, HostRunner):
        scored = jax.jit(partial(score, trainer))
        runs = []
        for p in range(trainer.problem.n_phases):
            actor = jax.tree.map(lambda s, p=p: s[p], state.snapshots)
            ep = env.greedy_episodes(acting._replace(actor=actor), SELECT_EPISODES,
                                     seed=int(state.update))
            runs.append(scored(state, slack, ep))
        returns, pen = (jnp.stack(x) for x in zip(*runs, strict=True))
        return returns, pen
    keys = jax.random.split(jax.random.fold_in(state.key, 1), SELECT_EPISODES)
    return jax.lax.map(lambda actor: score(trainer, state, slack, episodes(
        trainer.policy, acting._replace(actor=actor), env, keys, True)), state.snapshots)


def score(trainer: Trainer, state: TrainState, slack: jax.Array, ep: Episodes
          ) -> tuple[jax.Array, jax.Array]:
    """A candidate's mean discounted return of every phase's objective ``[P]`` and
    mean discounted penalty of the leaf's constraints ``[]`` over its episodes."""
    terms, gamma = trainer.terms, trainer.config.gamma
    # The critics see every step at once (one batched call, not one per step).
    value, next_value = trainer.values(state, jnp.stack([ep.obs, ep.next_obs]))[..., 0]
    rewards = ep.reward[..., jnp.asarray(terms.reward)]
    adv_all = ancestral_advantages(rewards, value, next_value, ep.terminated, gamma)
    pen = penalty(terms, adv_all, slack, jnp.int32(leaf_phase(trainer)),
                  trainer.loose_tolerance(state))
    return (discounted(rewards, ep.alive, gamma).mean(0),
            discounted(pen, ep.alive, gamma).mean(0))


def absolute_tolerance(trainer: Trainer, returns: jax.Array) -> jax.Array:
    """The absolute part ``[P]`` of the tolerance by which returns of each phase's
    objective tie: the env's own (``absolute_tolerance``: 0.5 on a map), else the
    judge's scale-free ``RANGE_SHARE * R_k`` with the value range ``R_k`` estimated
    by the spread of the candidates' returns ``[..., P]`` (they lie within it)."""
    fixed = trainer.env.absolute_tolerance
    flat = returns.reshape(-1, returns.shape[-1])
    if fixed is not None:
        return jnp.full(flat.shape[-1], fixed, jnp.float32)
    return RANGE_SHARE * (flat.max(0) - flat.min(0))


def selected(trainer: Trainer, slack: jax.Array, returns: jax.Array, pen: jax.Array,
             absolute: jax.Array) -> jax.Array:
    """The candidate that a run of ``trainer`` selects (:func:`select_phase`) from the
    candidates' ``returns [P, P]`` and penalty ``[P]``, holding the parents of the leaf's
    constraints at zero ``slack``, among those that keep the leaf's ancestral edges
    by LAR's rule on the candidates; returns tie within :func:`absolute_tolerance`'s
    ``absolute`` or 2 %."""
    prob, terms = trainer.problem, trainer.terms
    leaf = leaf_phase(trainer)
    ranges = reward_ranges(trainer.env.reward_low, trainer.env.reward_high)[prob.reward]
    zero = (terms.slacks(slack) <= 0) & (jnp.asarray(prob.active[leaf]) > 0)
    held = jnp.zeros(prob.n_phases, bool).at[jnp.asarray(prob.head)].max(zero)
    return select_phase(returns, pen, tie_order(trainer),
                        trainer.config.select_penalty * float(ranges[prob.head].max(initial=1.0)),
                        held, prob.reference, edges(trainer), allowance(trainer, slack),
                        absolute)


def edges(trainer: Trainer) -> list[tuple[int, int]]:
    """Every edge of the graph as its ``(parent, child)`` objectives' phases."""
    graph = trainer.problem.graph
    phase = {name: i for i, name in enumerate(graph.order)}
    return [(phase[e.parent], phase[e.child]) for e in graph.edges]


def allowance(trainer: Trainer, slack: jax.Array) -> jax.Array:
    """The most each edge lets its child lose of the parent's value at the start
    (a local ``slack`` eta allows eta / (1 - gamma))."""
    return jnp.asarray(slack, jnp.float32) / (1 - trainer.config.gamma)


def leaf_phase(trainer: Trainer) -> int:
    """The leaf objective's phase."""
    return len(trainer.problem.graph.order) - 1


def tie_order(trainer: Trainer) -> list[int]:
    """The phases in the order the tie rule weighs them: the leaf, then its
    ancestors roots first."""
    return [leaf_phase(trainer), *range(leaf_phase(trainer))]


def _acting_with(state: TrainState, snapshot: jax.Array) -> TrainState:
    """``state`` with its actor replaced by its phase ``snapshot``'s."""
    actor = jax.tree.map(lambda s: s[snapshot], state.snapshots)
    return state.replace(params={**state.params, "actor": actor})


def select_phase(returns: jax.Array, penalty: jax.Array, order: Sequence[int],
           penalty_tolerance: float | jax.Array, held: jax.Array | None = None,
           reference: int = -1, edges: Sequence[tuple[int, int]] = (),
           allowance: jax.Array | None = None,
           absolute: float | jax.Array = ABS_TOL) -> jax.Array:
    """The index of the selected candidate, by the tie rule on greedy returns.

    ``returns [N, P]``: candidate ``n``'s return of phase ``p``'s objective;
    ``penalty [N]``: its discounted violation of the leaf's constraints;
    ``reference``: the run's own policy (the leaf's; by default the last). A
    candidate is admissible when

    - its penalty is at most the reference's plus ``penalty_tolerance``;
    - it is no worse than the reference on its own phase's objective (it stands
      for that objective's optimum), unless the reference loses one of that
      objective's ancestral edges;
    - on the objectives ``held [P]`` at zero slack, taken in ``order``, it is
      lexicographically no worse than the reference;
    - with ``edges`` and ``allowance`` (:func:`select_member`), it keeps the
      leaf's ancestral edges by LAR's rule on the candidates, if one does.

    Of those, the best on each phase of ``order`` in turn (the leaf, then its
    ancestors roots first); the reference if still tied, else the latest.
    Returns tie as the verdicts do: within 2 % or ``absolute`` (a number or one
    per phase ``[P]``).
    """
    if edges and allowance is None:
        raise ValueError("select_phase: edges need their allowance")
    n = returns.shape[0]
    ref = returns[reference]
    absolute = jnp.broadcast_to(jnp.asarray(absolute, jnp.float32), ref.shape)
    tolerance = _tolerance(ref, absolute)
    own = jnp.diagonal(returns) >= ref - tolerance
    if edges:  # [objective, candidate]: keeps the objective's ancestral edges
        kept = keepers(returns, returns, edges, allowance, max(order) + 1, absolute)
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


def select_member(returns: jax.Array, picks: jax.Array, edges: Sequence[tuple[int, int]],
                  allowance: jax.Array, order: Sequence[int],
                  absolute: float | jax.Array = ABS_TOL) -> jax.Array:
    """The index of the answering member of a population, by LAR's rule on their returns.

    ``returns [M, N, P]``: member ``m``'s candidate ``n``'s return of phase ``p``'s
    objective (the objectives' phases first, in topological order); ``picks [M]``:
    each member's own answer (:func:`select_phase`). ``edges``: every edge of the graph
    as ``(parent, child)`` phases; ``allowance [E]``: the most each edge lets the
    child lose of the parent's value at the start (a local slack ``eta`` allows
    ``eta / (1 - gamma)``). Taking the objectives in topological order, the best
    value of ``w`` is the largest return of ``w`` among *all* candidates (every
    member's every phase) that keep ``w``'s ancestral edges, and a policy keeps an
    edge ``(w, v)`` when its return of ``w`` is at least that best less the
    allowance and the judge's tolerance. Among the answers that keep the leaf's
    ancestral edges (all of them if none does), the best on ``order`` (the leaf
    first, then its ancestors roots first), ties as in :func:`select_phase`; the first
    such member. Returns tie within 2 % or ``absolute`` (one number or one per phase).
    """
    m, n = returns.shape[:2]
    absolute = jnp.broadcast_to(jnp.asarray(absolute, jnp.float32), returns.shape[-1:])
    answers = returns[jnp.arange(m), picks]
    lar = keepers(returns.reshape(m * n, -1), answers, edges, allowance, max(order) + 1,
                  absolute)[-1]
    keep = lar | ~lar.any()
    for p in order:
        top = jnp.max(jnp.where(keep, answers[:, p], -jnp.inf))
        keep = keep & (answers[:, p] >= top - _tolerance(top, absolute[p]))
    return jnp.argmax(keep)


def keepers(pool: jax.Array, values: jax.Array, edges: Sequence[tuple[int, int]],
            allowance: jax.Array, objectives: int,
            absolute: float | jax.Array = ABS_TOL) -> jax.Array:
    """Which of ``values [N, P]`` keep each objective's ancestral edges by LAR's
    rule on the policies' returns ``pool [M, P]`` (:func:`select_member`): taking the
    objectives (the first ``objectives`` columns) in topological order, ``w``'s best
    is its largest return among the policies of ``pool`` that keep ``w``'s ancestral
    edges, and a policy keeps the edge ``(w, v)`` (``edges[e]``) when its return of
    ``w`` is at least that best less ``allowance[e]`` and the judge's tolerance.
    ``[objectives, N]`` bool (a root's row all true); ``absolute``: as
    :func:`select_phase`'s."""
    absolute = jnp.broadcast_to(jnp.asarray(absolute, jnp.float32), pool.shape[-1:])
    in_pool, in_values, best = [], [], []
    for v in range(objectives):
        keep_pool = jnp.ones(pool.shape[0], bool)
        keep_values = jnp.ones(values.shape[0], bool)
        for e, (w, child) in enumerate(edges):
            if child == v:
                floor = best[w] - allowance[e] - _tolerance(best[w], absolute[w])
                keep_pool = keep_pool & in_pool[w] & (pool[:, w] >= floor)
                keep_values = keep_values & in_values[w] & (values[:, w] >= floor)
        in_pool.append(keep_pool)
        in_values.append(keep_values)
        best.append(jnp.max(jnp.where(keep_pool, pool[:, v], -jnp.inf)))
    return jnp.stack(in_values)


def _tolerance(value: jax.Array, absolute: jax.Array) -> jax.Array:
    """The judge's tolerance around ``value``: 2 %, or ``absolute``."""
    return jnp.maximum(REL_TOL * jnp.abs(value), absolute)
