"""The constraint terms of a TPO phase: what its policy and its critic learn from
(paper Eq. 10 and the learner's added terms; docs/design.md §5).

:class:`ConstraintTerms` holds the static sizes of every term, built once from the
problem and the config; :func:`lagrangian_terms` is the one function that turns a
rollout and the frozen critics' values into the phase's advantage, its critic's
target and the penalty. Each added term is one config field, and its off value
removes it (docs/config.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from tpo.algo.config import TPOConfig
from tpo.algo.lagrangian import ancestral_advantages, lagrangian_advantages, violations
from tpo.algo.losses import discounted_cumsum
from tpo.algo.phases import Problem, reward_ranges, value_bounds

#: the second design's least tolerance of a loose constraint, a share of the
#: parent's one-step reward range
SECOND_FLOOR = 0.01


@dataclass(frozen=True, eq=False)
class ConstraintTerms:
    """The sizes of the constraint terms of every phase ``p`` and constraint ``c``
    (``C`` constraints of :class:`tpo.algo.phases.Problem`).

    Attributes:
        reward: ``[P]`` reward column of every phase.
        head: ``[C]`` the critic head (a phase) whose values constraint ``c`` reads.
        slack_index: ``[C]`` its slack: an edge's index, or ``n_edges`` for zero.
        weights: ``[P, C]`` 1 where phase ``p`` pays constraint ``c``'s penalty (none
            in the restriction form, which keeps the constraints by its actions).
        beta: ``[P]`` the multiplier (``config.beta``).
        margin: ``[C]`` how far below its slack a constraint starts to charge
            (``config.margin`` of the parent's one-step reward range).
        tolerance: ``[C]`` how far beyond zero slack a loose constraint starts to
            charge (``config.tolerance`` of that range).
        loose: ``[C]`` the zero-slack constraints counted from ``tolerance``: the
            completion's, and with ``telescope = "roots"`` those that do not telescope.
        telescoped: ``[C]`` the zero-slack constraints charging ``-A_w`` itself
            (``config.telescope``).
        dead_zone: ``[C]`` the soft threshold of a telescoped cost's advantage
            (``config.dead_zone`` of the range).
        tie: ``[P, P]`` weight of head ``h``'s return in phase ``p``'s objective: the
            ``j``-th ancestor of the leaf ``tie_break ** (j + 1)`` in units of the
            ranges (``config.tie_break``).
        tie_bound: ``[P]`` the most the tie-break moves one step's advantage.
        tie_critic: who values the tie-break (``config.tie_critic``).
        advantage: the advantage's form (``config.advantage``).
        gamma, lam: the discount and GAE's lambda.
        second_tolerance: the second design's loose tolerance, a share of the
            parent head's value spread (``config.second_tolerance``).
        second_floor: ``[C]`` its least value: :data:`SECOND_FLOOR` of the range.
    """

    reward: np.ndarray
    head: np.ndarray
    slack_index: np.ndarray
    weights: np.ndarray
    beta: np.ndarray
    margin: np.ndarray
    tolerance: np.ndarray
    loose: np.ndarray
    telescoped: np.ndarray
    dead_zone: np.ndarray
    tie: np.ndarray
    tie_bound: np.ndarray
    tie_critic: str
    advantage: str
    gamma: float
    lam: float
    second_tolerance: float
    second_floor: np.ndarray

    @classmethod
    def build(cls, problem: Problem, config: TPOConfig, reward_low: np.ndarray,
              reward_high: np.ndarray, penalized: bool = True) -> ConstraintTerms:
        """The terms of ``problem``'s phases under ``config``; ``penalized`` false for
        a form that keeps the constraints otherwise (no penalty is paid)."""
        graph, order = problem.graph, problem.graph.order
        all_ranges = reward_ranges(reward_low, reward_high)
        ranges = all_ranges[problem.reward[problem.head]]  # each constraint's parent
        telescoped = np.array([penalized and (config.telescope == "all" or (
            config.telescope == "roots" and h < len(order) and not graph.parents(order[h])))
            for h in problem.head], bool)
        completion = (problem.slack_index == len(graph.edges)) & (
            problem.head >= len(order) - 1)
        loose = completion | (config.telescope == "roots") & ~telescoped
        cost = np.asarray(reward_high, float)[problem.reward[problem.head]] == 0
        if config.beta == "auto":
            beta = value_bounds(reward_low, reward_high, config.gamma)[problem.reward]
        else:
            beta = np.full(problem.n_phases, float(config.beta))
        phase_ranges = all_ranges[problem.reward]
        tie = np.zeros((problem.n_phases, problem.n_phases), np.float32)
        leaf = len(order) - 1
        for j, h in enumerate(order.index(n) for n in graph.ancestors(graph.leaf)):
            tie[leaf, h] = config.tie_break ** (j + 1) * phase_ranges[leaf] / phase_ranges[h]
        return cls(problem.reward, problem.head, problem.slack_index,
                   problem.active if penalized else np.zeros_like(problem.active),
                   beta.astype(np.float32), (config.margin * ranges).astype(np.float32),
                   (config.tolerance * ranges).astype(np.float32), loose, telescoped,
                   (config.dead_zone * ranges * cost * telescoped).astype(np.float32),
                   tie, (config.tie_break * phase_ranges).astype(np.float32),
                   config.tie_critic, config.advantage, config.gamma, config.gae_lambda,
                   config.second_tolerance, (SECOND_FLOOR * ranges).astype(np.float32))

    def slacks(self, slack: jax.Array) -> jax.Array:
        """Every constraint's slack ``[C]`` from the edges' ``slack [n_edges]`` (zero
        for the completion constraints)."""
        return jnp.concatenate([slack, jnp.zeros(1)])[jnp.asarray(self.slack_index)]


def penalty(terms: ConstraintTerms, advantages: jax.Array, slack: jax.Array,
            phase: jax.Array, loose_tolerance: jax.Array) -> jax.Array:
    """Phase ``phase``'s penalty ``[...]`` from every head's one-step advantages
    ``[..., P]`` (Eq. 10's ``sum_{E_i} C_wv``)::

        C_wv = max(0, -A_w - (eta_wv - min(margin, eta_wv / 2)))   slack > 0
        C_wv = max(0, -A_w - tolerance)                            loose, zero slack
        C_wv = sign(-A_w) max(0, |A_w| - dead_zone)                telescoped, zero slack

    ``loose_tolerance [C]`` is :func:`loose_tolerance`'s.
    """
    slacks = terms.slacks(slack)
    margin = jnp.minimum(jnp.asarray(terms.margin), slacks / 2)
    loose = jnp.asarray(terms.loose) & (slacks <= 0)
    c = violations(advantages, jnp.asarray(terms.head),
                   slacks - margin + jnp.where(loose, loose_tolerance, 0.0),
                   jnp.asarray(terms.telescoped), jnp.asarray(terms.dead_zone))
    return c @ jnp.asarray(terms.weights)[phase]


def lagrangian_terms(terms: ConstraintTerms, phase: jax.Array, slack: jax.Array,
                     reward: jax.Array, value: jax.Array, next_value: jax.Array,
                     terminated: jax.Array, done: jax.Array, explore: jax.Array,
                     loose_tolerance: jax.Array, trace_decay: jax.Array
                     ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Phase ``phase``'s advantage, its critic's target and its penalty ``[T, E]``
    each, from a rollout's env rewards ``reward [T, E, k]``, every frozen head's
    values ``value``, ``next_value [T, E, P]`` and its flags ``[T, E]``.

    With ``r = r_i`` the phase's reward, ``A_h`` each head's one-step advantage,
    ``c_t`` :func:`penalty`'s sum of violations and ``G = gamma lambda``::

        traced:     A_t = GAE(r)_t - beta sum_l decay^l c_{t+l}    (Eq. 10's penalty,
        immediate:  A_t = GAE(r)_t - beta c_t                       the critic on r)
        penalized:  A_t = GAE(r - beta c)_t                         (the critic on it)
        tie-break:  A_t += sum_l G^l clip(sum_h tie_ih A_h, +-tie_bound_i)

    where ``tie_critic = "leaf"`` adds ``sum_h tie_ih r_h`` to ``r`` instead of the
    tie-break term. The critic's target is ``GAE(r)_t + V_i(s_t)`` (``penalized``:
    of ``r - beta c``). An exploring step (the restriction form's) cuts the
    trace of the steps before it. ``loose_tolerance`` and ``trace_decay`` are
    :func:`loose_tolerance`'s and :func:`trace_decay`'s.
    """
    pick = jax.nn.one_hot(phase, len(terms.reward))
    rewards = reward[..., jnp.asarray(terms.reward)]
    adv_all = ancestral_advantages(rewards, value, next_value, terminated, terms.gamma)
    pen = penalty(terms, adv_all, slack, phase, loose_tolerance)
    own, v, next_v = rewards @ pick, value @ pick, next_value @ pick
    tie = jnp.asarray(terms.tie)[phase]
    if terms.tie.any() and terms.tie_critic == "leaf":
        own = own + rewards @ tie
    following = jnp.concatenate([explore[1:], jnp.zeros_like(explore[:1])])
    done = jnp.maximum(done, following)
    advantage, target = lagrangian_advantages(
        terms.advantage, own, v, next_v, pen, jnp.asarray(terms.beta)[phase], terminated,
        done, terms.gamma, terms.lam, trace_decay)
    if terms.tie.any() and terms.tie_critic == "ancestors":
        bound = jnp.asarray(terms.tie_bound)[phase]
        step = jnp.clip(adv_all @ tie, -bound, bound)
        advantage = advantage + discounted_cumsum(step, terms.gamma * terms.lam, done)
    return advantage, target, pen


def loose_tolerance(terms: ConstraintTerms, design: jax.Array, spread: jax.Array
                    ) -> jax.Array:
    """The tolerance ``[C]`` from which a loose constraint counts: ``terms.tolerance``;
    in a population's second design (``design`` 1), ``second_tolerance`` times the
    spread (std) ``[P]`` of its parent head's value targets, at least
    ``terms.second_floor``."""
    second = jnp.maximum(terms.second_tolerance * spread[jnp.asarray(terms.head)],
                         jnp.asarray(terms.second_floor))
    return jnp.where(design == 1, second, jnp.asarray(terms.tolerance))


def trace_decay(terms: ConstraintTerms, design: jax.Array) -> jax.Array:
    """The traced penalty's decay: ``gamma * lambda``; ``gamma`` in a population's
    second design, so a violation reaches the fork that led to it undiminished."""
    return jnp.where(design == 1, terms.gamma, terms.gamma * terms.lam)
