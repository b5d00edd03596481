"""How a phase keeps its ancestors' slacks (``TPOConfig.constraint``, docs/design.md
§5): two strategies behind one interface, so that the update reads the same in both.

- :class:`PenaltyForm`, the paper's Algorithm 1: the policy acts freely and pays
  the Lagrangian penalty of :mod:`tpo.algo.constraints`.
- :class:`RestrictionForm`: the policy samples only the actions that LAR's rule
  admits on the frozen critics' advantage outputs, and a share of the steps
  explores uniformly so that those outputs learn every action (discrete actions).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

from tpo.algo.config import TPOConfig
from tpo.algo.constraints import ConstraintTerms
from tpo.algo.distributions import Categorical, Distribution
from tpo.algo.lagrangian import admissible, ancestral_advantages, below_best
from tpo.algo.networks import ADVANTAGE_UNIT, Critics
from tpo.algo.phases import Acting, Problem


class PenaltyForm:
    """The paper's form: no restriction, the penalty in the advantage."""

    name = "penalty"
    n_out = 1  # a critic head's outputs: its value

    def __init__(self, terms: ConstraintTerms) -> None:
        self.terms = terms

    def allowed(self, critics: Critics, acting: Acting, obs: jax.Array) -> None:
        """No action is ever excluded."""
        return None

    @staticmethod
    def restrict(pi: Distribution, allowed: jax.Array | None) -> Distribution:
        return pi

    def explore(self, action: jax.Array, allowed: Any, k_explore: jax.Array,
                k_uniform: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The policy's own actions, none exploring."""
        return action, jnp.zeros(action.shape[:1], jnp.float32)

    def critic_outputs(self, critics: Critics, params: dict, mb: Any, phase: jax.Array,
                       std: jax.Array) -> tuple[jax.Array, float]:
        """The phase head's normalised values ``[B]`` at the minibatch ``mb``'s
        observations (that head alone is run), and no advantage loss."""
        return critics.head(params, phase, mb.obs)[:, 0], 0.0

    def q_target(self, reward: jax.Array, value: jax.Array, next_value: jax.Array,
                 terminated: jax.Array) -> None:
        return None

    def trainable(self, grads: dict, phase: jax.Array) -> dict:
        """Only the phase's head is in the loss: every gradient as it is."""
        return grads

    @staticmethod
    def excluded(allowed: None) -> float:
        """The share of actions excluded: none."""
        return 0.0


class RestrictionForm:
    """LAR's admissible actions, read from advantage outputs ``Q_h(s, a) - V_h(s)``
    that every head ``h`` learns beside its value, then frozen with it."""

    name = "restriction"

    def __init__(self, problem: Problem, terms: ConstraintTerms, n_actions: int,
                 explore: float) -> None:
        self.problem, self.terms, self.explore_share = problem, terms, explore
        self.n_out = 1 + n_actions

    def allowed(self, critics: Critics, acting: Acting, obs: jax.Array) -> jax.Array:
        """The admissible actions ``[..., A]`` of ``acting.phase`` at ``obs``: LAR's
        sets computed phase by phase. A constraint on head ``w`` measures an action
        against the best action of ``A_w(s)`` (:func:`tpo.algo.lagrangian.below_best`,
        as LAR's ``V_w = max_{A_w} Q_w``), its slack widened by the tolerance;
        :func:`tpo.algo.lagrangian.admissible` keeps the actions of least total
        violation."""
        prob = self.problem
        head = jnp.asarray(prob.head)
        adv = acting.value_norm.denormalize(
            critics.apply({"params": acting.critics}, obs))[..., head, 1:]  # [..., C, A]
        slack = self.terms.slacks(acting.slack) + jnp.asarray(self.terms.tolerance)
        sets = [jnp.ones(adv.shape[:-2] + adv.shape[-1:], bool)]  # A_0: every action
        for p in range(1, prob.n_phases):  # a phase's constraints read earlier heads only
            known = jnp.stack(sets + sets[:1] * (prob.n_phases - p), axis=-2)  # [..., P, A]
            gaps = below_best(adv, known[..., head, :])
            sets.append(admissible(gaps, slack, jnp.asarray(prob.active[p])))
        return jnp.stack(sets, axis=-2)[..., acting.phase, :]

    @staticmethod
    def restrict(pi: Distribution, allowed: jax.Array) -> Distribution:
        return pi.restrict(allowed)

    def explore(self, action: jax.Array, allowed: jax.Array, k_explore: jax.Array,
                k_uniform: jax.Array) -> tuple[jax.Array, jax.Array]:
        """On a share ``explore`` of the envs a uniform action instead of ``action``
        (any action: a critic that wrongly excludes one must still see it), and the
        exploring flags (float)."""
        explore = (jax.random.uniform(k_explore, action.shape[:1])
                   < self.explore_share).astype(jnp.float32)
        uniform = Categorical(jnp.zeros(allowed.shape)).sample(k_uniform)
        return jnp.where(explore > 0, uniform, action), explore

    def critic_outputs(self, critics: Critics, params: dict, mb: Any, phase: jax.Array,
                       std: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The phase head's normalised values ``[B]`` at the minibatch ``mb``'s
        observations, and the loss of every head up to the phase on its advantage
        output of the action taken against ``mb.q_target`` (``[B, P]``)."""
        out = critics.apply({"params": params}, mb.obs)  # [B, P, 1 + A]
        index = mb.action[:, None, None].astype(jnp.int32)
        adv = jnp.take_along_axis(out[..., 1:], index, -1)[..., 0]  # [B, P]
        heads = (jnp.arange(self.problem.n_phases) <= phase).astype(jnp.float32)
        loss = jnp.mean((adv - mb.q_target / (std * ADVANTAGE_UNIT)) ** 2, axis=0) @ heads
        return out[:, phase, 0], loss

    def q_target(self, reward: jax.Array, value: jax.Array, next_value: jax.Array,
                 terminated: jax.Array) -> jax.Array:
        """Every head's one-step advantages ``r_h + gamma V_h(s') - V_h(s)``
        ``[T, E, P]``: with ``V_h`` frozen these targets are fixed, so an ancestor's
        advantages keep sharpening on every later rollout while its values stay
        frozen."""
        terms = self.terms
        return ancestral_advantages(reward[..., jnp.asarray(terms.reward)], value, next_value,
                                    terminated, terms.gamma)

    def trainable(self, grads: dict, phase: jax.Array) -> dict:
        """The critics' gradient restricted to the phase's own head and the advantage
        outputs of the earlier heads (the output layer's columns ``1:``; their hidden
        layers and values stay frozen)."""
        heads = jnp.arange(self.problem.n_phases)
        own = (heads == phase).astype(jnp.float32)
        columns = jnp.where(jnp.arange(self.n_out) == 0, own[:, None],
                            (heads <= phase).astype(jnp.float32)[:, None])  # [P, n_out]

        def mask(path, g):
            if jax.tree_util.keystr(path).startswith("['heads']['out']"):
                return g * (columns[:, None, :] if g.ndim == 3 else columns)
            return g * own.reshape(-1, *([1] * (g.ndim - 1)))

        return jax.tree_util.tree_map_with_path(mask, grads)

    @staticmethod
    def excluded(allowed: jax.Array) -> jax.Array:
        """The share of actions excluded over a rollout's ``allowed [T, E, A]``."""
        return 1.0 - allowed.mean()


Form = PenaltyForm | RestrictionForm


def constraint_form(config: TPOConfig, problem: Problem, space: gym.Space,
                    reward_low: np.ndarray, reward_high: np.ndarray) -> Form:
    """The form a run keeps its constraints in, with its :class:`ConstraintTerms`: the
    restriction where the config asks for it, the graph has edges and the actions
    are discrete; else the penalty."""
    restricts = (config.constraint == "restriction" and bool(problem.graph.edges)
                 and isinstance(space, gym.spaces.Discrete))
    terms = ConstraintTerms.build(problem, config, reward_low, reward_high,
                                  penalized=not restricts)
    if restricts:
        return RestrictionForm(problem, terms, int(space.n), config.explore)
    return PenaltyForm(terms)
